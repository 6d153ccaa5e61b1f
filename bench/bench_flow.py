"""Benchmark of the streaming grid-flow front end (jaxvo.flow.GridFlowTracker).

Times ``push`` (one new frame = one pair: grey conversion, depth refinement, forward and
backward LK, similarity, depth lookup, back-projection) on real 640x480 frames from the
shared data, or a generated textured pan if absent. The first pair is reported apart from
the steady state. Other processes share the cores, so the figures are medians / p90 over
many pairs, and the load average is printed next to them.

    .venv/bin/python bench/bench_flow.py [--threads N] [--pairs 200] [--thesis-lk]
        [--baseline OLD_FLOW_PY]

``--baseline`` times another version of jaxvo/flow.py in the same run, the two trackers
taking each frame in turn, e.g. ``git show HEAD~1:jaxvo/flow.py > /tmp/flow_old.py``.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import os
import time

import cv2
import numpy as np
from _common import machine_line

from jaxvo.camera import Intrinsics, read_camera_file
from jaxvo.config import Config
from jaxvo.flow import GridFlowTracker
from jaxvo.io import data_root

SEQUENCES = ("tum_fr3_walking_halfsphere_50", "7scenes_static_0000_0299")


def load_real(name: str, limit: int):
    root = data_root() / name
    if not (root / "associations.txt").is_file():
        return None
    cam = read_camera_file(root / "camera.txt")
    rows = [r.split() for r in (root / "associations.txt").read_text().splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")][:limit]
    frames = []
    for r in rows:
        img = cv2.imread(str(root / r[1]), cv2.IMREAD_COLOR)
        depth = cv2.imread(str(root / r[3]), cv2.IMREAD_UNCHANGED).astype(np.float32)
        frames.append((img, depth / np.float32(cam.depth_scale)))
    return cam, frames


def generated(n: int):
    """A smooth random texture panning 1.5 px per frame over a 2 m plane."""
    rng = np.random.default_rng(0)
    h, w = 480, 640
    big = cv2.resize(rng.standard_normal((60, 100)).astype(np.float32), (w + 400, h))
    big += 0.5 * cv2.resize(rng.standard_normal((240, 520)).astype(np.float32), (w + 400, h))
    big = cv2.normalize(big, None, 20, 235, cv2.NORM_MINMAX).astype(np.uint8)
    frames = []
    for i in range(n):
        m = np.float32([[1, 0, -1.5 * i], [0, 1, 0]])
        g = cv2.warpAffine(big, m, (w, h), flags=cv2.INTER_LINEAR)
        frames.append((cv2.cvtColor(g, cv2.COLOR_GRAY2BGR), np.full((h, w), 2.0, np.float32)))
    return Intrinsics(525.0, 525.0, 319.5, 239.5), frames


def load_tracker_class(path: str):
    """``GridFlowTracker`` of another flow.py (e.g. ``git show HEAD~3:jaxvo/flow.py``)."""
    spec = importlib.util.spec_from_file_location("baseline_flow", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.GridFlowTracker


def run(K, frames, cfg: Config, pairs: int, classes) -> list[dict]:
    """Stream frames (looping, with a reset at each wrap) until ``pairs`` pairs are timed.

    Each frame goes to one tracker of every class in ``classes`` in turn, so that they
    share the load of the moment and their medians compare.
    """
    h, w = frames[0][0].shape[:2]
    trackers = [cls(K, cfg, height=h, width=w) for cls in classes]
    stats = [{"first": None, "wall": [], "cpu": [], "valid": [], "n": t.n} for t in trackers]
    i = 0
    while len(stats[0]["wall"]) < pairs:
        img, depth = frames[i % len(frames)]
        for tracker, s in zip(trackers, stats):
            if i % len(frames) == 0:
                tracker.reset()
            t0, c0 = time.perf_counter(), time.thread_time()
            flow = tracker.push(img, depth)
            t1, c1 = time.perf_counter(), time.thread_time()
            if flow is None:
                continue
            if s["first"] is None:
                s["first"] = (t1 - t0) * 1e3
                continue
            s["wall"].append((t1 - t0) * 1e3)
            s["cpu"].append((c1 - c0) * 1e3)
            s["valid"].append(flow.valid.mean())
        i += 1
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None, help="cv2.setNumThreads (default: keep)")
    ap.add_argument("--pairs", type=int, default=200, help="timed pairs per sequence")
    ap.add_argument("--frames", type=int, default=50, help="frames read per sequence")
    ap.add_argument(
        "--thesis-lk", action="store_true", help="also time the thesis LK (window 21, 3 levels)"
    )
    ap.add_argument(
        "--baseline",
        metavar="FLOW_PY",
        help="also time the GridFlowTracker of this flow.py, interleaved pair by pair",
    )
    args = ap.parse_args()
    if args.threads is not None:
        cv2.setNumThreads(args.threads)

    print(f"machine     {machine_line()}")
    print(f"opencv      {cv2.__version__}  threads {cv2.getNumThreads()}")
    print(f"load avg    {' '.join(f'{x:.2f}' for x in os.getloadavg())} (before)")

    sets = []
    for name in SEQUENCES:
        got = load_real(name, args.frames)
        if got is not None:
            sets.append((name, *got))
    if not sets:
        sets.append(("generated_pan", *generated(args.frames)))

    configs = [("default", Config())]
    if args.thesis_lk:
        configs.append(("thesis LK 21/3", dataclasses.replace(Config(), lk_window=21, lk_levels=3)))
    classes = [("", GridFlowTracker)]
    if args.baseline:
        classes.append((" (baseline)", load_tracker_class(args.baseline)))
    print(
        f"\n{'sequence':32s} {'config':26s} {'n':>5s} {'first':>7s} {'median':>7s} "
        f"{'p90':>7s} {'cpu med':>7s} {'valid':>6s}   (ms per frame pair)"
    )
    for name, K, frames in sets:
        for label, cfg in configs:
            stats = run(K, frames, cfg, args.pairs, [cls for _, cls in classes])
            for (tag, _), s in zip(classes, stats):
                wall = np.array(s["wall"])
                print(
                    f"{name:32s} {label + tag:26s} {s['n']:5d} {s['first']:7.2f} "
                    f"{np.median(wall):7.2f} {np.percentile(wall, 90):7.2f} "
                    f"{np.median(s['cpu']):7.2f} {np.mean(s['valid']):6.3f}"
                )
            if len(stats) > 1:
                ratio = np.median(stats[0]["wall"]) / np.median(stats[1]["wall"])
                print(f"{'':32s} {'median / baseline':26s} {ratio:18.2f}")
    print(f"load avg    {' '.join(f'{x:.2f}' for x in os.getloadavg())} (after)")
    print("cpu med     CPU time of the calling thread: all of it with --threads 1 only")
    print("target      <= 5 ms per pair at 640x480, 16 px cells (1200 points)")


if __name__ == "__main__":
    main()
