"""Benchmark of the streaming grid-flow front end (jaxvo.host.frontend.flow.GridFlowTracker).

Times ``push`` (one new frame = one pair: grey conversion, depth refinement, forward and
backward LK, similarity, depth lookup, back-projection) on real 640x480 frames from the
shared data, or a generated textured pan if absent. The first pair is reported apart from
the steady state. Other processes share the cores, so the figures are medians / p90 over
many pairs, and the load average is printed next to them.

    .venv/bin/python bench/bench_flow.py [--threads N] [--pairs 200] [--thesis-lk]
        [--baseline OLD_FLOW_PY]

``--baseline`` times another version of jaxvo/host/frontend/flow.py in the same run, e.g.
``git show HEAD~1:jaxvo/host/frontend/flow.py > flow_old.py``: each version streams in its own
process (its own heap: page faults cost ~2.7 us each here, and one version's allocations
must not cost the other faults), the two taking turns every 10 pairs.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import multiprocessing
import os
import resource
import time

import cv2
import numpy as np
from _common import machine_line, real_present

from jaxvo.config import Config
from jaxvo.host.frontend.camera import Intrinsics, read_camera_file
from jaxvo.host.frontend.flow import GridFlowTracker
from jaxvo.host.readers.io import data_root


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


def load_set(name: str, n_frames: int):
    """``(name, K, frames)`` of a real sequence, or of the generated pan."""
    if name == "generated_pan":
        return (name, *generated(n_frames))
    cam, frames = load_real(name, n_frames)
    return name, cam, frames


def load_tracker_class(path: str | None):
    """``GridFlowTracker`` of another flow.py (e.g. ``git show HEAD~3:jaxvo/host/frontend/flow.py``)."""
    if path is None:
        return GridFlowTracker
    spec = importlib.util.spec_from_file_location("baseline_flow", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.GridFlowTracker


class Streamer:
    """One tracker fed the frames in a loop (reset at each wrap), each pair timed."""

    def __init__(self, cls, K, frames, cfg: Config):
        h, w = frames[0][0].shape[:2]
        self.tracker = cls(K, cfg, height=h, width=w)
        self.frames = frames
        self.i = 0
        self.stats = {"first": None, "wall": [], "cpu": [], "faults": [], "valid": []}
        self.stats["n"] = self.tracker.n

    def step(self, pairs: int) -> None:
        """Push frames until ``pairs`` more steady-state pairs are timed."""
        s = self.stats
        goal = len(s["wall"]) + pairs
        while len(s["wall"]) < goal:
            img, depth = self.frames[self.i % len(self.frames)]
            if self.i % len(self.frames) == 0:
                self.tracker.reset()
            self.i += 1
            f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            t0, c0 = time.perf_counter(), time.thread_time()
            flow = self.tracker.push(img, depth)
            t1, c1 = time.perf_counter(), time.thread_time()
            f1 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            if flow is None:
                continue
            if s["first"] is None:
                s["first"] = (t1 - t0) * 1e3
                continue
            s["wall"].append((t1 - t0) * 1e3)
            s["cpu"].append((c1 - c0) * 1e3)
            s["faults"].append(f1 - f0)
            s["valid"].append(flow.valid.mean())


def _worker(conn, flow_py, name, n_frames, cfg, threads) -> None:
    """A Streamer in its own process, stepping when told: its own heap, so that one
    version's allocations cannot cost the other page faults."""
    if threads is not None:
        cv2.setNumThreads(threads)
    _, K, frames = load_set(name, n_frames)
    streamer = Streamer(load_tracker_class(flow_py), K, frames, cfg)
    while (pairs := conn.recv()) is not None:
        streamer.step(pairs)
        conn.send(True)
    conn.send(streamer.stats)


def run_against(name, n_frames, cfg, pairs, versions, threads, block: int = 10):
    """Stats of each flow.py in ``versions`` (None = this checkout), one process each,
    taking turns every ``block`` pairs so that they share the load of the moment."""
    ctx = multiprocessing.get_context("spawn")
    links = []
    for flow_py in versions:
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=_worker, args=(child, flow_py, name, n_frames, cfg, threads))
        proc.start()
        links.append((parent, proc))
    for _ in range(0, pairs, block):
        for parent, _ in links:
            parent.send(block)
            parent.recv()
    stats = []
    for parent, proc in links:
        parent.send(None)
        stats.append(parent.recv())
        proc.join()
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
        help="also time the GridFlowTracker of this flow.py, taking turns (own processes)",
    )
    args = ap.parse_args()
    if args.baseline and not os.path.isfile(args.baseline):
        ap.error(f"--baseline: no such file: {args.baseline}")
    if args.pairs < 1 or args.frames < 2:
        ap.error("--pairs must be at least 1 and --frames at least 2")
    if args.threads is not None:
        cv2.setNumThreads(args.threads)

    print(f"machine     {machine_line()}")
    print(f"opencv      {cv2.__version__}  threads {cv2.getNumThreads()}")
    print(f"load avg    {' '.join(f'{x:.2f}' for x in os.getloadavg())} (before)")

    names = real_present()
    names = names or ["generated_pan"]

    configs = [("default", Config())]
    if args.thesis_lk:
        configs.append(("thesis LK 21/3", dataclasses.replace(Config(), lk_window=21, lk_levels=3)))
    print(
        f"\n{'sequence':32s} {'config':26s} {'n':>5s} {'first':>7s} {'median':>7s} "
        f"{'p90':>7s} {'cpu med':>7s} {'faults':>6s} {'valid':>6s}   (ms per frame pair)"
    )
    for name in names:
        for label, cfg in configs:
            if args.baseline:
                tags = ["", " (baseline)"]
                stats = run_against(
                    name, args.frames, cfg, args.pairs, [None, args.baseline], args.threads
                )
            else:
                tags = [""]
                _, K, frames = load_set(name, args.frames)
                streamer = Streamer(GridFlowTracker, K, frames, cfg)
                streamer.step(args.pairs)
                stats = [streamer.stats]
            for tag, s in zip(tags, stats):
                wall = np.array(s["wall"])
                print(
                    f"{name:32s} {label + tag:26s} {s['n']:5d} {s['first']:7.2f} "
                    f"{np.median(wall):7.2f} {np.percentile(wall, 90):7.2f} "
                    f"{np.median(s['cpu']):7.2f} {np.mean(s['faults']):6.0f} "
                    f"{np.mean(s['valid']):6.3f}"
                )
            if len(stats) > 1:
                ratio = np.median(stats[0]["wall"]) / np.median(stats[1]["wall"])
                print(f"{'':32s} {'median / baseline':26s} {ratio:18.2f}")
    print(f"load avg    {' '.join(f'{x:.2f}' for x in os.getloadavg())} (after)")
    print("cpu med     CPU time of the calling thread: all of it with --threads 1 only")
    print("faults      minor page faults per pair (mean): ~2.7 us each on this VM")
    print("target      <= 5 ms per pair at 640x480, 16 px cells (1200 points)")


if __name__ == "__main__":
    main()
