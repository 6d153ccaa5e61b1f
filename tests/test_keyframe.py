"""Frame-to-keyframe tracking: jaxvo.core.keyframe (device) and its host tracker
(jaxvo.host.flow.KeyframeTracker), tested together because neither runs without the other."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_flow import CFG, H, K, W, bgr, plane, texture, warp

from jaxvo.config import Config, Params
from jaxvo.core.keyframe import init_keyframe, keyframe_points, update_keyframe
from jaxvo.core.noise import init_noise
from jaxvo.host.flow import FrameChain, GridFlowTracker
from jaxvo.odometry import Odometry, run_sequence
from jaxvo.synth.scenes import make_sequence

KF_CFG = dataclasses.replace(Config(), keyframes=True)


def _pose(rng) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, 0.5, 3)
    return T


def test_keyframe_points_are_the_keyframe_points_in_the_previous_camera():
    """src = inv(T_w_prev) T_w_kf p_kf in float64 numpy, to 1e-5 m; points not static or
    not valid are left out."""
    rng = np.random.default_rng(0)
    n = 50
    T_w_kf, T_w_prev = _pose(rng), _pose(rng)
    p_kf = rng.uniform([-1, -1, 1], [1, 1, 4], (n, 3))
    p_cur = rng.uniform([-1, -1, 1], [1, 1, 4], (n, 3))
    valid = rng.random(n) > 0.2
    static = rng.random(n) > 0.2
    state = init_keyframe(T_w_kf, n)._replace(static=jnp.asarray(static))
    kf = (jnp.asarray(p_kf, jnp.float32), jnp.asarray(p_cur, jnp.float32), jnp.asarray(valid))
    from jaxvo.host.flow import KeyframeFlow

    pts = keyframe_points(state, KeyframeFlow(*kf, jnp.bool_(False)),
                          jnp.asarray(T_w_prev, jnp.float32), Params(), focal=525.0,
                          scale=init_noise(Params()))
    want = (np.linalg.inv(T_w_prev) @ T_w_kf @ np.c_[p_kf, np.ones(n)].T)[:3]
    keep = valid & static
    np.testing.assert_array_equal(np.asarray(pts.valid), keep)
    np.testing.assert_allclose(np.asarray(pts.src)[:, keep], want[:, keep], atol=1e-5)
    np.testing.assert_allclose(np.asarray(pts.dst)[:, keep], p_cur.T[:, keep], atol=1e-6)


def test_update_keyframe_renews_only_when_told():
    n = 4
    st = init_keyframe(np.eye(4), n)
    T = np.eye(4, dtype=np.float32)
    T[0, 3] = 1.0
    static = jnp.asarray([True, False, True, False])
    same = update_keyframe(st, jnp.bool_(False), T, static)
    np.testing.assert_array_equal(np.asarray(same.T_w_kf), np.eye(4))
    assert bool(same.static.all()) and int(same.count) == 1
    new = update_keyframe(st, jnp.bool_(True), T, static)
    np.testing.assert_array_equal(np.asarray(new.T_w_kf), T)
    np.testing.assert_array_equal(np.asarray(new.static), np.asarray(static))
    assert int(new.count) == 2


@pytest.fixture(scope="module")
def shifted_frames():
    """A textured plane at 2 m seen while the view slides 12 px a frame to the left."""
    tex = texture(5)
    return [warp(tex, np.array([[1.0, 0, -12.0 * k], [0, 1, 0]])) for k in range(20)]


def test_tracker_follows_the_keyframe_and_renews_when_the_overlap_is_gone(shifted_frames):
    """Each keyframe point lands 12 px per frame since its keyframe to the left (to 0.1 px
    at the median, as 3-D points at 2 m); the keyframe is renewed once fewer than
    ``keyframe_overlap`` of its first pair's points are left, and only then."""
    cfg = dataclasses.replace(CFG, keyframes=True)
    chain = FrameChain(GridFlowTracker(K, cfg, height=H, width=W), min_valid=5, keyframes=True)
    assert chain.push(bgr(shifted_frames[0]), plane(2.0)) == (None, None)
    since, counts, renewals = 0, [], 0
    for img in shifted_frames[1:]:
        _, why = chain.push(bgr(img), plane(2.0))
        assert why is None
        kf = chain.keyframe_flow
        since += 1
        v = kf.valid
        assert v.sum() > 100
        dx = (kf.pts_cur[v, 0] - kf.pts_kf[v, 0]) * K.fx / 2.0  # pixels at 2 m
        assert abs(np.median(dx) + 12.0 * since) < 0.1, (since, np.median(dx))
        counts.append(int(v.sum()))
        if kf.renew:
            renewals += 1
            assert counts[-1] < cfg.keyframe_overlap * counts[-since]
            since, counts = 0, []
        else:
            assert not counts or counts[-1] >= cfg.keyframe_overlap * counts[0]
    assert renewals >= 1


@pytest.fixture(scope="module")
def kf_seq():
    return make_sequence("handheld_slow", frames=10, seed=3)


@pytest.mark.slow
def test_stream_and_scan_take_the_same_keyframes_and_poses(kf_seq):
    res = run_sequence(kf_seq, cfg=KF_CFG, seed=7)
    odo = Odometry(kf_seq.intrinsics, cfg=KF_CFG, seed=7, T_w_c0=kf_seq.groundtruth.poses[0])
    results = [odo.process(f.bgr, f.depth, f.timestamp) for f in kf_seq]
    np.testing.assert_allclose(odo.trajectory.poses, res.trajectory.poses, atol=1e-4)
    np.testing.assert_array_equal([int(r.output.keyframes) for r in results[1:]],
                                  np.asarray(res.outputs.keyframes))
    off = run_sequence(kf_seq, cfg=Config(), seed=7)
    assert off.outputs.keyframes is None
    # the switch changes the poses (the keyframe points enter the fit)
    assert np.abs(off.trajectory.poses - res.trajectory.poses).max() > 1e-7
