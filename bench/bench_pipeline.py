"""End-to-end speed and memory of the odometry (issue 5's figures).

Measures, on this machine, with the first call (compile) apart from steady state:

1. streaming: ``Odometry.process`` per frame at 640x480, 16 px cells, H = 20 (flow on the
   host + the jitted per-frame step), median and p90 ms per frame; and the same with the
   pipelined ``Odometry.submit`` (the device step of a frame overlaps the next frame's flow);
2. the whole-sequence ``lax.scan`` from precomputed flow: frames per second;
3. peak memory of ``jaxvo run`` on a 300-frame sequence (7-Scenes from the data root when
   present, else a synthetic one written to a temporary folder), as the maximum resident set
   size that the ``jaxvo run`` process reports for itself.

Usage: ``python bench/bench_pipeline.py [--frames 120] [--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import SEVEN_SCENES, machine

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.flow import flows_for_sequence
from jaxvo.io import data_root
from jaxvo.odometry import Odometry
from jaxvo.pipeline import run_scan
from jaxvo.synth import make_sequence, write_sequence


def bench_streaming(frames: list, K, *, pipelined: bool = False, compiled: bool = False) -> dict:
    """Per-frame wall time of ``Odometry.process`` (latency: the frame's pose is back when
    the call returns), or of ``Odometry.submit`` (throughput: the call returns the previous
    frame's result while this frame's device step keeps running)."""
    odo = Odometry(K, cfg=Config(), seed=0)
    call = odo.submit if pipelined else odo.process
    times = []
    for f in frames:
        t0 = time.perf_counter()
        call(f.bgr, f.depth, f.timestamp)
        times.append(time.perf_counter() - t0)
    odo.flush()
    steady = np.asarray(times[3:]) * 1e3
    # the step compiles on the first pair's call; a second run in this process reuses it
    first = "first_pair_s_step_already_compiled" if compiled else "first_pair_s_compile_included"
    return {
        first: round(max(times[1:3]), 2),
        "median_ms_per_frame": round(float(np.median(steady)), 2),
        "p90_ms_per_frame": round(float(np.percentile(steady, 90)), 2),
        "frames": len(frames),
    }


def bench_scan(seq, cfg: Config, repeats: int = 5) -> dict:
    flows = flows_for_sequence(seq, cfg)
    flows = jax.tree.map(jnp.asarray, flows)
    grid = grid_shape(seq.height, seq.width, cfg.cell)
    p = params_as_arrays(Params())
    T0 = jnp.eye(4, dtype=jnp.float32)
    t0 = time.perf_counter()
    jax.block_until_ready(run_scan(flows, jax.random.key(0), p, T0, cfg=cfg, grid=grid))
    compile_s = time.perf_counter() - t0
    runs = []
    for r in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(run_scan(flows, jax.random.key(r), p, T0, cfg=cfg, grid=grid))
        runs.append(time.perf_counter() - t0)
    n = len(seq) - 1
    best, med = min(runs), float(np.median(runs))
    return {
        "pairs": n,
        "first_call_s_compile_included": round(compile_s, 2),
        "median_frames_per_second": round(n / med, 1),
        "best_frames_per_second": round(n / best, 1),
        "median_ms_per_frame": round(1e3 * med / n, 3),
    }


def bench_memory(tmp: str) -> dict:
    seq_dir = data_root() / SEVEN_SCENES
    if not (seq_dir / "rgb.txt").is_file():
        seq_dir = os.path.join(tmp, "synthetic_300")
        write_sequence(make_sequence("handheld_slow", frames=300, seed=0), seq_dir)
    out = os.path.join(tmp, "traj.txt")
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "jaxvo.cli", "run", str(seq_dir), "--out", out, "-q", "--json"],
        capture_output=True, text=True, check=False,
    )
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr)
    summary = json.loads(proc.stdout)
    return {
        "sequence": str(seq_dir),
        "frames": summary["frames"],
        # the child's own high-water mark (VmHWM): RUSAGE_CHILDREN would also count the
        # pages of this (large) process that the fork shares before exec
        "peak_rss_mib": summary["peak_rss_mib"],
        "wall_s": round(wall, 1),
        "frames_per_second_reported": summary["frames_per_second"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=120, help="synthetic frames for 1 and 2")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()

    seq = make_sequence("handheld_slow", frames=args.frames, seed=0)
    frames = [seq[i] for i in range(len(seq))]  # rendered up front: not part of the timing
    res = {"machine": machine()}
    print("machine:", res["machine"], flush=True)
    res["streaming"] = bench_streaming(frames, seq.intrinsics)
    print("streaming, process (flow + jitted step per frame):", res["streaming"], flush=True)
    res["streaming_pipelined"] = bench_streaming(frames, seq.intrinsics, pipelined=True,
                                                 compiled=True)
    print("streaming, submit (pipelined, results one frame late):", res["streaming_pipelined"],
          flush=True)
    res["scan"] = bench_scan(seq, Config())
    print("whole-sequence scan from precomputed flow:", res["scan"], flush=True)
    if not args.skip_memory:
        with tempfile.TemporaryDirectory() as tmp:
            res["memory"] = bench_memory(tmp)
        print("jaxvo run peak memory:", res["memory"], flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1)


if __name__ == "__main__":
    main()
