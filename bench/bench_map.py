"""The static map on real people, and what a Rerun recording costs a run (issue 35).

**People in the map.** jaxvo runs on the TUM walking clip (``--seeds`` seeds; the same
trajectory and dynamic cells ``jaxvo run --dynamic-masks`` gives for the seed), and the
clip's depth is fused into the static map (jaxvo's masks, :mod:`jaxvo.host.writers.mapping`) and the
map with nothing left out, from the same poses (with depth edges left out, both maps). A map point is *on the people* when, in
some frame, it projects into that frame's hand-drawn people mask (``bench/annotations``,
``bench/people_masks.py``) and lies on the surface the frame's depth sees there (within
max(5 cm, 5 % of its depth): a wall behind a person is not on the person). The figure:
people points of the static map over those of the full map (target at most 1/3), median
over seeds with the worst and best, and for each way of using the masks (as they are,
grown, the per-cube vote, both: the defaults), with the share of the map's other points the
static map keeps. The defaults were chosen on this clip (its development use only).

**Logging cost.** ``jaxvo run`` over the clip with and without ``--rerun-save``, alternated
``--reps`` times after one warm-up run (the step then loads from the compile cache): the
steady ms/frame of the summary (the main loop: the recording is encoded and logged on a
thread behind it) and the wall time of the whole process (the thread's work, the import of
rerun and the file's last writes included). Beside it, in one process: ``Odometry.submit``
over the preloaded frames with a logger attached and without, the logger's close included
(so every frame's logging is counted), the step compiled before.

Run: ``.venv/bin/python bench/bench_map.py [--seeds 5] [--reps 3] [--picture
docs/images/static_map.png] [--out results/]``; writes ``map.md`` and ``map.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import TUM_WALKING, load_average, log, machine_line, markdown_table
from people_masks import people_clip

from jaxvo.config import Config
from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.host.writers.mapping import GROW, VOTE_SHARE, fuse_maps, map_picture
from jaxvo.host.writers.masks import dynamic_pixels
from jaxvo.odometry import Odometry, run_sequence

# (name, grow pixels, vote share, depth edge): the ways of using jaxvo's masks compared
VARIANTS = (("masks as they are", 0, 1.0, 0.0), (f"grown {GROW} px", GROW, 1.0, 0.0),
            ("depth edges left out (5 %)", 0, 1.0, 0.05),
            (f"cube vote ({VOTE_SHARE})", 0, VOTE_SHARE, 0.0),
            ("grown and vote (defaults)", GROW, VOTE_SHARE, 0.0))


def on_people(pmap, seq, poses, people) -> np.ndarray:
    """(m,) bool: map points on a person's surface in some annotated frame."""
    K, hit = seq.intrinsics, np.zeros(len(pmap.points), bool)
    for i, T in poses:
        if i not in people:
            continue
        Ti = np.linalg.inv(T)
        c = pmap.points.astype(np.float64) @ Ti[:3, :3].T + Ti[:3, 3]
        z = np.where(c[:, 2] > 0.05, c[:, 2], np.inf)
        u = np.rint(K.fx * c[:, 0] / z + K.cx).astype(int)
        v = np.rint(K.fy * c[:, 1] / z + K.cy).astype(int)
        idx = np.nonzero((u >= 0) & (u < seq.width) & (v >= 0) & (v < seq.height))[0]
        d = seq[i].depth[v[idx], u[idx]]
        on = people[i][v[idx], u[idx]] & (d > 0) & (
            np.abs(d - z[idx]) <= np.maximum(0.05, 0.05 * z[idx]))
        hit[idx[on]] = True
    return hit


def seed_maps(seq, people, seed: int, picture: Path | None) -> list[dict]:
    """One seed: every variant's people points, static and full."""
    r = run_sequence(seq, seed=seed)
    cells = {int(f): r.outputs.dynamic[min(k, len(r.outputs.dynamic) - 1)]
             for k, f in enumerate(r.frames)}  # the last frame takes the last pair's cells

    def dynamic(index, timestamp):
        return (dynamic_pixels(cells[index], seq.height, seq.width, Config().cell)
                if index in cells else None)

    poses = [(int(f), T) for f, T in zip(r.frames, r.trajectory.poses)]
    rows = []
    for name, grow, share, edge in VARIANTS:
        maps = fuse_maps(seq, poses, dynamic, grow=grow, vote_share=share, edge=edge)
        s, f = on_people(maps.static, seq, poses, people), on_people(maps.full, seq, poses, people)
        rows.append({"seed": seed, "variant": name, "people_static": int(s.sum()),
                     "people_full": int(f.sum()), "ratio": float(s.sum() / max(f.sum(), 1)),
                     "points_static": len(s), "points_full": len(f),
                     "others_kept": float((~s).sum() / max((~f).sum(), 1))})
        if picture is not None and name.endswith("(defaults)"):
            import cv2

            picture.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(picture), map_picture(maps, seq.intrinsics, poses[0][1],
                                                  seq.height, seq.width),
                        [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return rows


def cli_run(folder: Path, out: Path, rrd: Path | None) -> dict:
    """One ``jaxvo run`` process: steady ms/frame of its summary and its wall time."""
    cmd = [sys.executable, "-m", "jaxvo.cli.main", "run", str(folder), "--out",
           str(out / "traj.txt"), "-q", "--json"]
    cmd += ["--rerun-save", str(rrd)] if rrd else []
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    summary = json.loads(done.stdout)
    return {"ms_per_frame": 1e3 / summary["frames_per_second"], "wall_s": wall,
            "rrd_mib": rrd.stat().st_size / 2**20 if rrd else 0.0}


def in_process(seq, logger_path: Path | None) -> float:
    """ms/frame of ``Odometry.submit`` over the frames, a logger's close included."""
    logger = None
    if logger_path is not None:
        from jaxvo.host.writers.recording import RerunLogger

        logger = RerunLogger(save=logger_path)
    odo = Odometry(seq.intrinsics, logger=logger)
    t0 = time.perf_counter()
    for f in seq:
        odo.submit(f.bgr, f.depth, f.timestamp)
    odo.flush()
    if logger is not None:
        logger.close()
    return 1e3 * (time.perf_counter() - t0) / len(seq)


def logging_cost(folder: Path, seq, reps: int) -> dict:
    """The CLI and in-process timings, alternated, with and without the recording."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cli_run(folder, tmp, None)  # warm-up: the step into the compile cache
        in_process(seq, None)  # the step compiled in this process
        runs = {"off": [], "on": []}
        inproc = {"off": [], "on": []}
        for rep in range(reps):
            runs["off"].append(cli_run(folder, tmp, None))
            runs["on"].append(cli_run(folder, tmp, tmp / "run.rrd"))
            inproc["off"].append(in_process(seq, None))
            inproc["on"].append(in_process(seq, tmp / "odo.rrd"))
            log(f"rep {rep}: cli {runs['off'][-1]} / {runs['on'][-1]}; in process "
                f"{inproc['off'][-1]:.2f} / {inproc['on'][-1]:.2f} ms/frame")
    med = {k: {m: float(np.median([r[m] for r in v])) for m in v[0]} for k, v in runs.items()}
    return {"cli": med, "cli_runs": runs,
            "in_process_ms": {k: float(np.median(v)) for k, v in inproc.items()},
            "in_process_runs": inproc}


def report(rows: list[dict], cost: dict | None, frames: int, seeds: int) -> list[str]:
    """The Markdown report."""
    L = ["# The static map on real people, and what a Rerun recording costs", "",
         machine_line(), "",
         (f"TUM `{TUM_WALKING}`, {frames} frames, {seeds} seeds. People points: map points "
          "on a person's surface in some frame (hand-drawn masks, depth within max(5 cm, 5 "
          "%)); ratio: the static map's over the map with nothing left out (target <= "
          "1/3); others kept: the share of the other points the static map keeps."), ""]
    table = []
    for name, *_ in VARIANTS if rows else ():
        rs = [r for r in rows if r["variant"] == name]
        ratio = [r["ratio"] for r in rs]
        table.append([name, f"{np.median(ratio):.3f}", f"{max(ratio):.3f}",
                      f"{min(ratio):.3f}",
                      (f"{np.median([r['people_static'] for r in rs]):.0f} / "
                       f"{np.median([r['people_full'] for r in rs]):.0f}"),
                      f"{np.median([r['others_kept'] for r in rs]):.3f}"])
    if table:
        L += [markdown_table(["masks used", "ratio median", "worst", "best",
                              "people points static / full (median)", "others kept"], table),
              ""]
    if cost:
        c, ip = cost["cli"], cost["in_process_ms"]
        L += [markdown_table(
            ["", "off", "--rerun-save", "on / off"],
            [["jaxvo run steady ms/frame (summary)", f"{c['off']['ms_per_frame']:.2f}",
              f"{c['on']['ms_per_frame']:.2f}",
              f"{c['on']['ms_per_frame'] / c['off']['ms_per_frame']:.3f}"],
             ["jaxvo run process wall s", f"{c['off']['wall_s']:.2f}", f"{c['on']['wall_s']:.2f}",
              f"{c['on']['wall_s'] / c['off']['wall_s']:.3f}"],
             ["Odometry.submit ms/frame, close included", f"{ip['off']:.2f}", f"{ip['on']:.2f}",
              f"{ip['on'] / ip['off']:.3f}"]]), "",
              (f"Timed on `{cost['sequence']}`; the recording: {c['on']['rrd_mib']:.1f} MiB for "
               f"{cost['frames']} frames. Medians of {len(cost['cli_runs']['on'])} runs; load "
               f"average at the end {load_average()}."), ""]
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeded runs (default 5; 0: no map)")
    ap.add_argument("--reps", type=int, default=3, help="timed runs of each (default 3; 0: "
                    "no timing)")
    ap.add_argument("--timing-seq", default=TUM_WALKING, metavar="NAME",
                    help="the data root's sequence the logging is timed on (default the TUM "
                    "clip)")
    ap.add_argument("--picture", type=Path, default=None,
                    help="write seed 0's map picture (the defaults) here")
    ap.add_argument("--out", default="results", help="folder for map.md / map.json")
    args = ap.parse_args(argv)
    clip = people_clip("bench_map")
    if clip is None:
        return 0
    seq, people = clip
    seq = InMemorySequence(seq) if args.seeds else seq
    rows = []
    for s in range(args.seeds):
        rows += seed_maps(seq, people, s, args.picture if s == 0 else None)
        log(f"seed {s}: " + "; ".join(f"{r['variant']} {r['ratio']:.3f}"
                                      for r in rows[-len(VARIANTS):]))
    cost = None
    if args.reps:
        timed = data_root() / args.timing_seq
        tseq = InMemorySequence(open_sequence(timed))
        cost = logging_cost(timed, tseq, args.reps)
        cost.update(sequence=args.timing_seq, frames=len(tseq))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.json").write_text(json.dumps({"maps": rows, "logging": cost}, indent=1))
    L = report(rows, cost, len(seq), args.seeds)
    (out / "map.md").write_text("\n".join(L))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
