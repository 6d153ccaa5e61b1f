"""Benchmark of the temporal stage: one ``update_temporal`` on a 640 x 480 image, 16 px cells.

Times the first call (trace + compile) apart from the steady state, and reports the median
and quartiles of the per-frame time (other work may share the cores, so medians, not means).
Inputs: a background and three moving objects whose segment numbers the "spatial stage"
permutes every frame, 10 % invalid flow.

Run: ``.venv/bin/python bench/bench_temporal.py [--frames 200]``
"""

from __future__ import annotations

import argparse
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine_line

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.identifiers import identify, measured_labels
from jaxvo.core.temporal import TemporalInputs, init_temporal, update_temporal


class Seg(NamedTuple):
    labels: jax.Array  # (n,) int32
    sizes: jax.Array  # (max_segments,) int32
    num_segments: jax.Array  # () int32
    status: jax.Array  # () int32


def make_inputs(num, grid, cfg, seed=0):
    rows, cols = grid
    n = rows * cols
    rng = np.random.default_rng(seed)
    objects = [(4, 12, 3, 11, 1, 0), (15, 25, 20, 30, -1, 0), (5, 10, 28, 36, 0, 1)]
    out = []
    for k in range(num):
        lab = np.ones((rows, cols), np.int32)
        disp = np.zeros((rows, cols, 2), np.float32)
        disp[...] = rng.normal(0.0, 0.3, 2)  # small camera motion, pixels
        for j, (r0, r1, c0, c1, vx, vy) in enumerate(objects):
            dr, dc = (k * vy) % rows // 3, (k * vx) % cols // 3
            sl = (slice(r0 + dr, min(r1 + dr, rows)), slice(c0 + dc, min(c1 + dc, cols)))
            lab[sl] = j + 2
            disp[sl] = (vx * cfg.cell / 3, vy * cfg.cell / 3)
        perm = np.concatenate([[0], rng.permutation(len(objects) + 1) + 1]).astype(np.int32)
        lab = perm[lab].ravel()
        valid = rng.random(n) > 0.1
        lab = np.where(valid, lab, 0)
        sizes = np.bincount(lab, minlength=cfg.max_segments + 1)[1:].astype(np.int32)
        seg = Seg(
            jnp.asarray(lab),
            jnp.asarray(sizes),
            jnp.int32(np.count_nonzero(sizes)),
            jnp.int32(0),
        )
        out.append((seg, jnp.asarray(disp.reshape(n, 2)), jnp.asarray(valid)))
    return out


def temporal_frame(state, seg, disp, valid, params, *, cfg, grid):
    """One frame of the temporal stage: Algorithm 3's identifiers, then the update (no
    background choice, no segment explained by the ego-motion, no evidence)."""
    labels = measured_labels(seg, valid, cfg=cfg)
    inputs = TemporalInputs(labels, disp, valid,
                            segment_ids=identify(state.identifiers, labels, params, cfg=cfg),
                            explained=jnp.zeros((cfg.max_segments,), bool),
                            evidence_delta=jnp.zeros(valid.shape, jnp.float32))
    return update_temporal(state, inputs, params, cfg=cfg, grid=grid)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200, help="steady-state frames timed")
    args = ap.parse_args()

    cfg = Config()
    grid = grid_shape(480, 640, cfg.cell)
    params = params_as_arrays(Params())
    inputs = make_inputs(50, grid, cfg)
    step = jax.jit(temporal_frame, static_argnames=("cfg", "grid"))

    state = init_temporal(cfg=cfg, grid=grid)
    t0 = time.perf_counter()
    state, out = step(state, *inputs[0], params, cfg=cfg, grid=grid)
    jax.block_until_ready((state, out))
    compile_s = time.perf_counter() - t0

    times = []
    for k in range(args.frames):
        seg, disp, valid = inputs[(k + 1) % len(inputs)]
        t0 = time.perf_counter()
        state, out = step(state, seg, disp, valid, params, cfg=cfg, grid=grid)
        jax.block_until_ready((state, out))
        times.append(time.perf_counter() - t0)
    ms = np.asarray(times) * 1e3

    print("bench_temporal: update_temporal, one frame")
    print(f"  machine   {machine_line()} (shared cores: medians reported)")
    print(
        f"  grid      {grid[0]}x{grid[1]} (640x480, {cfg.cell} px), max_ids {cfg.max_ids}, "
        f"match_window {cfg.match_window}, max_segments {cfg.max_segments}"
    )
    print(f"  compile   {compile_s * 1e3:.0f} ms (first call: trace + compile + run)")
    q1, med, q3 = np.percentile(ms, [25, 50, 75])
    print(f"  steady    median {med:.3f} ms  (q1 {q1:.3f}, q3 {q3:.3f}, n={len(ms)})")


if __name__ == "__main__":
    main()
