"""A parameter study in one vmapped call against the same configurations run one by one,
and the study split over 1, 2 and 4 devices.

One synthetic sequence (grid flow computed once on the host), B configurations over seeds,
lambda (thesis eq. 3.1) and the grid model's max_age: ``jaxvo.core.pipeline.run_study`` (one
jit-compiled ``vmap`` over the whole-sequence scan) against ``run_scan`` called B times in
a Python loop. Both are compiled before timing (compile times reported apart); steady-state
times are medians of ``--repeats`` runs. Throughput = configurations x frame pairs per
second. To show where the time goes, the vmapped call is also timed at B = 1, 2, 4, ...

Then the same B configurations as one call of ``jaxvo study``'s sharded runner
(``jaxvo.study.devices.run_call``: B / D configurations vmapped on each of D devices) for each D of
``--devices``, each in a fresh process whose CPU is split into D JAX devices
(``jax_num_cpu_devices``; on an accelerator, its devices as they are), the first call
(compile included) apart from the steady state, against the loop of scans above as a ratio.

Last, the batch ``jaxvo study`` chooses for a study of ``--sized`` configurations of the
sequence (``jaxvo.study.devices.call_batch``: 4 on the CPU; on an accelerator the widest call the
study fills and half the free memory holds) against each hand-picked batch of
``--curve``: configuration-frames/s of the whole study at each, and the chosen batch's
ratio to the best.

Run: ``.venv/bin/python bench/bench_study.py [--frames 60] [--batch 8] [--devices 1,2,4]
[--sized 4096 --curve 64,256,1024,4096] [--out results/]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import load_average, machine

from jaxvo.config import Config, Params, grid_shape
from jaxvo.core.pipeline import batch_params, run_scan, run_study
from jaxvo.study import runner as study

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


def sequence(scenario: str, frames: int, cfg: Config, cache: Path) -> study.SequenceData:
    """The benchmark's sequence and flow, through the study's flow cache (so the device
    workers read the flow the parent computed)."""
    s = study.SequenceSpec(scenario, scenario, None, frames, 0, 1, None)
    return study.sequence_data(s, cfg, cache)[0]


def worker(args) -> int:
    """One device count: the B configurations as sharded study calls; prints JSON."""
    cfg = Config()
    data = sequence(args.scenario, args.frames, cfg, Path(args.cache))
    T = len(data.timestamps) - 1
    B, D = args.batch, len(jax.devices())
    seeds, lam, age, _, _ = configurations(B)
    configs = [{"lam": lam[b], "max_age": age[b]} for b in range(B)]
    devices = study.study_devices()

    def call():
        return study.run_call(data, cfg, configs, [int(s) for s in seeds], devices=devices,
                              batch=B // D)

    t0 = time.perf_counter()
    first = call()
    first_s = time.perf_counter() - t0
    t = median_time(call, args.repeats)
    print(json.dumps({"devices": D, "device_kind": str(jax.devices()[0].device_kind),
                      "batch_per_device": B // D, "first_call_s": first_s, "seconds": t,
                      "config_frames_per_s": B * T / t,
                      "poses": np.asarray(first[0]).tolist()}))
    return 0


def device_runs(args, cache: Path) -> list[dict]:
    """:func:`worker` in a fresh process for each device count of ``--devices``."""
    runs = []
    for d in (int(x) for x in args.devices.split(",")):
        if args.batch % d:
            print(f"  {d} devices: skipped, B = {args.batch} does not split over them",
                  flush=True)
            continue
        env = {**os.environ}
        cmd = [sys.executable, __file__, "--worker", "--frames", str(args.frames), "--batch",
               str(args.batch), "--scenario", args.scenario, "--repeats", str(args.repeats),
               "--cache", str(cache)]
        if jax.default_backend() == "cpu":
            env["JAX_NUM_CPU_DEVICES"] = str(d)
        elif d != len(jax.devices()):
            print(f"  {d} devices: skipped, the accelerator has {len(jax.devices())}")
            continue
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"{d} devices failed: {done.stderr[-2000:]}")
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
        r = runs[-1]
        print(f"  {r['devices']} device(s), {r['batch_per_device']} configuration(s) each: "
              f"first call {r['first_call_s']:.1f} s, steady {r['seconds']:.2f} s = "
              f"{r['config_frames_per_s']:.1f} config-frames/s", flush=True)
    return runs


def batch_sizing(data: study.SequenceData, n: int, curve: str) -> dict:
    """A study of ``n`` configurations (seeds 0..n-1 at the default Params) at the batch
    ``jaxvo study`` chooses and at each hand-picked batch of ``curve``: the first call
    (compile) apart, then the whole study's configuration-frames/s."""
    cfg = Config()
    devices = study.study_devices()
    configs, seeds = [{}] * n, list(range(n))
    T = len(data.timestamps) - 1
    t0 = time.perf_counter()
    chosen = study.call_batch(data, cfg, configs, requested=None, devices=devices)
    sizing_s = time.perf_counter() - t0
    rows = []
    for b in sorted({chosen, *(int(x) for x in curve.split(",") if x)}):
        per_call = b * len(devices)
        t0 = time.perf_counter()
        study.run_call(data, cfg, configs[:per_call], seeds[:per_call], devices=devices, batch=b)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        for start in range(0, n, per_call):
            study.run_call(data, cfg, configs[start:start + per_call],
                           seeds[start:start + per_call], devices=devices, batch=b)
        took = time.perf_counter() - t0
        rows.append({"batch": b, "chosen": b == chosen, "first_call_s": first,
                     "seconds": took, "config_frames_per_s": n * T / took})
        print(f"  sized study, batch {b}{' (chosen)' if b == chosen else ''}: "
              f"{n * T / took:.0f} config-frames/s", flush=True)
    best = max(r["config_frames_per_s"] for r in rows)
    mine = next(r for r in rows if r["chosen"])
    return {"configurations": n, "devices": len(devices), "chosen": chosen,
            "sizing_s": sizing_s, "free_bytes": study.free_memory(devices[0]),
            "rows": rows, "ratio_to_best": mine["config_frames_per_s"] / best}


def sizing_table(s: dict) -> list[str]:
    free = "not reported" if s["free_bytes"] is None else f"{s['free_bytes'] / 2**30:.1f} GiB"
    L = [(f"A study of {s['configurations']} configurations on {s['devices']} device(s): "
          f"`jaxvo study` chose {s['chosen']} configurations per device and call (sizing "
          f"took {s['sizing_s']:.1f} s; free device memory {free}); its throughput is "
          f"**{s['ratio_to_best']:.2f}x** the best hand-picked batch's."),
         "", "| batch per device | first call [s] | whole study [s] | config x frames / s |",
         "|---|---|---|---|"]
    L += [f"| {r['batch']}{' (chosen)' if r['chosen'] else ''} | {r['first_call_s']:.1f} | "
          f"{r['seconds']:.2f} | {r['config_frames_per_s']:.0f} |" for r in s["rows"]]
    return L + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=60, help="frames of the sequence (default 60)")
    ap.add_argument("--batch", type=int, default=8, help="configurations B (default 8)")
    ap.add_argument("--scenario", default="handheld_slow", help="synthetic scenario")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs (median)")
    ap.add_argument("--no-scaling", action="store_true",
                    help="skip timing the vmapped call at smaller B")
    ap.add_argument("--devices", default="1,2,4",
                    help="device counts to split the study over (default 1,2,4; '' skips)")
    ap.add_argument("--out", default="results", help="folder for study.json / study.md")
    ap.add_argument("--sized", type=int, default=0,
                    help="configurations of the batch-sizing study (default 0: skipped)")
    ap.add_argument("--curve", default="",
                    help="hand-picked batches to time the sized study at, e.g. 64,256,1024")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--cache", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = machine()
    cfg = Config()

    cache = Path(tempfile.mkdtemp(prefix="bench_study_flows_"))
    data = sequence(args.scenario, args.frames, cfg, cache)
    grid = grid_shape(data.height, data.width, cfg.cell)
    flows = jax.tree.map(jnp.asarray, data.flows)
    T = int(flows.valid.shape[0])
    T0 = jnp.asarray(data.T_w_c0, jnp.float32)
    B = args.batch
    seeds, lam, age, keys, params = configurations(B)
    one = [jax.tree.map(lambda a, b=b: a[b], params) for b in range(B)]
    print(f"{args.scenario}: {T} frame pairs, B = {B} configurations", flush=True)

    static = dict(cfg=cfg.step, grid=grid)
    vmapped, study_compile = timed_compile(run_study, flows, keys, params, T0, **static)
    scan, scan_compile = timed_compile(run_scan, flows, keys[0], one[0], T0, **static)
    print(f"compile: vmapped {study_compile:.1f} s, single scan {scan_compile:.1f} s",
          flush=True)

    outs_v = jax.block_until_ready(vmapped(flows, keys, params, T0))  # warm-up
    outs_l = [jax.block_until_ready(scan(flows, keys[b], one[b], T0)[1]) for b in range(B)]
    # same configurations, same answers (up to float reassociation under vmap)
    pose_diff = max(float(jnp.max(jnp.abs(outs_v.T_w_c[b][:, :3, 3] - outs_l[b].T_w_c[:, :3, 3])))
                    for b in range(B))

    t_vmap = median_time(lambda: vmapped(flows, keys, params, T0), args.repeats)
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
            exe, c = timed_compile(run_study, flows, k_b, p_b, T0, **static)
            exe(flows, k_b, p_b, T0)
            t = median_time(lambda exe=exe, k_b=k_b, p_b=p_b: exe(flows, k_b, p_b, T0),
                            args.repeats)
            scaling.append({"B": b, "seconds": t, "config_frames_per_s": b * T / t,
                            "compile_s": c})
            print(f"  vmapped B = {b}: {t:.2f} s ({b * T / t:.1f} config-frames/s)", flush=True)
            b *= 2
        scaling.append({"B": B, "seconds": t_vmap, "config_frames_per_s": thr_v,
                        "compile_s": study_compile})

    devices = device_runs(args, cache) if args.devices else []
    positions = [np.asarray(r.pop("poses"))[..., :3, 3] for r in devices]
    for r, p in zip(devices, positions, strict=True):
        r["ratio_to_loop"] = r["config_frames_per_s"] / thr_l
        # the same configurations vmapped B / D at a time agree up to float rounding
        # (jaxvo study keeps the per-device batch fixed instead, and gets equal bits)
        r["max_position_diff_vs_first_m"] = float(np.max(np.abs(p - positions[0])))

    sizing = batch_sizing(data, args.sized, args.curve) if args.sized else None

    info["load_average_end"] = load_average()
    res = {
        "machine": info, "scenario": args.scenario, "frames": args.frames, "pairs": T,
        "batch": B, "seeds": seeds.tolist(), "lam": lam, "max_age": age,
        "repeats": args.repeats,
        "vmapped": {"seconds": t_vmap, "config_frames_per_s": thr_v,
                    "compile_s": study_compile},
        "loop": {"seconds": t_loop, "config_frames_per_s": thr_l, "compile_s": scan_compile},
        "ratio": ratio, "max_position_diff_m": pose_diff,
        "scaling": scaling, "devices": devices, "sizing": sizing,
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
         (f"Ratio vmapped / loop throughput: **{ratio:.2f}x**. Largest position "
         f"difference between the two for the same configuration: {pose_diff:.2e} m."), ""]
    if scaling:
        L += [("Vmapped call against B (where the time goes: a per-configuration cost that "
              "stays flat as B grows means vmap batches no work away on this machine):"), "",
              "| B | seconds | config x frames / s | s per configuration |", "|---|---|---|---|"]
        L += [f"| {s['B']} | {s['seconds']:.2f} | {s['config_frames_per_s']:.1f} | "
              f"{s['seconds'] / s['B']:.3f} |" for s in scaling]
        L += [""]
    if devices:
        L += [(f"The same B = {B} configurations as one call of `jaxvo study`'s sharded runner "
               "(`jaxvo.study.devices.run_call`, B / D configurations vmapped on each of D devices; "
               f"{'the CPU split into D JAX devices' if info['jax_backend'] == 'cpu' else ''}"
               "), each device count in a fresh process; steady state is the median of "
               f"{args.repeats} calls, the first call includes the compile:"), "",
              ("| devices | per device | first call [s] | steady [s] | config x frames / s | "
               "vs loop of scans | largest position difference to the first row [m] |"),
              "|---|---|---|---|---|---|---|"]
        L += [f"| {r['devices']} | {r['batch_per_device']} | {r['first_call_s']:.1f} | "
              f"{r['seconds']:.2f} | {r['config_frames_per_s']:.1f} | "
              f"{r['ratio_to_loop']:.2f}x | {r['max_position_diff_vs_first_m']:.1e} |"
              for r in devices]
        L += ["", ("The per-device batch differs between rows (B / D), and a vmapped batch of "
                   "another size may differ in the last bit; `jaxvo study` keeps the batch per "
                   "device fixed, so its numbers are the same bits on any device count "
                   "(`tests/test_study.py`).")]
        L += [""]
    if sizing:
        L += sizing_table(sizing)
    (out / "study.md").write_text("\n".join(L))
    print(f"wrote {out / 'study.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
