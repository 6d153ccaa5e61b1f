"""Render time of jaxvo.synth.scenes frames (640x480) on this machine: first call and steady state.

Usage: .venv/bin/python bench/bench_synth.py [--frames N] [--scenario NAME ...]

For each scenario it times, per frame, ``seq[i]`` (the full frame: ray cast, texture
look-up, shading, sensor model, copy to numpy) with the default sensor options and with
``SensorOptions.ideal()``. The first frame (JIT compile) is reported apart; the steady
state is the median (and 10th / 90th percentiles) of the wall time over the remaining
frames, because other processes share the cores; ``cpu ms`` is this process's CPU time per
frame (all threads), which contention inflates less. The budget is 20 ms a frame.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import machine_line

from jaxvo.synth import scenes as synth

BUDGET_MS = 20.0


def time_frames(seq) -> tuple[float, np.ndarray, np.ndarray]:
    """First frame (s), then wall and process-CPU ms per frame for the others."""
    t0 = time.perf_counter()
    seq[0]  # compile + first render; frames come back as numpy arrays (blocking)
    first = time.perf_counter() - t0
    wall, cpu = [], []
    for i in range(1, len(seq)):
        t0, c0 = time.perf_counter(), time.process_time()
        seq[i]
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return first, 1000.0 * np.array(wall), 1000.0 * np.array(cpu)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=121)
    parser.add_argument("--scenario", nargs="*", default=list(synth.SCENARIOS))
    args = parser.parse_args()
    print(f"machine: {machine_line()}")
    print(f"frames per run: {args.frames} (first apart, then {args.frames - 1} timed)")
    print(f"{'scenario':16s} {'options':8s} {'first s':>8s} {'median ms':>10s} "
          f"{'p10 ms':>7s} {'p90 ms':>7s} {'cpu ms':>7s}  budget {BUDGET_MS:.0f} ms (wall median)")
    medians = []
    for name in args.scenario:
        for label, opts in (("default", synth.SensorOptions()),
                            ("ideal", synth.SensorOptions.ideal())):
            seq = synth.make_sequence(name, frames=args.frames, seed=0, options=opts)
            first, ms, cpu = time_frames(seq)
            med = float(np.median(ms))
            medians.append(med)
            verdict = "ok" if med <= BUDGET_MS else "OVER"
            print(f"{name:16s} {label:8s} {first:8.2f} {med:10.2f} "
                  f"{np.percentile(ms, 10):7.2f} {np.percentile(ms, 90):7.2f} "
                  f"{np.median(cpu):7.2f}  {verdict}")
    print(f"all runs: median of medians {np.median(medians):.2f} ms, worst median "
          f"{max(medians):.2f} ms per 640x480 frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
