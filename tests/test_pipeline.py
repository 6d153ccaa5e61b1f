"""The end-to-end pipeline: one compile per sequence, reproducibility, the three ways to run.

A short synthetic sequence is flowed once (module fixture) and reused; every jitted entry
point is compiled once for it.
"""


import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.pipeline import (
    batch_params,
    jit_step,
    run_scan,
    run_study,
)
from jaxvo.errors import InputError
from jaxvo.host.frontend.flow import flows_for_sequence
from jaxvo.odometry import Odometry, run_sequence
from jaxvo.status import Status
from jaxvo.synth.scenes import make_sequence

CFG = Config()
FRAMES = 12


@pytest.fixture(scope="module")
def seq():
    return make_sequence("handheld_slow", frames=FRAMES, seed=3)


@pytest.fixture(scope="module")
def flows(seq):
    return flows_for_sequence(seq, CFG)


@pytest.fixture(scope="module")
def scan_result(seq):
    return run_sequence(seq, cfg=CFG, seed=7)


@pytest.mark.slow
def test_scan_gives_one_pose_per_frame_and_finite(scan_result, seq):
    traj = scan_result.trajectory
    assert traj.poses.shape == (len(seq), 4, 4)
    assert np.all(np.isfinite(traj.poses))
    # the identifiers name an object exactly where the cells are reported moving
    outs = scan_result.outputs
    np.testing.assert_array_equal(np.asarray(outs.ids) >= 2, np.asarray(outs.moving))
    np.testing.assert_allclose(traj.poses[0], seq.groundtruth.poses[0], atol=1e-12)
    # every pose stays a rigid transform (R orthonormal to 1e-4, float32 chain)
    R = traj.poses[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-4)


@pytest.mark.slow
def test_scan_accuracy_is_near_what_was_measured_and_far_better_than_a_peer(scan_result, seq):
    """End to end against the exact ground truth, bounded near the measured figure (so a
    regression of a few tenths of a millimetre shows): ATE 0.16 mm measured (handheld_slow,
    12 frames, scene seed 3, run seed 7, 2-core CPU; 0.16 mm with run seed 0), bounded at
    0.5 mm; and relative to OpenCV's RGB-D odometry on the same frames (5.7 mm measured,
    jaxvo 0.028 of it), bounded at a tenth of it."""
    from jaxvo.evaluation.metrics import ate
    from jaxvo.host.readers.io import InMemorySequence
    from jaxvo.host.services.peers import run_peer

    jaxvo_ate = ate(seq.groundtruth, scan_result.trajectory).stats.rmse
    assert jaxvo_ate < 0.0005, jaxvo_ate
    peer = run_peer(InMemorySequence(seq), "opencv_rgbd")
    peer_ate = ate(seq.groundtruth, peer.trajectory).stats.rmse
    assert jaxvo_ate < 0.1 * peer_ate, (jaxvo_ate, peer_ate)


@pytest.mark.slow
def test_same_seed_same_trajectory_bit_for_bit(scan_result, seq):
    again = run_sequence(seq, cfg=CFG, seed=7)
    np.testing.assert_array_equal(again.trajectory.poses, scan_result.trajectory.poses)
    np.testing.assert_array_equal(again.outputs.ids, scan_result.outputs.ids)


@pytest.mark.slow
def test_streaming_matches_scan_and_compiles_once(scan_result, seq):
    gt = seq.groundtruth
    odo = Odometry(seq.intrinsics, cfg=CFG, seed=7, T_w_c0=gt.poses[0])
    before = jit_step._cache_size()
    results = [odo.process(frame.bgr, frame.depth, frame.timestamp) for frame in seq]
    assert jit_step._cache_size() - before <= 1  # one compile serves every frame
    # same per-frame keys and code: same labels, poses equal to float32 rounding (1e-4 m)
    np.testing.assert_allclose(odo.trajectory.poses, scan_result.trajectory.poses, atol=1e-4)
    # each pair's status as the scan gives it (the first frame has no pair: OK)
    assert results[0].status == Status.OK
    np.testing.assert_array_equal([int(r.status) for r in results[1:]],
                                  np.asarray(scan_result.outputs.status))
    # the step stays on the CPU (the default, also where an accelerator is present)
    assert odo.device.platform == "cpu"
    assert odo._state.T_w_c.devices() == {odo.device}


def test_streaming_device_by_name_and_a_clear_error_for_a_missing_one(seq):
    assert Odometry(seq.intrinsics, device="cpu").device.platform == "cpu"
    with pytest.raises(ValueError, match="no 'nosuchplatform' device here; available: .*cpu"):
        Odometry(seq.intrinsics, device="nosuchplatform")


def test_pipelined_submit_gives_the_results_of_process_one_frame_late(seq):
    frames = list(seq)[:6]
    sync = Odometry(seq.intrinsics, cfg=CFG, seed=3)
    want = [sync.process(f.bgr, f.depth, f.timestamp) for f in frames]
    piped = Odometry(seq.intrinsics, cfg=CFG, seed=3)
    got = [piped.submit(f.bgr, f.depth, f.timestamp) for f in frames]
    assert got[0] is None  # the first call only starts the pipeline
    got = got[1:] + [piped.flush()]
    assert piped.flush() is None  # nothing left pending
    for a, b in zip(want, got):
        assert (a.index, a.timestamp, a.status) == (b.index, b.timestamp, b.status)
        np.testing.assert_array_equal(a.T_w_c, b.T_w_c)
        np.testing.assert_array_equal(a.ids, b.ids)
    np.testing.assert_array_equal(sync.trajectory.poses, piped.trajectory.poses)
    # process() after submit() completes the pending frame first, in order
    piped.submit(frames[0].bgr, frames[0].depth, 9.0)
    r = piped.process(frames[1].bgr, frames[1].depth, 10.0)
    assert list(piped.trajectory.timestamps[-2:]) == [9.0, 10.0] and r.timestamp == 10.0


def test_a_setting_of_the_host_flow_compiles_the_step_no_more(seq):
    """Each side has its own options: the step's static argument is ``Config.step``, which
    an LK setting (the flow's, ``Config.flow``) leaves as it is, so an odometry with other
    LK settings runs the program the first one compiled (jax.jit's cache counts them)."""
    frames = list(seq)[:3]

    def run(cfg: Config) -> Odometry:
        odo = Odometry(seq.intrinsics, cfg=cfg)
        for f in frames:
            odo.process(f.bgr, f.depth, f.timestamp)
        return odo

    lk = Config(lk_window=13, lk_levels=3, lk_iters=20, fb_max=2.0, min_similarity=0.6)
    assert lk.flow != CFG.flow and lk.step == CFG.step  # what the count below relies on
    assert Config(num_hypotheses=10).step != CFG.step  # a step setting is the step's own
    first = run(CFG)
    compiled = jit_step._cache_size()
    second = run(lk)
    if hasattr(first._step, "_cache_size"):  # the step exported in the compile cache
        assert second._step is first._step and first._step._cache_size() == 1
    else:  # jit_step as it is (no flatbuffers, or the cache off)
        assert compiled >= 1 and jit_step._cache_size() == compiled


@pytest.mark.slow
def test_study_vmaps_seeds_and_params_and_matches_single_runs(flows, seq, scan_result):
    grid = grid_shape(seq.height, seq.width, CFG.cell)
    T0 = jnp.asarray(seq.groundtruth.poses[0], jnp.float32)
    keys = jnp.stack([jax.random.key(7), jax.random.key(7), jax.random.key(8)])
    params = batch_params(Params(), lam=[1e3, 1e4, 1e3])
    outs = run_study(flows, keys, params, T0, cfg=CFG.step, grid=grid)
    assert outs.T_w_c.shape == (3, FRAMES - 1, 4, 4)
    # configuration 0 is the default run: equal to the single scan within float32 rounding
    np.testing.assert_allclose(np.asarray(outs.T_w_c[0]), scan_result.outputs.T_w_c, atol=1e-4)
    single = run_scan(flows, jax.random.key(8), params_as_arrays(Params()), T0, cfg=CFG.step,
                      grid=grid)[1]
    np.testing.assert_allclose(np.asarray(outs.T_w_c[2]), np.asarray(single.T_w_c), atol=1e-4)


def test_batch_params_rejects_unknown_and_ragged():
    with pytest.raises(ValueError, match="unknown parameter"):
        batch_params(Params(), lamda=[1.0])
    with pytest.raises(ValueError, match="same length"):
        batch_params(Params(), lam=[1.0, 2.0], delta=[0.1])


def test_one_frame_sequence_is_a_clear_error():
    one = make_sequence("static", frames=1, seed=0)
    with pytest.raises(InputError, match="needs 2 or more"):
        run_sequence(one, cfg=CFG)


def test_streaming_drops_a_frame_of_another_size_and_pairs_across_it(seq):
    odo = Odometry(seq.intrinsics, cfg=CFG, seed=0)
    f0, f1, f2 = seq[0], seq[1], seq[2]
    odo.process(f0.bgr, f0.depth, f0.timestamp)
    bad = odo.process(f1.bgr[:100], f1.depth[:100], f1.timestamp)  # another size
    assert bad.status == Status.BAD_INPUT and "differs from the first frame" in bad.dropped
    np.testing.assert_array_equal(bad.T_w_c, np.eye(4))  # the last kept pose, repeated
    good = odo.process(f2.bgr, f2.depth, f2.timestamp)  # pairs with frame 0, the last good one
    assert good.status == Status.OK and good.dropped is None
    assert np.all(np.isfinite(good.T_w_c))
    # the dropped frame has no pose in the trajectory
    np.testing.assert_array_equal(odo.trajectory.timestamps, [f0.timestamp, f2.timestamp])


@pytest.mark.slow
def test_streaming_and_scan_drop_the_same_frame_and_agree(seq):
    """A black frame: both modes drop it (no pose), pair the next frame with the last good
    one and give the same poses (float32 rounding, 1e-4 m). One frame more than ``seq``
    (the same scene, whose frames do not depend on how many are asked), so that the frames
    kept make the scan of ``scan_result``'s length, which is compiled once for both."""
    longer = make_sequence("handheld_slow", frames=FRAMES + 1, seed=3)
    frames = list(longer)
    frames[3] = frames[3]._replace(bgr=np.zeros_like(frames[3].bgr))

    class Blacked:  # the frames with frame 3 black
        name, intrinsics, height, width = seq.name, seq.intrinsics, seq.height, seq.width
        timestamps = longer.timestamps
        groundtruth = None

        def __len__(self):
            return len(frames)

        def __getitem__(self, i):
            return frames[i]

    res = run_sequence(Blacked(), cfg=CFG, seed=7)
    assert list(res.dropped) == [3] and list(res.frames) == [0, 1, 2, *range(4, FRAMES + 1)]
    assert res.start_pose == "identity (no ground truth of the first frame)"
    odo = Odometry(seq.intrinsics, cfg=CFG, seed=7)
    for f in frames:
        odo.process(f.bgr, f.depth, f.timestamp)
    np.testing.assert_array_equal(odo.trajectory.timestamps, res.trajectory.timestamps)
    np.testing.assert_allclose(odo.trajectory.poses, res.trajectory.poses, atol=1e-4)


@pytest.mark.slow
def test_fast_real_motion_keeps_the_background_identified(require_data):
    """7-Scenes at every fourth frame (about 28 mm and 1.6 deg a frame, a third of the grid
    measured): the static scene's background stays matched to identifier 1 in every frame,
    no pair is skipped or re-acquires its background, and at most the issue's 1 % of the
    grid cells are reported moving (0 measured) and 2 % fall in the plug-in masks (0
    measured). Counting unmeasured retained cells in eq. (4.1) lost the match for 9 frames
    in a row here (frames 24-32) and called most cells moving."""
    from jaxvo.host.readers.io import InMemorySequence, open_sequence

    seq = InMemorySequence(open_sequence(require_data("7scenes_static_0000_0299")), 36, step=4)
    # streamed: the per-frame step every default `jaxvo run` on 640x480 frames compiles (a
    # scan of these 35 pairs would be a program of its own; the two agree, as tested above)
    odo = Odometry(seq.intrinsics, cfg=CFG, seed=0)
    outs = [odo.process(f.bgr, f.depth, f.timestamp).output for f in seq][1:]
    out = jax.tree.map(lambda *a: np.stack(a), *outs)
    background_seen = np.any(out.matched == 1, axis=1)
    assert background_seen.all(), np.flatnonzero(~background_seen)
    assert np.all(out.status == Status.OK) and not out.reacquired.any()
    assert out.moving.mean() <= 0.01, out.moving.mean()
    assert out.dynamic.mean() <= 0.02, out.dynamic.mean()


# ------------------------------------------------------------------ the step on hand-made flow
#
# A 12 x 16 grid of points: a background at 2.4-3.6 m moving as the camera's apparent
# motion CAM, and a box at 1.1-1.3 m on 100 of the 192 cells (more than half the view) that
# moves as OBJ from a given pair on; the model's noise (0.2 px across the ray, 3e-4 z^2
# along it per reading). The points keep their cells (no image motion), so the temporal
# compensation is the identity and the labels can be checked cell by cell.

GRID_S = (12, 16)
N_S = GRID_S[0] * GRID_S[1]
FOCAL_S = 250.0


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _pose(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


CAM = _pose(_rot([0.3, 1.0, 0.1], 0.01), [0.01, -0.005, 0.008])  # T_cur_prev of the scene
OBJ = _pose(_rot([1.0, 0.2, 0.0], 0.03), [0.04, 0.02, -0.02]) @ CAM  # the box, moving
_R, _C = np.arange(N_S) // GRID_S[1], np.arange(N_S) % GRID_S[1]
BOX = (_C < 10) & (_R >= 1) & (_R < 11)


def hand_flow(rng, box_moves, status=Status.OK, valid=True):
    from jaxvo.core.inputs import GridFlow

    uv = np.stack([(_C + 0.5) * CFG.cell, (_R + 0.5) * CFG.cell], 1)
    cx, cy = GRID_S[1] * CFG.cell / 2, GRID_S[0] * CFG.cell / 2
    z = np.where(BOX, 1.2 + 0.1 * np.cos(0.5 * _C), 3.0 + 0.6 * np.sin(0.7 * _C + 0.4 * _R))
    prev = np.stack([(uv[:, 0] - cx) * z / FOCAL_S, (uv[:, 1] - cy) * z / FOCAL_S, z], 1)
    T = np.where((BOX & box_moves)[:, None, None], OBJ, CAM)
    cur = np.einsum("nij,nj->ni", T[:, :3, :3], prev) + T[:, :3, 3]

    def along_ray(p):
        return p / np.linalg.norm(p, axis=1, keepdims=True) * rng.normal(size=(N_S, 1)) \
            * 3e-4 * p[:, 2:] ** 2

    ray = cur / np.linalg.norm(cur, axis=1, keepdims=True)
    across = rng.normal(size=(N_S, 3))
    across -= np.sum(across * ray, axis=1, keepdims=True) * ray
    cur = cur + along_ray(cur) + across * 0.2 * cur[:, 2:] / FOCAL_S
    prev = prev + along_ray(prev)
    return GridFlow(prev.astype(np.float32), cur.astype(np.float32), uv.astype(np.float32),
                    uv.astype(np.float32), np.full(N_S, valid), np.int32(status),
                    np.float32(FOCAL_S),
                    np.where(valid, prev[:, 2], 0.0).astype(np.float32),
                    np.array([FOCAL_S, FOCAL_S, 0.0, 0.0], np.float32),
                    np.zeros(N_S, np.float32), np.zeros(N_S, np.float32))


def run_hand(flows, seed=0):
    from jaxvo.core.pipeline import init_pipeline

    prm = params_as_arrays(Params())
    state = init_pipeline(cfg=CFG, grid=GRID_S, params=prm)
    outs = []
    for f in flows:
        state, out = jit_step(state, f, jax.random.key(seed), prm, cfg=CFG.step, grid=GRID_S)
        outs.append(jax.tree.map(np.asarray, out))
    return state, outs


@pytest.mark.slow
def test_a_failed_pair_carries_the_predicted_motion_never_a_frozen_camera():
    """A pair without a motion of its own (unreadable, or no valid flow) carries the last
    accepted ego-motion, bit for bit, and chains it into the pose; only before any motion
    exists is the carried motion the identity. The camera then ends within 5 mm of where
    it is (freezing it twice would leave it 28 mm off)."""
    rng = np.random.default_rng(0)
    bad = {"status": Status.BAD_INPUT}
    flows = [hand_flow(rng, False, **bad)] + [hand_flow(rng, False) for _ in range(3)] \
        + [hand_flow(rng, False, **bad), hand_flow(rng, False, valid=False)] \
        + [hand_flow(rng, False)]
    _, outs = run_hand(flows)
    status = [int(o.status) for o in outs]
    assert status == [Status.BAD_INPUT, 0, 0, 0, Status.BAD_INPUT, Status.TOO_FEW_FLOW, 0]
    np.testing.assert_array_equal(outs[0].T_cur_prev, np.eye(4))
    for k in (4, 5):
        np.testing.assert_array_equal(outs[k].T_cur_prev, outs[3].T_cur_prev)
        assert int(outs[k].background) == 0 and not bool(outs[k].reacquired)
        assert not outs[k].static.any()
    for k in range(1, 7):
        # the pose chain, float32: 1e-6
        np.testing.assert_allclose(outs[k].T_w_c,
                                   outs[k - 1].T_w_c @ np.linalg.inv(outs[k].T_cur_prev),
                                   atol=1e-6)
    for k in (1, 2, 3, 6):  # the accepted motions: within 3 mm (and 3 mrad) of the truth
        np.testing.assert_allclose(outs[k].T_cur_prev, CAM, atol=3e-3)
    truth = np.linalg.matrix_power(np.linalg.inv(CAM), 6)  # six pairs of motion after pair 0
    assert np.linalg.norm(outs[-1].T_w_c[:3, 3] - truth[:3, 3]) < 5e-3


@pytest.mark.parametrize("box_starts", [0, 3])
def test_a_box_over_half_the_view_never_takes_the_background(box_starts):
    """A box on 100 of 192 cells, nearer than the background: when it moves from the first
    pair, the background (more surface, z^2 per point) takes identifier 1 at once; when the
    first pairs merge it with the background (it stands still) and it then moves, its
    segment keeps identifier 1 by matching, and the background re-acquires it in that very
    pair (``reacquired``), which is not skipped. Every pair's motion is the camera's; the
    box, not the background, is reported moving once its evidence is significant."""
    rng = np.random.default_rng(1)
    flows = [hand_flow(rng, k >= box_starts) for k in range(8)]
    _, outs = run_hand(flows)
    for k, o in enumerate(outs):
        assert int(o.status) == Status.OK, k
        # within 3 mm / 3 mrad of the camera's motion (the box moves 4 cm and 30 mrad apart)
        np.testing.assert_allclose(o.T_cur_prev, CAM, atol=3e-3, err_msg=str(k))
        assert set(np.unique(o.matched[~BOX])) == {1}, k
        assert not o.moving[~BOX].any(), k
        if k >= box_starts:
            assert 1 not in set(np.unique(o.matched[BOX])), k
    reacquired = [bool(o.reacquired) for o in outs]
    assert reacquired == [k == box_starts and k > 0 for k in range(8)]
    assert outs[-1].moving[BOX].mean() > 0.9
    ids, moving = outs[-1].ids, outs[-1].moving
    np.testing.assert_array_equal(ids >= 2, moving)  # one notion of moving
    assert set(np.unique(ids[~BOX])) == {1}
    assert len(set(np.unique(ids[BOX & moving]))) == 1  # the box, by one identifier


# ------------------------------------------------------------------ the pieces of the step


def test_grow_moving_spreads_only_into_open_cells():
    """Against SciPy's 8-connected dilation restricted to the open (unmeasured, not
    established background) cells, for one and two steps."""
    from scipy import ndimage

    from jaxvo.core.pipeline import grow_moving

    rng = np.random.default_rng(12)
    grid = (12, 16)
    for trial in range(5):
        moving = rng.random(grid) < 0.05
        open_cells = rng.random(grid) < 0.4
        for steps in (1, 2):
            got = np.asarray(grow_moving(jnp.asarray(moving.ravel()),
                                         jnp.asarray(open_cells.ravel()), grid=grid,
                                         steps=steps)).reshape(grid)
            want = ndimage.binary_dilation(moving, structure=np.ones((3, 3), bool),
                                           iterations=steps, mask=open_cells | moving)
            np.testing.assert_array_equal(got, want, err_msg=f"{trial} {steps}")
    # a lone moving cell among measured cells stays alone
    moving = np.zeros(grid, bool)
    moving[5, 5] = True
    got = grow_moving(jnp.asarray(moving.ravel()), jnp.zeros(np.prod(grid), bool), grid=grid,
                      steps=1)
    np.testing.assert_array_equal(np.asarray(got).reshape(grid), moving)


def test_final_moving_is_the_final_evidence_above_the_confidence():
    from jaxvo.core.pipeline import final_moving, init_pipeline

    prm = params_as_arrays(Params())
    state = init_pipeline(cfg=CFG, grid=(2, 3), params=prm)
    ev = jnp.asarray([-6.0, 0.0, 4.5, 4.7, 6.0, 5.0], jnp.float32)
    state = state._replace(temporal=state.temporal._replace(evidence=ev))
    np.testing.assert_array_equal(np.asarray(final_moving(state, prm)),
                                  [False, False, False, True, True, True])


def test_the_noise_calibration_is_compiled_in_only_when_switched_on():
    """Config.noise_calibration off (the default): the step's program holds no calibration,
    whose two masked quantiles are a bisection loop (a scan) each; on, it holds them."""
    from jaxvo.core.pipeline import init_pipeline, step

    flow = hand_flow(np.random.default_rng(0), box_moves=True)
    prm = params_as_arrays(Params(noise_rate=0.5))
    loops = {}
    for on in (False, True):
        cfg = dataclasses.replace(CFG, noise_calibration=on)
        state = init_pipeline(cfg=cfg, grid=GRID_S, params=prm)
        jaxpr = jax.make_jaxpr(lambda s, f, k, p, cfg=cfg: step(s, f, k, p, cfg=cfg,
                                                                  grid=GRID_S))(
            state, flow, jax.random.key(0), prm)
        loops[on] = str(jaxpr).count("scan[")
    assert loops[True] == loops[False] + 2, loops
