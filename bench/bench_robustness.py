"""jaxvo on the development and validation splits (``bench/splits.py``), side by side.

For every case: ATE and RPE against ground truth and the best OpenCV peer's ATE on the same
frames; moving recall / precision / F at the grid points where exact masks exist; on the
static real frames the share of grid cells reported moving and of pixels in the plug-in
masks; on the TUM walking clip the share of the image the masks flag outside the annotated
people (``bench/annotations``); the pairs skipped and the background re-acquisitions. With
``--plugin`` each OpenCV peer runs again with jaxvo's dynamic pixels masked out (thesis
Fig. 5.8) and the report gives its ATE over the peer's own.

The grid flow of each case and the peers' trajectories do not depend on jaxvo's device
stages: they are computed once and cached under ``--cache`` (default ``results/cache``),
so a change to the method re-runs in about a minute.

Run: ``.venv/bin/python bench/bench_robustness.py [--split dev|val|all] [--only CASE ...]
[--plugin] [--out results/]``. Writes ``robustness.md`` and ``robustness.json``.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import inspect
import io
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer
from _common import first_pose, groundtruth, log, machine, markdown_table
from _options import check_options, params_from, params_setting
from splits import Case, cases, in_split, runnable

import jaxvo.host.frontend.keyframes
from jaxvo.config import Config, Params, config_fields, grid_shape, params_as_arrays
from jaxvo.core.inputs import GridFlow
from jaxvo.core.pipeline import committed_poses, final_moving, init_pipeline, jit_step
from jaxvo.evaluation.metrics import SegmentationScores
from jaxvo.evaluation.scores import moving_at_grid, trajectory_scores
from jaxvo.host.frontend.flow import sequence_flows
from jaxvo.host.services.peers import OPENCV_PEERS
from jaxvo.host.writers.outputs import write_bytes, write_text
from jaxvo.host.writers.plugin import iter_dynamic_masks
from jaxvo.status import Status
from jaxvo.study import runner as study
from jaxvo.trajectory import Trajectory

CFG = Config()


# ------------------------------------------------------------------------------- caching


def _flow_key(cfg: Config) -> str:
    """A short hash of what the host flow depends on: the Config fields it reads and the
    version of what the flow computes (``jaxvo.study.runner``'s flow cache key)."""
    fields = {k: getattr(cfg, k) for k in study.flow_fields()}
    return hashlib.sha1(json.dumps([fields, study.FLOW_FORMAT], sort_keys=True)
                        .encode()).hexdigest()[:10]


def frames_hash() -> str:
    """A short hash of the code that makes a case's frames (not its flow): what the peers'
    runs and the grid truth depend on, so that a change to the tracker re-runs neither."""
    import jaxvo.host.frontend.frames
    import jaxvo.host.readers.io
    import jaxvo.synth.render
    import jaxvo.synth.scenario
    import jaxvo.synth.scenes
    import jaxvo.synth.sequence

    h = hashlib.sha1()
    for mod in (jaxvo.host.frontend.frames, jaxvo.host.readers.io, jaxvo.synth.render, jaxvo.synth.scenario,
                jaxvo.synth.sequence, jaxvo.synth.scenes):
        h.update(inspect.getsource(mod).encode())
    return h.hexdigest()[:16]


def prepare(case: Case, cache: Path, cfg: Config) -> dict:
    """Flows, timestamps, ground truth and grid truth of a case, from the cache or computed
    (the flows in one file, keyed by the flow settings; the moving truth in another)."""
    path = flow_path(case, cache, cfg)
    truth = cache / f"{case.name}__truth{cfg.cell}_{frames_hash()}.npz"
    seq = None
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        data = {k: z[k] for k in z.files if k != "grid_gt"}
    else:
        data, seq = build_flow(case, path, cfg)
        if "gt_poses" in data:  # the peers alone, once (they do not depend on jaxvo)
            peers_alone(case, cache, seq)
    if case.kind in ("synthetic", "composite"):
        if not truth.is_file():
            seq = seq if seq is not None else case.build()
            log(f"{case.name}: the moving truth of every grid cell (cached in {truth})")
            save_npz(truth, grid_gt=np.stack(
                [moving_grid_truth(seq, k, cfg.cell) for k in range(len(seq))]))
        grid_gt = np.load(truth)["grid_gt"]
        data["grid_gt"] = grid_gt[data["frames"]] if "frames" in data else grid_gt
    return data


def flow_path(case: Case, cache: Path, cfg: Config) -> Path:
    """Where the case's flow is cached: keyed by the flow's settings and code, and apart
    when it holds the keyframe flow too (``cfg.keyframes``)."""
    if not cfg.keyframes:
        return cache / f"{case.name}__{_flow_key(cfg)}.npz"
    fields = {f.name: getattr(cfg, f.name) for f in config_fields().values()
              if f.name.startswith("keyframe")}
    kf = hashlib.sha1(json.dumps([fields, inspect.getsource(jaxvo.host.frontend.keyframes)],
                                 sort_keys=True).encode()).hexdigest()[:8]
    return cache / f"{case.name}__{_flow_key(cfg)}_kf{kf}.npz"


def build_flow(case: Case, path: Path, cfg: Config):
    """The case's flows (with ``cfg.keyframes`` its keyframe flows too, ``kf_<field>``),
    timestamps, image size and ground truth, computed and saved at ``path``:
    ``(data, sequence)``."""
    log(f"{case.name}: building the sequence and its flow (cached in {path})")
    seq = case.build()
    sf = sequence_flows(seq, cfg)
    data = {f"flow_{k}": np.asarray(v) for k, v in sf.flows._asdict().items()}
    if sf.keyframes is not None:
        data.update({f"kf_{k}": np.asarray(v) for k, v in sf.keyframes._asdict().items()})
    # the frames the chain kept: a frame it dropped (too few valid tracks, e.g. an oracle's
    # frame whose depth was mostly a mover's) has no pose
    data["frames"] = np.asarray(sf.frames, np.int64)
    data["timestamps"] = np.asarray(seq.timestamps, np.float64)[data["frames"]]
    data["size"] = np.array([seq.height, seq.width])
    gt = seq.groundtruth
    if gt is not None and len(gt) > 0:
        data["gt_poses"] = np.asarray(gt.poses, np.float64)
        if len(gt) != len(data["timestamps"]):  # of some frames (associated by time)
            data["gt_times"] = np.asarray(gt.timestamps, np.float64)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_npz(path, **data)
    return data, seq


def save_npz(path: Path, **arrays) -> None:
    """``arrays`` as the compressed ``.npz`` cache file ``path``, whole or not at all: a run
    stopped while writing (Ctrl-C, a full disk) leaves no truncated cache for the next run
    to fail on."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_bytes(path, buf.getvalue())


# An object moves in a frame pair when a corner of its box moves by more than this (metres):
# a stopped object that the method calls static is right (thesis section 5.2 counts it so).
_STOPPED = 1e-3


def moving_grid_truth(seq, k: int, cell: int) -> np.ndarray:
    """(n,) bool grid cells of image ``k`` on an object that moves between images ``k`` and
    ``k + 1`` (the last image: ``k - 1`` and ``k``), from the exact masks and object poses."""
    mask = seq[k].mask
    objects = getattr(seq, "object_trajectories", None)
    if not objects:
        return moving_at_grid(mask, cell)
    a, b = (k, k + 1) if k + 1 < len(seq) else (k - 1, k)
    halves = [np.asarray(o.size) / 2 for o in seq.scenario.objects]
    moving_ids = []
    for oid, traj in objects.items():
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T * halves[oid - 1]
        pa = corners @ traj.poses[a][:3, :3].T + traj.poses[a][:3, 3]
        pb = corners @ traj.poses[b][:3, :3].T + traj.poses[b][:3, 3]
        if np.max(np.linalg.norm(pa - pb, axis=1)) > _STOPPED:
            moving_ids.append(oid)
    from jaxvo.evaluation.scores import ids_at_grid

    return np.isin(ids_at_grid(mask, cell), moving_ids)


def peer_kinds() -> list[str]:
    """The OpenCV peers, and ORB-SLAM3 where it can run (``bench/orbslam3_peer.py``)."""
    return list(OPENCV_PEERS) + ([] if orbslam3_peer.missing() else [orbslam3_peer.NAME])


def peers_alone(case: Case, cache: Path, seq=None) -> dict:
    """ATE and ms/frame of each peer alone on the case (cached; a peer missing from the
    cache, such as ORB-SLAM3 newly installed, is run and added); {} without ground truth.
    ORB-SLAM3 is not deterministic: its cached figure is one run."""
    path = cache / f"{case.name}__peers_{frames_hash()}.json"
    out = json.loads(path.read_text()) if path.is_file() else {}
    todo = [k for k in peer_kinds() if k not in out]
    if not todo:
        return out
    seq = seq if seq is not None else case.build()
    if seq.groundtruth is None:
        return {}
    for kind in todo:
        log(f"{case.name}: peer {kind}")
        run = orbslam3_peer.run_any_peer(seq, kind)
        out[kind] = trajectory_scores(seq.groundtruth, run.trajectory)
        out[kind]["ms_per_frame"] = run.ms_per_frame
    write_text(path, json.dumps(out, indent=1))  # whole or not at all: it is read back
    return out


# ----------------------------------------------------------------------------------- run


def run_jaxvo(data: dict, params: Params, cfg: Config, seed: int):
    """The streaming step over the cached flows (compiled once for every 640x480 case):
    the same per-frame keys as ``run_scan``, so the same result."""
    h, w = (int(x) for x in data["size"])
    grid = grid_shape(h, w, cfg.cell)
    T0 = first_pose(data)
    state = init_pipeline(cfg=cfg.step, grid=grid, T_w_c0=T0, params=params)
    key = jax.random.key(seed)
    p = params_as_arrays(params)
    flows = GridFlow(*(data[f"flow_{k}"] for k in GridFlow._fields))
    outs = []
    t0 = time.perf_counter()
    for k in range(len(flows.valid)):
        flow = GridFlow(*(jnp.asarray(a[k]) for a in flows))
        state, out = jit_step(state, flow, key, p, cfg=cfg.step, grid=grid)
        outs.append(out)
    outs = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *outs)
    seconds = time.perf_counter() - t0
    committed = committed_poses(outs)
    poses = np.concatenate([np.asarray(T0, np.float64)[None], np.asarray(committed, np.float64)])
    return Trajectory(data["timestamps"], poses), outs, np.asarray(final_moving(state, p)), seconds


def score(case: Case, data: dict, traj, outs, final_ids, cache: Path, cfg: Config) -> dict:
    h, w = (int(x) for x in data["size"])
    res: dict = {"case": case.name, "split": case.split, "kind": case.kind,
                 "pairs": len(outs.status)}
    status = np.asarray(outs.status)
    res["skipped"] = {Status(int(c)).reason: int(np.sum(status == c))
                      for c in np.unique(status) if c != Status.OK}
    res["skipped_no_static"] = int(np.sum(status == Status.NO_STATIC))
    if hasattr(outs, "reacquired"):
        res["reacquired"] = int(np.sum(np.asarray(outs.reacquired)))
    moving = np.asarray(outs.moving)
    res["moving_cells_pct"] = 100.0 * float(moving.mean())
    masks = list(iter_dynamic_masks(outs, h, w, cfg.cell, final_ids=final_ids))
    res["dynamic_pixels_pct"] = 100.0 * float(np.mean([m.mean() for m in masks]))
    res["dynamic_pixels_pct_max"] = 100.0 * float(np.max([m.mean() for m in masks]))
    if "gt_poses" in data:
        gt = groundtruth(data)
        res.update(trajectory_scores(gt, traj))
        peers = peers_alone(case, cache)
        if peers:
            best = min(OPENCV_PEERS, key=lambda k: peers[k]["ate_rmse_m"])
            res["best_peer"] = best
            res["best_peer_ate_m"] = peers[best]["ate_rmse_m"]
            res["ate_over_best_peer"] = res["ate_rmse_m"] / max(peers[best]["ate_rmse_m"], 1e-12)
            if orbslam3_peer.NAME in peers:
                o = peers[orbslam3_peer.NAME]
                res["orbslam3_ate_m"], res["orbslam3_ms_per_frame"] = o["ate_rmse_m"], o["ms_per_frame"]
    if "grid_gt" in data:
        # the moving cells, and the identifiers' own notion (>= 2: an object), which the
        # label masks and overlays show
        for name, pred in (("moving", moving), ("ids", np.asarray(outs.ids) >= 2)):
            s = SegmentationScores()
            for k in range(len(pred)):
                s.add(pred[k], data["grid_gt"][k])
            res.update({f"{name}_{k}": v for k, v in s.as_dict().items()
                        if k in ("recall", "precision", "f_measure")})
    if case.kind == "people":
        res.update(people_scores(case, masks, h, w, cfg))
    return res


def people_scores(case: Case, masks, h: int, w: int, cfg: Config) -> dict:
    """Share of the image flagged dynamic more than one cell away from the annotated people
    (a flagged cell that straddles a person's outline is not counted against it)."""
    try:
        from people_masks import people_masks
    except ImportError:
        return {"people": "no annotation module (bench/people_masks.py)"}
    import cv2

    from jaxvo.host.readers.io import data_root

    people = people_masks(data_root() / case.source)
    grow = np.ones((2 * cfg.cell + 1, 2 * cfg.cell + 1), np.uint8)
    outside, inside = [], []
    for k, m in enumerate(masks):
        p = people[k]
        near = cv2.dilate(p.astype(np.uint8), grow).astype(bool)
        outside.append(float(np.mean(m & ~near)))
        inside.append(float(np.sum(m & p) / max(np.sum(p), 1)))
    return {"dynamic_outside_people_pct": 100.0 * float(np.mean(outside)),
            "dynamic_outside_people_pct_max": 100.0 * float(np.max(outside)),
            "people_covered_pct": 100.0 * float(np.mean(inside))}


def plugin(case: Case, outs, final_ids, data: dict, cfg: Config) -> dict:
    """Each peer with jaxvo's dynamic pixels masked out: its ATE."""
    if "gt_poses" not in data:
        return {}
    seq = case.build()
    h, w = seq.height, seq.width
    masks = list(iter_dynamic_masks(outs, h, w, cfg.cell, final_ids=final_ids))
    out = {}
    for kind in peer_kinds():
        run = orbslam3_peer.run_any_peer(seq, kind, keep=lambda i: ~masks[i])
        out[kind] = trajectory_scores(seq.groundtruth, run.trajectory)["ate_rmse_m"]
    return out


# -------------------------------------------------------------------------------- report


def _fmt(x, spec=".3f"):
    return "-" if x is None else format(x, spec)


def table(rows: list[dict]) -> str:
    head = ["case", "split", "ATE mm", "best OpenCV peer mm", "ratio", "ORB-SLAM3 mm (ms/frame)",
            "RPE mm/frame", "F", "recall", "precision", "ids F (P)", "moving cells %",
            "mask px % (max)", "skipped (no static)", "re-acq"]
    cells = []
    for r in rows:
        ate, peer, rpe = r.get("ate_rmse_m"), r.get("best_peer_ate_m"), r.get("rpe_trans_m_per_frame")
        cells.append([
            r["case"], r["split"], _fmt(ate and 1e3 * ate, ".1f"), _fmt(peer and 1e3 * peer, ".1f"),
            _fmt(r.get("ate_over_best_peer"), ".2f"),
            (f"{1e3 * r['orbslam3_ate_m']:.1f} ({r['orbslam3_ms_per_frame']:.0f})"
             if "orbslam3_ate_m" in r else "-"),
            _fmt(rpe and 1e3 * rpe, ".2f"),
            _fmt(r.get("moving_f_measure")), _fmt(r.get("moving_recall")),
            _fmt(r.get("moving_precision")),
            "-" if r.get("ids_f_measure") is None
            else f"{r['ids_f_measure']:.3f} ({r['ids_precision']:.3f})",
            f"{r['moving_cells_pct']:.2f}",
            f"{r['dynamic_pixels_pct']:.2f} ({r['dynamic_pixels_pct_max']:.1f})",
            f"{sum(r['skipped'].values())} ({r['skipped_no_static']})",
            str(r.get("reacquired", "-"))])
    return markdown_table(head, cells)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "val", "fresh", "all"), default="all")
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--plugin", action="store_true", help="also each peer with jaxvo's masks")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", type=params_setting,
                    help="Params values to run with (a study of one configuration)")
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)
    check_options(ap, args, cases=[c.name for c in cases()])
    params = params_from(args.set)

    todo = [c for c in cases() if in_split(c, args.split)
            and (not args.only or c.name in args.only)]
    rows = []
    todo, skipped = runnable(todo)
    for name, why in skipped.items():
        log(f"{name}: skipped ({why})")
    for case in todo:
        data = prepare(case, args.cache, CFG)
        traj, outs, final_ids, seconds = run_jaxvo(data, params, CFG, args.seed)
        row = score(case, data, traj, outs, final_ids, args.cache, CFG)
        row["jaxvo_seconds"] = seconds
        if args.plugin and case.kind in ("static", "composite"):
            masked = plugin(case, outs, final_ids, data, CFG)
            alone = peers_alone(case, args.cache)
            row["plugin_ate_over_alone"] = {k: masked[k] / max(alone[k]["ate_rmse_m"], 1e-12)
                                            for k in masked}
        rows.append(row)
        log(f"{case.name}: " + ", ".join(
            f"{k} {v:.4g}" for k, v in row.items()
            if isinstance(v, float) and k in ("ate_rmse_m", "ate_over_best_peer",
                                              "moving_f_measure", "moving_cells_pct",
                                              "dynamic_pixels_pct",
                                              "dynamic_outside_people_pct")))
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": machine(),
            "skipped_cases": skipped}
    (args.out / "robustness.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = [(f"# jaxvo on the development and validation splits\n\n{meta['date']}; "
           f"{meta['machine']['cpu_model']}; jax {meta['machine']['jax']}\n"),
          "## Development split (tuned on)\n", table([r for r in rows if r["split"] == "dev"]),
          "\n## Validation split (never tuned on)\n",
          table([r for r in rows if r["split"] == "val"]),
          "\n## Fresh cases (run once after the last change)\n",
          table([r for r in rows if r["split"] == "fresh"])]
    people = [r for r in rows if "dynamic_outside_people_pct" in r]
    for r in people:
        md.append(f"\n{r['case']}: masks outside the people {r['dynamic_outside_people_pct']:.2f} % "
                  f"of the image on average (worst frame {r['dynamic_outside_people_pct_max']:.1f} %); "
                  f"people covered {r['people_covered_pct']:.1f} %")
    plug = [r for r in rows if "plugin_ate_over_alone" in r]
    if plug:
        md.append("\n## Plug-in: each peer's ATE with jaxvo's mask over its ATE alone\n")
        kinds = [k for k in peer_kinds() if k in plug[0]["plugin_ate_over_alone"]]
        md.append(markdown_table(["case", *kinds], [
            [r["case"], *(f"{r['plugin_ate_over_alone'][k]:.3f}" for k in kinds)] for r in plug]))
    md.append("\nORB-SLAM3 (`bench/orbslam3_peer.py`, one run per case, its own process): "
              + (f"skipped: {orbslam3_peer.missing()}" if orbslam3_peer.missing() else
                 f"x jaxvo with `{orbslam3_peer.CHOSEN.name}` masking. "
                 + orbslam3_peer.vocabulary_note()))
    for name, why in skipped.items():
        md.append(f"\n{name}: skipped, {why}")
    (args.out / "robustness.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
