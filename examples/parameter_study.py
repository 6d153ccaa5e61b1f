"""A parameter study: the grid model's maximum age and the confidence of the noise-model
tests (inliers, minimal samples, the moving report), swept in one vmapped, jit-compiled
call, scored against ground truth.

    python examples/parameter_study.py
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np

import jaxvo
from jaxvo.config import grid_shape
from jaxvo.core.pipeline import batch_params, run_study
from jaxvo.host.frontend.flow import flows_for_sequence
from jaxvo.host.services.compile_cache import setup_compile_cache

setup_compile_cache()  # later runs load the compiled programs (~20 s saved)
cfg = jaxvo.Config()
seq = jaxvo.make_sequence("fixed_camera_1", frames=60, seed=0)
flows = flows_for_sequence(seq, cfg)
grid = grid_shape(seq.height, seq.width, cfg.cell)
combos = list(itertools.product([5.0, 15.0, 30.0], [0.95, 0.99, 0.999]))
params = batch_params(jaxvo.Params(), max_age=[a for a, _ in combos],
                            confidence=[c for _, c in combos])
keys = jnp.stack([jax.random.key(0)] * len(combos))
T0 = jnp.asarray(seq.groundtruth.poses[0], jnp.float32)
outs = run_study(flows, keys, params, T0, cfg=cfg.step, grid=grid)

print(f"{'max_age':>8} {'confidence':>11} {'ATE [mm]':>9} {'F-measure':>10}")
for b, (age, conf) in enumerate(combos):
    poses = np.concatenate([seq.groundtruth.poses[:1], np.asarray(outs.T_w_c[b])])
    ate = jaxvo.trajectory_scores(seq.groundtruth, jaxvo.Trajectory(seq.timestamps, poses))
    seg = jaxvo.segmentation_scores(seq, np.asarray(outs.moving[b]), cfg.cell)
    print(f"{age:8.0f} {conf:11.3f} {ate['ate_rmse_m'] * 1000:9.2f} {seg.f_measure:10.3f}")
