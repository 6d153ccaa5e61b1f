"""Heavy cover: does the ego-motion lock on a near mover that fills the view?

The heavy-cover family (``jaxvo.synth`` presets ``heavy_cover_50``, ``_70``, ``_90``): one
near box covering about that share of the view from the first frame, moving with the camera
and across it, in the synthetic room and composited into the shared 7-Scenes frames
(development: frames 0-59; validation: frames 150-209). Each of ``--seeds`` seeds is a
scene of its own (the box's path, its texture, the sensor noise) run with the same jaxvo
seed. Per case and seed: whether the ego-motion is *locked on the mover* at frames 1, 10
and 50, two ways: by the points it used (more than half of them lie on the box, from the
exact masks: the issue's reading), and by its motion (it moves the pair's points nearer to
where the box's own motion takes them than to where the camera's does: in a pair where the
box's motion differs from the camera's by less than the noise, the points used cover both
and only the motion says which one the fit followed); the share of pairs locked from frame
10 on, the pairs whose motion was carried (not
measured), the box's cover of the view (its share of the grid cells),
and the ATE beside the best OpenCV peer on the same frames.

``--family carried`` runs the carried family instead (presets ``carried_50``, ``_70``: a box
carried with the camera itself, 150 frames: frames 0-149 and 150-299 of 7-Scenes), and
writes ``cover_carried.md`` / ``.json``.

Run: ``.venv/bin/python bench/bench_cover.py [--seeds 10] [--family heavy|carried] [--only CASE ...] [--set
NAME=VALUE ...] [--out results/] [--title LINE]``; writes ``cover.md`` and ``cover.json``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, first_pose, groundtruth, log, machine_line, markdown_table
from _options import check_options, config_from, count, params_from
from bench_robustness import CFG, peers_alone, prepare
from bench_seeds import add_run_options, run_seeds, spread
from splits import Case

from jaxvo.config import Params
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import InMemorySequence, data_root
from jaxvo.host.services.peers import OPENCV_PEERS
from jaxvo.synth.scenes import composite_sequence, make_sequence

# each family's presets (jaxvo.synth) and frames a run: frames 1, 10 and 50 are judged
FAMILIES = {"heavy": ("heavy_cover", (50, 70, 90), 60),
            "carried": ("carried", (50, 70), 150)}
AT = (1, 10, 50)
# (kind, split, first 7-Scenes frame or None for the synthetic room)
SETTINGS = (("synth", "dev", None), ("comp", "dev", 0), ("comp", "val", 150))


def cover_cases(seeds: int, family: str = "heavy") -> list[tuple[str, list[Case]]]:
    """Each (cover, setting) group's name and its cases, one per seed (``Case.build``
    renders the frames; :func:`lazy_sequence` gives the same sequence unrendered)."""
    prefix, covers, frames = FAMILIES[family]
    groups = []
    for cover in covers:
        scenario = f"{prefix}_{cover}"
        for kind, split, start in SETTINGS:
            name = f"{kind}_{scenario}_{split}"
            cases = []
            for s in range(seeds):
                if start is None:
                    build = (lambda sc=scenario, s=s: InMemorySequence(
                        make_sequence(sc, frames=frames, seed=s)))
                    source = None
                else:
                    build = (lambda sc=scenario, s=s, st=start: InMemorySequence(
                        composite_sequence(data_root() / SEVEN_SCENES, sc, start=st,
                                           frames=frames, seed=s)))
                    source = SEVEN_SCENES
                cases.append(Case(f"{name}_s{s}", split, "synthetic" if start is None
                                  else "composite", source, build))
            groups.append((name, cases))
    return groups


def lazy_sequence(case: Case):
    """The case's sequence before rendering (its camera and object trajectories)."""
    prefix, _, frames = next(f for f in FAMILIES.values() if f"_{f[0]}_" in case.name)
    scenario = f"{prefix}_" + case.name.split(f"{prefix}_")[1].split("_")[0]
    seed = int(case.name.rsplit("_s", 1)[1])
    if case.source is None:
        return make_sequence(scenario, frames=frames, seed=seed)
    start = 0 if "_dev_" in case.name else 150
    return composite_sequence(data_root() / SEVEN_SCENES, scenario, start=start,
                              frames=frames, seed=seed)


def motion_locked(T_est: np.ndarray, seq, pts_prev: np.ndarray, valid: np.ndarray):
    """(T,) bool: each pair's estimated motion ``T_est`` (T, 4, 4) takes the pair's valid
    points (``pts_prev`` (T, n, 3), ``valid`` (T, n)) nearer (RMS) to where the box's motion
    takes them than to where the camera's does."""
    Tc = seq.groundtruth.poses
    To = next(iter(seq.object_trajectories.values())).poses
    out = []
    for k in range(len(T_est)):
        cam = np.linalg.inv(Tc[k + 1]) @ Tc[k]
        box = np.linalg.inv(Tc[k + 1]) @ To[k + 1] @ np.linalg.inv(To[k]) @ Tc[k]
        p = pts_prev[k][valid[k]].astype(np.float64)
        if len(p) == 0:
            out.append(False)
            continue

        def rms(A, B, p=p):
            d = p @ (A[:3, :3] - B[:3, :3]).T + (A[:3, 3] - B[:3, 3])
            return np.sqrt(np.mean(np.sum(d * d, axis=1)))

        E = T_est[k].astype(np.float64)
        out.append(rms(E, box) < rms(E, cam))
    return np.array(out)


def locked(static: np.ndarray, on_mover: np.ndarray) -> np.ndarray:
    """(T,) bool: more than half of the points the ego-motion used at each pair lie on a
    mover (``static``, ``on_mover`` (T, n) bool, the grid of the pair's first image)."""
    used = static.sum(axis=1)
    return (static & on_mover).sum(axis=1) > 0.5 * np.maximum(used, 1)


def run_group(name: str, cases: list[Case], params: Params, cfg, cache: Path) -> dict:
    rows = []
    for s, case in enumerate(cases):
        data = prepare(case, cache, cfg)
        T0 = first_pose(data)
        # one seed a scene: the scene's own seed is the run's
        trajs, outs = run_seeds(data, T0, params, cfg, 1, first_seed=s)
        on_mover = data["grid_gt"][:-1].astype(bool)
        lk = locked(np.asarray(outs.static[0]), on_mover)
        ok = np.asarray(outs.status[0]) == 0
        mk = motion_locked(np.asarray(outs.T_cur_prev[0]), lazy_sequence(case),
                           data["flow_pts_prev"], data["flow_valid"]) & ok
        gt = groundtruth(data)
        peers = peers_alone(case, cache)
        best = min(OPENCV_PEERS, key=lambda k: peers[k]["ate_rmse_m"]) if peers else None
        status = np.asarray(outs.status[0])
        rows.append({
            "seed": s,
            "ate_mm": 1e3 * trajectory_scores(gt, trajs[0])["ate_rmse_m"],
            "best_peer_mm": 1e3 * peers[best]["ate_rmse_m"] if best else None,
            "locked_at": {k: bool(lk[k - 1]) for k in AT},
            "locked_after10": float(lk[9:].mean()),
            "motion_locked_at": {k: bool(mk[k - 1]) for k in AT},
            "motion_locked_after10": float(mk[9:].mean()),
            "carried": int(np.sum(status != 0)),
            "cover_pct": [float(100 * on_mover[k].mean()) for k in (0, 10, 50)],
        })
    ate = spread([r["ate_mm"] for r in rows])
    peer = [r["best_peer_mm"] for r in rows if r["best_peer_mm"] is not None]
    return {
        "case": name, "seeds": len(rows), "ate_mm": ate,
        "best_peer_mm": float(np.median(peer)) if peer else None,
        "locked_at": {k: sum(r["locked_at"][k] for r in rows) for k in AT},
        "seeds_locked_after10": sum(r["locked_after10"] > 0 for r in rows),
        "locked_after10_pct": spread([100 * r["locked_after10"] for r in rows]),
        "motion_locked_at": {k: sum(r["motion_locked_at"][k] for r in rows) for k in AT},
        "seeds_motion_locked_after10": sum(r["motion_locked_after10"] > 0 for r in rows),
        "motion_locked_after10_pct": spread([100 * r["motion_locked_after10"] for r in rows]),
        "carried": spread([r["carried"] for r in rows]),
        "cover_pct": [float(np.median([r["cover_pct"][i] for r in rows])) for i in range(3)],
        "runs": rows,
    }


def table(groups: list[dict], seeds: int) -> str:
    head = ["case", "cover % at frames 0 / 10 / 50 (median)",
            "locked by points used at frames 1 / 10 / 50 (seeds)",
            "seeds locked by points after frame 10", "pairs locked by points after 10 %",
            "locked by motion at frames 1 / 10 / 50 (seeds)",
            "seeds locked by motion after frame 10", "pairs locked by motion after 10 %",
            "pairs carried", "ATE mm median [best-worst]", "worst/best", "best OpenCV peer mm"]

    def pct(x):
        return f"{x['median']:.0f} [{x['best']:.0f}-{x['worst']:.0f}]"

    cells = []
    for g in groups:
        a = g["ate_mm"]
        cells.append([
            g["case"], " / ".join(f"{c:.0f}" for c in g["cover_pct"]),
            " / ".join(str(g["locked_at"][k]) for k in AT), str(g["seeds_locked_after10"]),
            pct(g["locked_after10_pct"]),
            " / ".join(str(g["motion_locked_at"][k]) for k in AT),
            str(g["seeds_motion_locked_after10"]), pct(g["motion_locked_after10_pct"]),
            f"{g['carried']['median']:.0f}",
            f"{a['median']:.1f} [{a['best']:.1f}-{a['worst']:.1f}]", f"{a['spread']:.2f}",
            f"{g['best_peer_mm']:.1f}" if g["best_peer_mm"] is not None else "-"])
    return markdown_table(head, cells) + f"\n\n{seeds} seeds; pairs locked: median [best-worst].\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=count(1), default=10)
    ap.add_argument("--only", nargs="*", help="group names (e.g. comp_heavy_cover_50_dev)")
    ap.add_argument("--family", choices=sorted(FAMILIES), default="heavy",
                    help="heavy: the heavy-cover presets (60 frames); carried: a box carried "
                    "with the camera itself (150 frames)")
    add_run_options(ap)
    args = ap.parse_args(argv)
    check_options(ap, args, cases=[name for name, _ in cover_cases(1, args.family)])
    params = params_from(args.set)
    cfg = config_from(args.config) if args.config else CFG
    groups = []
    for name, cases in cover_cases(args.seeds, args.family):
        if args.only and name not in args.only:
            continue
        if cases[0].source is not None and not (data_root() / cases[0].source).is_dir():
            log(f"{name}: skipped, {cases[0].source} not under {data_root()}")
            continue
        t0 = time.perf_counter()
        g = run_group(name, cases, params, cfg, args.cache)
        g["seconds"] = time.perf_counter() - t0
        groups.append(g)
        log(f"{name}: locked at {g['locked_at']} (motion {g['motion_locked_at']}), after 10:"
            f" {g['seeds_locked_after10']} seeds (motion {g['seeds_motion_locked_after10']}),"
            f" ATE {g['ate_mm']['median']:.1f} mm [{g['ate_mm']['best']:.1f}-"
            f"{g['ate_mm']['worst']:.1f}]")
    args.out.mkdir(parents=True, exist_ok=True)
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "seeds": args.seeds,
            "set": args.set, "config": args.config, "title": args.title}
    stem = "cover" if args.family == "heavy" else f"cover_{args.family}"
    (args.out / f"{stem}.json").write_text(json.dumps({"meta": meta, "groups": groups},
                                                      indent=1))
    heading = {"heavy": "Heavy cover", "carried": "A box carried with the camera"}[args.family]
    md = [f"# {heading} over {args.seeds} seeds\n", machine_line(), "", args.title, "",
          table(groups, args.seeds), ""]
    (args.out / f"{stem}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
