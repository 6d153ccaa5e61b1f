"""Benchmark of the spatial stage: ``segment`` on a 640 x 480 image at 16 px cells (n = 1200).

Reports, on synthetic frames (camera motion plus two or three rigidly moving blocks, depth
1-3 m, 2 mm noise, 10 % invalid flow):

* the first call (trace + compile) apart from the steady state;
* steady-state median and quartiles of the per-frame time (``block_until_ready`` before every
  clock read; other work may share the cores, so medians, not means), with the default stop
  rules (mean entropy below ``s_min``, or no segment left to find) and with all ``H``
  hypothesis trips forced (``s_min = 0``: the worst case of the fixed-trip search);
* the default stop rules on real frames too (the grid flow of the first pairs of each real
  sequence under the data root, when present): real depth noise leaves more points outside
  every hypothesis, so the search there runs more trips than on the synthetic frames;
* the batched rigid fit (Horn quaternion by repeated squaring) against a ``jnp.linalg.svd``
  Kabsch of the same fits, timed interleaved in the same run, as a ratio;
* the machine, JAX version and device.

Run: ``.venv/bin/python bench/bench_spatial.py [--frames 50] [--fits 4000] [--json out.json]``
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
from _common import load_average, machine, real_present

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.procrustes import fit_rigid
from jaxvo.core.spatial import segment
from jaxvo.host.frontend.flow import flows_for_sequence
from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence


def _rotation(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _unit(rng):
    d = rng.normal(size=3)
    return d / np.linalg.norm(d)


def make_frames(num, grid, seed=0):
    """``num`` synthetic point-pair frames with 2-3 rigid motions each."""
    rows, cols = grid
    rng = np.random.default_rng(seed)
    f = 525.0
    u = (np.arange(cols) + 0.5) * 16 - cols * 8
    v = (np.arange(rows) + 0.5) * 16 - rows * 8
    uu, vv = np.meshgrid(u, v)
    frames = []
    for _ in range(num):
        z = rng.uniform(1.0, 3.0, (rows, cols))
        prev = np.stack([uu * z / f, vv * z / f, z], -1).reshape(-1, 3)
        label = np.zeros((rows, cols), int)
        for k in range(1, rng.integers(2, 4)):
            r0, c0 = rng.integers(0, rows - 8), rng.integers(0, cols - 10)
            label[r0 : r0 + rng.integers(6, 10), c0 : c0 + rng.integers(8, 12)] = k
        label = label.ravel()
        cur = np.empty_like(prev)
        for k in range(label.max() + 1):
            r = _rotation(rng.normal(size=3), rng.uniform(0.01, 0.05))
            # objects move 8-15 cm relative to the camera motion (clearly separable)
            t = rng.normal(0, 0.02, 3) + (k > 0) * rng.uniform(0.08, 0.15) * _unit(rng)
            cur[label == k] = prev[label == k] @ r.T + t
        cur += rng.normal(0, 0.002, cur.shape)
        valid = rng.uniform(size=len(prev)) > 0.1
        frames.append((prev.astype(np.float32), cur.astype(np.float32), valid))
    return frames


def real_frames(num, cfg):
    """The grid flow of the first ``num`` pairs of each real sequence present, as frames."""
    frames = []
    for name in real_present():
        flows = flows_for_sequence(InMemorySequence(open_sequence(data_root() / name), num + 1), cfg)
        for k in range(len(flows.valid)):
            valid = flows.valid[k] & (flows.status[k] == 0)
            frames.append((flows.pts_prev[k], flows.pts_cur[k], valid))
    return frames


def time_segment(fn, frames, params, reps):
    """First-call seconds and the steady per-frame times (seconds) over ``reps`` passes."""
    key = jax.random.key(0)
    t0 = time.perf_counter()
    jax.block_until_ready(fn(key, *frames[0], params))
    first = time.perf_counter() - t0
    times, segments = [], []  # segments found per frame (the frames hold 2 or 3 motions)
    for rep in range(reps):
        for i, (prev, cur, valid) in enumerate(frames):
            k = jax.random.fold_in(key, rep * len(frames) + i)
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(k, prev, cur, valid, params))
            times.append(time.perf_counter() - t0)
            segments.append(int(out.num_segments))
    return first, np.asarray(times), segments


def _kabsch_svd(src, dst, w):
    """Reference: weighted Kabsch with ``jnp.linalg.svd`` and the determinant correction."""
    ws = jnp.sum(w)
    ps = jnp.sum(w[:, None] * src, 0) / ws
    pd = jnp.sum(w[:, None] * dst, 0) / ws
    m = ((dst - pd) * w[:, None]).T @ (src - ps)
    u, _, vt = jnp.linalg.svd(m)
    d = jnp.sign(jnp.linalg.det(u @ vt))
    r = u @ jnp.diag(jnp.array([1.0, 1.0, 0.0]).at[2].set(d)) @ vt
    return r, pd - r @ ps


def bench_fits(num, points, reps, seed=1):
    rng = np.random.default_rng(seed)
    src = rng.uniform(-0.5, 0.5, (num, points, 3)) + np.array([0, 0, 2.0])
    q = rng.normal(size=(num, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w_, x, y, z = q.T
    rot = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w_ * z), 2 * (x * z + w_ * y)], -1),
            np.stack([2 * (x * y + w_ * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w_ * x)], -1),
            np.stack([2 * (x * z - w_ * y), 2 * (y * z + w_ * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    dst = np.einsum("bij,bnj->bni", rot, src) + rng.normal(0, 0.003, (num, points, 3))
    args = [jnp.asarray(a, jnp.float32) for a in (src, dst, np.ones((num, points)))]
    ours = jax.jit(jax.vmap(fit_rigid))
    svd = jax.jit(jax.vmap(_kabsch_svd))
    compile_s = {}
    for name, fn in (("horn", ours), ("svd", svd)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        compile_s[name] = time.perf_counter() - t0
    times = {"horn": [], "svd": []}
    for _ in range(reps):  # interleaved, so both see the same machine load
        for name, fn in (("horn", ours), ("svd", svd)):
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*args))
            times[name].append(time.perf_counter() - t0)
    r_ours = np.asarray(ours(*args)[0])[:, :3, :3]
    r_svd = np.asarray(svd(*args)[0])
    med = {k: float(np.median(v)) for k, v in times.items()}
    return {
        "fits": num,
        "points_per_fit": points,
        "horn_ms": med["horn"] * 1e3,
        "svd_ms": med["svd"] * 1e3,
        "svd_over_horn": med["svd"] / med["horn"],
        "max_rotation_difference": float(np.abs(r_ours - r_svd).max()),
        "compile_s": compile_s,
    }


def _summary(times):
    q1, med, q3 = np.percentile(times * 1e3, [25, 50, 75])
    return {"median_ms": med, "q1_ms": q1, "q3_ms": q3, "min_ms": float(times.min() * 1e3)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="distinct synthetic frames")
    ap.add_argument("--reps", type=int, default=3, help="passes over the frames")
    ap.add_argument("--fits", type=int, default=4000, help="batch of rigid fits to time")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args(argv)

    cfg = Config(num_hypotheses=20)
    grid = grid_shape(480, 640, cfg.cell)
    frames = make_frames(args.frames, grid)
    result = {"machine": machine(), "grid": list(grid), "n": grid[0] * grid[1]}
    result["config"] = {
        "num_hypotheses": cfg.num_hypotheses,
        "num_candidates": cfg.num_candidates,
        "sample_size": cfg.sample_size,
        "refine_iters": cfg.refine_iters,
        "cluster_refine_iters": cfg.cluster_refine_iters,
    }

    real = real_frames(args.frames, cfg)
    modes = [
        ("default_stop", frames, params_as_arrays(Params())),
        ("all_H_trips", frames, params_as_arrays(Params(s_min=0.0))),
    ]
    if real:
        modes.append(("real_frames", real, params_as_arrays(Params())))
    else:
        print(f"no real sequence under {data_root()}: real-frame timing skipped")
    # A fresh jit per mode: the first call of each really compiles.
    for mode, mode_frames, params in modes:
        fn = jax.jit(lambda *a, **k: segment(*a, **k), static_argnames=("cfg", "grid"))

        def run(key, prev, cur, valid, params, fn=fn):
            return fn(key, prev, cur, valid, params, cfg=cfg, grid=grid)

        first, times, segments = time_segment(run, mode_frames, params, args.reps)
        result[mode] = {
            "first_call_s": first,
            **_summary(times),
            "frames_timed": len(times),
            "segments_found": dict(zip(*np.unique(segments, return_counts=True))),
        }
        result[mode]["segments_found"] = {
            str(k): int(v) for k, v in result[mode]["segments_found"].items()
        }
    result["procrustes"] = bench_fits(args.fits, cfg.sample_size, reps=30)
    result["load_average_end"] = load_average()

    print(f"segment, grid {grid[0]}x{grid[1]} (n={result['n']}), H={cfg.num_hypotheses}")
    for mode, mode_frames, _ in modes:
        r = result[mode]
        print(
            f"  {mode:13s} compile {r['first_call_s']:.1f} s; steady median {r['median_ms']:.2f} ms"
            f" (q1 {r['q1_ms']:.2f}, q3 {r['q3_ms']:.2f}, min {r['min_ms']:.2f}) per frame;"
            f" segments {r['segments_found']} ({len(mode_frames)} frames)"
        )
    p = result["procrustes"]
    print(
        f"procrustes, {p['fits']} fits of {p['points_per_fit']} points: Horn {p['horn_ms']:.2f} ms,"
        f" jnp.linalg.svd Kabsch {p['svd_ms']:.2f} ms -> {p['svd_over_horn']:.1f}x faster"
        f" (max |R diff| {p['max_rotation_difference']:.1e})"
    )
    m = result["machine"]
    print(
        f"machine: {m['platform']}, {m['cpu_model']}, {m['cores']} cores, jax {m['jax']}"
        f" on {m['jax_devices']}, load {m['load_average_start']} -> {result['load_average_end']}"
    )
    if args.json:
        args.json.write_text(json.dumps(result, indent=2, default=float))


if __name__ == "__main__":
    main()
