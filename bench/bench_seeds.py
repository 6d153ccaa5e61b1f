"""jaxvo's accuracy over seeds on the development and validation splits (issue 38).

Every figure of a dynamic case is the median and the spread (worst / best) over ``--seeds``
seeded runs: one seed is an anecdote. The cases are ``bench/splits.py``'s (their flows
cached by ``bench_robustness.py``), run for all seeds at once: the per-frame step vmapped
over the seeds' keys (one compiled program for every 640x480 case, the same frame keys as
``run_scan``). Per case and seed: ATE against the ground truth, moving F at the grid
points (composites and synthetic scenes), the share of grid cells reported moving (static
frames), the points the ego-motion used. On the TUM walking clip: the ATE against TUM's
ground truth (``ground_truth/`` under the data root). On the clip and on the composites the
same for the *oracle*: jaxvo with the depth under the movers set to 0 (the clip's hand-drawn
people masks, ``bench/annotations``; the composites' exact box masks), which splits the
error into what the segmentation lets in and what the tracking loses.

Run: ``.venv/bin/python bench/bench_seeds.py [--split dev|val|all] [--only CASE ...]
[--seeds 5] [--set NAME=VALUE ...] [--out results/]``; writes ``seeds.md`` and
``seeds.json``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer
from _common import first_pose, groundtruth, log, machine_line, markdown_table
from _options import check_options, config_from, config_setting, count, params_from, params_setting
from bench_people import without_people
from bench_robustness import CFG, peers_alone, prepare
from people_masks import people_masks
from splits import Case, cases, runnable

from jaxvo.config import (
    Config,
    Params,
    StepOptions,
    grid_shape,
    params_as_arrays,
)
from jaxvo.core.inputs import GridFlow, KeyframeFlow
from jaxvo.core.pipeline import committed_poses, frame_key, init_pipeline, step
from jaxvo.evaluation.metrics import SegmentationScores
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import data_root
from jaxvo.host.services.peers import OPENCV_PEERS
from jaxvo.host.writers.outputs import write_text
from jaxvo.trajectory import Trajectory


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def _seeds_step(states, flow, keys, params, kf=None, *, cfg: StepOptions, grid):
    """One frame pair for every seed: the step vmapped over the seeds' states and keys."""

    def one(state, key):
        return step(state, flow, frame_key(key, state.frame), params, cfg=cfg, grid=grid,
                    batch_axis="seeds", keyframe=kf)

    return jax.vmap(one, axis_name="seeds")(states, keys)


def run_seeds(flows: dict, T0, params: Params, cfg: Config, seeds: int, first_seed: int = 0):
    """Trajectories (one per seed, float64 poses) and the stacked outputs (S, T, ...) of the
    seeds ``first_seed`` .. ``first_seed + seeds - 1`` over the cached ``flows``
    (``flow_<field>`` arrays)."""
    h, w = (int(x) for x in flows["size"])
    grid = grid_shape(h, w, cfg.cell)
    state = init_pipeline(cfg=cfg.step, grid=grid, T_w_c0=T0, params=params)
    states = jax.tree.map(lambda x: jnp.broadcast_to(x, (seeds,) + jnp.shape(x)), state)
    keys = jnp.stack([jax.random.key(first_seed + s) for s in range(seeds)])
    p = params_as_arrays(params)
    flow_all = GridFlow(*(flows[f"flow_{k}"] for k in GridFlow._fields))
    kf_all = (KeyframeFlow(*(flows[f"kf_{k}"] for k in KeyframeFlow._fields))
              if cfg.keyframes else None)
    outs = []
    for k in range(len(flow_all.valid)):
        flow = GridFlow(*(jnp.asarray(a[k]) for a in flow_all))
        kf = None if kf_all is None else KeyframeFlow(*(jnp.asarray(a[k]) for a in kf_all))
        states, out = _seeds_step(states, flow, keys, p, kf, cfg=cfg.step, grid=grid)
        outs.append(out)
    outs = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs], axis=1), *outs)
    t = np.asarray(flows["timestamps"], np.float64)
    T0 = np.asarray(T0, np.float64)
    committed = [np.asarray(committed_poses(jax.tree.map(lambda x, s=s: x[s], outs)),
                            np.float64) for s in range(seeds)]
    trajs = [Trajectory(t, np.concatenate([T0[None], committed[s]])) for s in range(seeds)]
    return trajs, outs


def add_run_options(ap: argparse.ArgumentParser) -> None:
    """The options of a seeded accuracy run that this script and ``bench_cover.py`` share:
    ``--set`` (Params), ``--config`` (Config), ``--cache``, ``--out`` and ``--title``."""
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE", type=params_setting,
                    help="Params values to run with")
    ap.add_argument("--config", nargs="*", default=[], metavar="NAME=VALUE",
                    type=config_setting, help="Config values to run with (e.g. keyframes=true)")
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    ap.add_argument("--out", type=Path, default=Path("results"))
    ap.add_argument("--title", default="", help="a line saying what this run is")


def reference_case(case: Case) -> Case:
    """The case's oracle: the same frames and ground truth with the depth under the movers
    set to 0. The people case's movers are its hand-drawn people masks (``_nopeople``), a
    composite's its boxes' exact masks (``_nobox``)."""
    if case.kind == "composite":
        def build():
            seq = case.build()
            return without_people(seq, {i: f.mask > 0 for i, f in enumerate(seq)})
        return case._replace(name=f"{case.name}_nobox", build=build)
    folder = data_root() / case.source
    return case._replace(name=f"{case.name}_nopeople", build=lambda: without_people(
        case.build(), people_masks(folder)))


def spread(values) -> dict:
    """Median, worst, best and worst / best of per-seed figures (lower is better)."""
    v = np.asarray(values, np.float64)
    return {"median": float(np.median(v)), "worst": float(v.max()), "best": float(v.min()),
            "spread": float(v.max() / max(v.min(), 1e-12)), "values": [float(x) for x in v]}


def score_case(case: Case, data: dict, params: Params, seeds: int, cache: Path,
               cfg: Config = CFG) -> dict:
    T0 = first_pose(data)
    t0 = time.perf_counter()
    trajs, outs = run_seeds(data, T0, params, cfg, seeds)
    row: dict = {"case": case.name, "split": case.split, "kind": case.kind,
                 "seconds": time.perf_counter() - t0,
                 "used_points": float(np.median(np.sum(outs.static, axis=-1))),
                 "moving_cells_pct": spread(100.0 * outs.moving.mean(axis=(1, 2)))}
    status = np.asarray(outs.status)
    row["skipped"] = int(np.sum(status != 0))
    if cfg.keyframes:
        row["keyframes"] = int(np.median(outs.keyframes[:, -1]))
    if "gt_poses" in data:
        gt = groundtruth(data)
        row["ate_mm"] = spread([1e3 * trajectory_scores(gt, tr)["ate_rmse_m"] for tr in trajs])
        peers = peers_alone(case, cache)
        if peers:
            best = min(OPENCV_PEERS, key=lambda k: peers[k]["ate_rmse_m"])
            row["best_peer"], row["best_peer_mm"] = best, 1e3 * peers[best]["ate_rmse_m"]
            if orbslam3_peer.NAME in peers:  # one run: ORB-SLAM3 is not deterministic
                row["orbslam3_mm"] = 1e3 * peers[orbslam3_peer.NAME]["ate_rmse_m"]
    if "grid_gt" in data:
        fs = []
        for s in range(seeds):
            sc = SegmentationScores()
            for k in range(outs.moving.shape[1]):
                sc.add(outs.moving[s, k], data["grid_gt"][k])
            fs.append(sc.as_dict()["f_measure"])
        row["moving_f"] = {"median": float(np.median(fs)), "worst": float(np.min(fs)),
                           "best": float(np.max(fs)), "values": [float(x) for x in fs]}
    if case.kind in ("people", "composite") and "gt_poses" in data:
        oracle = prepare(reference_case(case), cache, cfg)
        refs, _ = run_seeds(oracle, T0, params, cfg, seeds)
        gt = groundtruth(data)
        row["oracle_ate_mm"] = spread([1e3 * trajectory_scores(gt, tr)["ate_rmse_m"]
                                       for tr in refs])
    return row


def fmt_spread(s: dict | None, spec: str = ".1f") -> str:
    """A :func:`spread` as ``median [best-worst]``; "-" for none."""
    if not s:
        return "-"
    return f"{s['median']:{spec}} [{s['best']:{spec}}-{s['worst']:{spec}}]"


def table(rows: list[dict]) -> str:
    head = ["case", "ATE mm median [best-worst]", "worst/best", "best OpenCV peer mm",
            "median / best peer", "ORB-SLAM3 mm (one run)", "oracle ATE mm (movers' depth removed)",
            "worst/best",
            "moving F median [worst-best]", "moving cells %", "points used", "skipped"]
    cells = []
    for r in rows:
        a, d = r.get("ate_mm"), r.get("oracle_ate_mm")
        f = r.get("moving_f")
        cells.append([
            r["case"], fmt_spread(a), f"{a['spread']:.2f}" if a else "-",
            f"{r['best_peer_mm']:.1f}" if "best_peer_mm" in r else "-",
            f"{a['median'] / r['best_peer_mm']:.2f}" if a and "best_peer_mm" in r else "-",
            f"{r['orbslam3_mm']:.1f}" if "orbslam3_mm" in r else "-",
            fmt_spread(d), f"{d['spread']:.2f}" if d else "-",
            f"{f['median']:.3f} [{f['worst']:.3f}-{f['best']:.3f}]" if f else "-",
            fmt_spread(r["moving_cells_pct"], ".2f"), f"{r['used_points']:.0f}", str(r["skipped"])])
    return markdown_table(head, cells)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "val", "fresh", "draws", "all"), default="val")
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--seeds", type=count(1), default=5)
    add_run_options(ap)
    args = ap.parse_args(argv)
    check_options(ap, args, cases=[c.name for c in cases()])
    params = params_from(args.set)
    cfg = config_from(args.config)
    todo = [c for c in cases() if c.split in (("dev", "val") if args.split == "all"
                                                 else (args.split,))
            and (not args.only or c.name in args.only)]
    rows = []
    todo, skipped = runnable(todo)
    for case in todo:
        row = score_case(case, prepare(case, args.cache, cfg), params, args.seeds, args.cache,
                         cfg)
        rows.append(row)
        log(f"{case.name}: ATE {fmt_spread(row.get('ate_mm'))} oracle {fmt_spread(row.get('oracle_ate_mm'))}"
            f" F {row.get('moving_f', {}).get('median', float('nan')):.3f}"
            f" cells {row['moving_cells_pct']['median']:.2f} % used {row['used_points']:.0f}")
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
            "seeds": args.seeds, "set": args.set, "config": args.config, "title": args.title,
            "skipped": skipped}
    write_text(args.out / "seeds.json", json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = [f"# jaxvo over {args.seeds} seeds\n", machine_line(), "",
          args.title, "", table(rows), ""]
    md += [f"{k}: skipped, {v}" for k, v in skipped.items()]
    write_text(args.out / "seeds.md", "\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
