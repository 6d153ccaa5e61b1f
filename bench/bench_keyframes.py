"""Keyframes and their local window (``Config.keyframes``, issues 27 and 39) against frame to
frame, over seeds, beside ORB-SLAM3.

Four settings on the same cached flows: keyframes off (the default), the latest keyframe
only (``keyframe_window=1``, issue 27's tracking), the local window (``keyframe_window``'s
default: the recent keyframes' poses and points refined together) and that window tracked
every pair (``keyframe_track_window``: every frame also fits the older keyframes' points).
Cases: all 300 shared 7-Scenes frames at every 1st, 2nd and 4th frame (issue 39's target
frames), and ``bench/splits.py``'s development and validation splits (static halves,
composites, the TUM walking clip). Every figure is the median [best-worst] over ``--seeds``
seeds (``bench_seeds.py``'s runner); ORB-SLAM3 (stand-in vocabulary, RGB-D) and the best
OpenCV peer are one run each on the same frames, from the peer cache. Then
``Odometry.process`` on the first ``--timing-frames`` 7-Scenes frames, each setting in
alternating runs (the first 5 frames of each apart), median ms a frame.

Run: ``.venv/bin/python bench/bench_keyframes.py [--split dev|val|all] [--seeds 5]
[--out results/] [--timing-frames 150]``; writes ``keyframes.md`` and ``keyframes.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, log, machine_line, markdown_table
from _options import check_options, count
from bench_robustness import prepare
from bench_seeds import score_case
from splits import Case, cases, runnable

from jaxvo.config import Config, Params
from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.odometry import Odometry

SETTINGS = {
    "off": Config(),
    "latest keyframe": Config(keyframes=True, keyframe_window=1),
    "window": Config(keyframes=True),
    # every pair also tracked against the window's older keyframes (issue 52's first step)
    "window tracked": Config(keyframes=True, keyframe_track_window=True),
}


def _all_frames(step: int) -> Case:
    def build():
        seq = InMemorySequence(open_sequence(data_root() / SEVEN_SCENES), step=step)
        seq.name = f"{SEVEN_SCENES}_every{step}"
        return seq
    return Case(f"static_all_every{step}", "target", "static", SEVEN_SCENES, build)


def process_ms(seq, frames: int, repeats: int = 2) -> dict:
    """Median ms a frame of ``Odometry.process`` for each setting, alternating runs."""
    times: dict[str, list] = {k: [] for k in SETTINGS}
    for _ in range(repeats):
        for name, cfg in SETTINGS.items():
            odo = Odometry(seq.intrinsics, cfg=cfg)
            ts = []
            for f in list(seq)[:frames]:
                t0 = time.perf_counter()
                odo.process(f.bgr, f.depth, f.timestamp)
                ts.append(time.perf_counter() - t0)
            times[name] += ts[5:]
    return {k: 1e3 * float(np.median(t)) for k, t in times.items()}


def _cell(row: dict) -> str:
    s = row.get("ate_mm") or row.get("distance_mm")
    return f"{s['median']:.1f} [{s['best']:.1f}-{s['worst']:.1f}]" if s else "-"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "val", "all"), default="all")
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--seeds", type=count(1), default=5)
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    ap.add_argument("--out", type=Path, default=Path("results"))
    ap.add_argument("--timing-frames", type=count(0), default=150)
    args = ap.parse_args(argv)
    splits = ("dev", "val") if args.split == "all" else (args.split,)
    todo = [_all_frames(k) for k in (1, 2, 4)] + [c for c in cases() if c.split in splits]
    check_options(ap, args, cases=[c.name for c in todo])
    todo = [c for c in todo if not args.only or c.name in args.only]
    todo, skipped = runnable(todo)
    rows: dict[str, dict] = {}
    for case in todo:
        rows[case.name] = {}
        for name, cfg in SETTINGS.items():
            row = score_case(case, prepare(case, args.cache, cfg), Params(), args.seeds,
                             args.cache, cfg)
            rows[case.name][name] = row
            log(f"{case.name} {name}: {_cell(row)}")
    timing = {}
    folder = data_root() / SEVEN_SCENES
    if args.timing_frames and folder.is_dir():
        log("Odometry.process timing")
        timing = process_ms(InMemorySequence(open_sequence(folder), frames=args.timing_frames),
                            args.timing_frames)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "keyframes.json").write_text(json.dumps(
        {"seeds": args.seeds, "settings": {k: c.as_dict() for k, c in SETTINGS.items()},
         "rows": rows, "process_ms": timing, "skipped": skipped}, indent=1))
    head = ["case"] + [f"{k} mm" for k in SETTINGS] + ["window / ORB-SLAM3", "ORB-SLAM3 mm",
                                                       "best OpenCV peer mm", "keyframes"]
    cells = []
    for name, r in rows.items():
        w = r["window"]
        orb = w.get("orbslam3_mm")
        ratio = f"{w['ate_mm']['median'] / orb:.2f}" if orb and "ate_mm" in w else "-"
        cells.append([name] + [_cell(r[k]) for k in SETTINGS]
                     + [ratio, f"{orb:.1f}" if orb else "-",
                        f"{w['best_peer_mm']:.1f}" if "best_peer_mm" in w else "-",
                        str(w.get("keyframes", "-"))])
    L = [f"# Keyframes and their local window over {args.seeds} seeds", "", machine_line(), "",
         ("ATE after rigid alignment, mm, median [best-worst] over the seeds (the TUM clip: "
          "the distance from its people-masked reference, computed with the same setting)."),
         "", markdown_table(head, cells), ""]
    if timing:
        L += [f"`Odometry.process`, median of 2 alternating runs over the first "
              f"{args.timing_frames} 7-Scenes frames, ms a frame: "
              + ", ".join(f"{k} {v:.2f}" for k, v in timing.items()) + ".", ""]
    L += [f"{k}: skipped, {v}" for k, v in skipped.items()]
    (args.out / "keyframes.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
