"""A parameter study in one vmapped call against the same configurations run one by one.

One synthetic sequence (grid flow computed once on the host), B configurations over seeds,
lambda (thesis eq. 3.1) and the grid model's max_age: ``jaxvo.pipeline.run_study`` (one
jit-compiled ``vmap`` over the whole-sequence scan) against ``run_scan`` called B times in
a Python loop. Both are compiled before timing (compile times reported apart); steady-state
times are medians of ``--repeats`` runs. Throughput = configurations x frame pairs per
second. To show where the time goes, the vmapped call is also timed at B = 1, 2, 4, ...

Run: ``.venv/bin/python bench/bench_study.py [--frames 60] [--batch 8] [--out results/]``
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import load_average, machine

from jaxvo.config import Config, Params, grid_shape
from jaxvo.flow import flows_for_sequence
from jaxvo.pipeline import batch_params, run_scan, run_study
from jaxvo.synth import make_sequence

LAMBDAS = (3e2, 1e3, 3e3, 1e4)
MAX_AGES = (15.0, 30.0)


def configurations(batch: int):
    """Seeds 0..B-1 crossed with cycling lambda and max_age values."""
    seeds = np.arange(batch)
    lam = [LAMBDAS[b % len(LAMBDAS)] for b in range(batch)]
    age = [MAX_AGES[(b // len(LAMBDAS)) % len(MAX_AGES)] for b in range(batch)]
    keys = jax.vmap(jax.random.key)(jnp.asarray(seeds))
    return seeds, lam, age, keys, batch_params(Params(), lam=lam, max_age=age)


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def timed_compile(jitted, *args, **static):
    t0 = time.perf_counter()
    exe = jitted.lower(*args, **static).compile()
    return exe, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames of the sequence (default 60)")
    ap.add_argument("--batch", type=int, default=8, help="configurations B (default 8)")
    ap.add_argument("--scenario", default="handheld_slow", help="synthetic scenario")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs (median)")
    ap.add_argument("--no-scaling", action="store_true",
                    help="skip timing the vmapped call at smaller B")
    ap.add_argument("--out", default="results", help="folder for study.json / study.md")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = machine()
    cfg = Config()

    seq = make_sequence(args.scenario, frames=args.frames, seed=0)
    grid = grid_shape(seq.height, seq.width, cfg.cell)
    flows = jax.tree.map(jnp.asarray, flows_for_sequence(seq, cfg))
    T = int(flows.valid.shape[0])
    T0 = jnp.asarray(seq.groundtruth.poses[0], jnp.float32)
    B = args.batch
    seeds, lam, age, keys, params = configurations(B)
    one = [jax.tree.map(lambda a, b=b: a[b], params) for b in range(B)]
    print(f"{args.scenario}: {T} frame pairs, B = {B} configurations", flush=True)

    study, study_compile = timed_compile(run_study, flows, keys, params, T0, cfg=cfg, grid=grid)
    scan, scan_compile = timed_compile(run_scan, flows, keys[0], one[0], T0, cfg=cfg, grid=grid)
    print(f"compile: vmapped {study_compile:.1f} s, single scan {scan_compile:.1f} s",
          flush=True)

    outs_v = jax.block_until_ready(study(flows, keys, params, T0))  # warm-up
    outs_l = [jax.block_until_ready(scan(flows, keys[b], one[b], T0)[1]) for b in range(B)]
    # same configurations, same answers (up to float reassociation under vmap)
    pose_diff = max(float(jnp.max(jnp.abs(outs_v.T_w_c[b][:, :3, 3] - outs_l[b].T_w_c[:, :3, 3])))
                    for b in range(B))

    t_vmap = median_time(lambda: study(flows, keys, params, T0), args.repeats)
    t_loop = median_time(lambda: [scan(flows, keys[b], one[b], T0) for b in range(B)],
                         args.repeats)
    thr_v, thr_l = B * T / t_vmap, B * T / t_loop
    ratio = thr_v / thr_l
    print(f"vmapped: {t_vmap:.2f} s = {thr_v:.1f} config-frames/s; loop: {t_loop:.2f} s = "
          f"{thr_l:.1f} config-frames/s; ratio {ratio:.2f}x", flush=True)

    scaling = []
    if not args.no_scaling:
        b = 1
        while b < B:
            _, _, _, k_b, p_b = configurations(b)
            exe, c = timed_compile(run_study, flows, k_b, p_b, T0, cfg=cfg, grid=grid)
            exe(flows, k_b, p_b, T0)
            t = median_time(lambda exe=exe, k_b=k_b, p_b=p_b: exe(flows, k_b, p_b, T0),
                            args.repeats)
            scaling.append({"B": b, "seconds": t, "config_frames_per_s": b * T / t,
                            "compile_s": c})
            print(f"  vmapped B = {b}: {t:.2f} s ({b * T / t:.1f} config-frames/s)", flush=True)
            b *= 2
        scaling.append({"B": B, "seconds": t_vmap, "config_frames_per_s": thr_v,
                        "compile_s": study_compile})

    info["load_average_end"] = load_average()
    res = {
        "machine": info, "scenario": args.scenario, "frames": args.frames, "pairs": T,
        "batch": B, "seeds": seeds.tolist(), "lam": lam, "max_age": age,
        "repeats": args.repeats,
        "vmapped": {"seconds": t_vmap, "config_frames_per_s": thr_v,
                    "compile_s": study_compile},
        "loop": {"seconds": t_loop, "config_frames_per_s": thr_l, "compile_s": scan_compile},
        "ratio": ratio, "target_ratio": 5.0, "max_position_diff_m": pose_diff,
        "scaling": scaling,
    }
    (out / "study.json").write_text(json.dumps(res, indent=1))
    L = ["# Parameter study: one vmapped call vs a loop of scans", "",
         (f"Sequence: synthetic `{args.scenario}`, {args.frames} frames ({T} pairs), grid "
         f"{grid[0]} x {grid[1]}. B = {B} configurations: seeds {seeds.tolist()}, lambda "
         f"{lam}, max_age {age}. Machine: {info['cpu_model']}, {info['cores']} cores, JAX "
         f"{info['jax']} ({info['jax_backend']}); load average {info['load_average_start']} "
         f"at start, {info['load_average_end']} at end. Medians of {args.repeats} runs, "
         "compile apart."), "",
         "| | seconds (steady) | config x frames / s | compile [s] |", "|---|---|---|---|",
         f"| vmapped `run_study` | {t_vmap:.2f} | {thr_v:.1f} | {study_compile:.1f} |",
         f"| loop of `run_scan` | {t_loop:.2f} | {thr_l:.1f} | {scan_compile:.1f} |", "",
         (f"Ratio vmapped / loop throughput: **{ratio:.2f}x** (target 5x). Largest position "
         f"difference between the two for the same configuration: {pose_diff:.2e} m."), ""]
    if scaling:
        L += [("Vmapped call against B (where the time goes: a per-configuration cost that "
              "stays flat as B grows means vmap batches no work away on this machine):"), "",
              "| B | seconds | config x frames / s | s per configuration |", "|---|---|---|---|"]
        L += [f"| {s['B']} | {s['seconds']:.2f} | {s['config_frames_per_s']:.1f} | "
              f"{s['seconds'] / s['B']:.3f} |" for s in scaling]
        L += [""]
    (out / "study.md").write_text("\n".join(L))
    print(f"wrote {out / 'study.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
