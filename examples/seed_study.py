"""A seed study: the same sequence under 9 PRNG seeds in one vmapped, jitted call.

    python examples/seed_study.py

Every run is reproducible bit for bit from its seed; the spread of the ATE over seeds shows
how much the randomised hypothesis sampling matters.
"""

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
seq = jaxvo.make_sequence("fixed_camera_2", frames=45, seed=0)
flows = flows_for_sequence(seq, cfg)
grid = grid_shape(seq.height, seq.width, cfg.cell)
seeds = np.arange(9)  # as many as parameter_study.py's configurations: one compile serves both
keys = jnp.stack([jax.random.key(int(s)) for s in seeds])
params = batch_params(jaxvo.Params(), size=len(seeds))
T0 = jnp.asarray(seq.groundtruth.poses[0], jnp.float32)
outs = run_study(flows, keys, params, T0, cfg=cfg.step, grid=grid)

for s, poses in zip(seeds, np.asarray(outs.T_w_c)):
    traj = jaxvo.Trajectory(seq.timestamps, np.concatenate([seq.groundtruth.poses[:1], poses]))
    ate = jaxvo.trajectory_scores(seq.groundtruth, traj)["ate_rmse_m"]
    print(f"seed {s}: ATE {ate * 1000:.2f} mm")
