"""Keyframes and their local window: jaxvo.core.keyframe (device) and its host tracker
(jaxvo.host.frontend.keyframes.KeyframeTracker), tested together because neither runs without the
other."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_flow import CFG, H, K, W, bgr, plane, texture, warp

from jaxvo.config import Config, Params
from jaxvo.core.inputs import KeyframeFlow, invalid_keyframe_flow
from jaxvo.core.keyframe import (
    KeyframeInputs,
    KeyframeState,
    SupportInputs,
    _problem,
    init_keyframe,
    keyframe_index,
    keyframe_points,
    keyframe_support,
    refine,
    track_evidence,
    update_keyframe,
    window_points,
)
from jaxvo.core.evidence import moving_logodds
from jaxvo.core.noise import init_noise
from jaxvo.core.points import frame_points
from jaxvo.host.frontend.flow import FrameChain, GridFlowTracker
from jaxvo.odometry import Odometry, run_sequence
from jaxvo.synth.scenes import make_sequence

KF_CFG = dataclasses.replace(Config(), keyframes=True)


def _pose(rng) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.2, 3)).as_matrix()
    T[:3, 3] = rng.normal(0, 0.5, 3)
    return T


GRID = (5, 10)  # 50 grid points, every one a keyframe point (keyframe_stride 1)
UNIT_CFG = dataclasses.replace(Config(), keyframes=True, keyframe_stride=1, keyframe_window=3)


def _kf_flow(n: int, W: int, **fields) -> KeyframeFlow:
    """An all-invalid keyframe flow of n points and W window slots, ``fields`` replaced."""
    return invalid_keyframe_flow(n, W + 1)._replace(**{"renew": np.bool_(False), **fields})


def test_keyframe_points_are_the_keyframe_points_in_the_previous_camera():
    """src = inv(T_w_prev) T_w_kf p_kf in float64 numpy, to 1e-5 m; points not static or
    not valid are left out."""
    rng = np.random.default_rng(0)
    n = GRID[0] * GRID[1]
    T_w_kf, T_w_prev = _pose(rng), _pose(rng)
    p_kf = rng.uniform([-1, -1, 1], [1, 1, 4], (n, 3)).astype(np.float32)
    p_cur = rng.uniform([-1, -1, 1], [1, 1, 4], (n, 3)).astype(np.float32)
    valid = rng.random(n) > 0.2
    static = rng.random(n) > 0.2
    state = init_keyframe(T_w_kf, cfg=UNIT_CFG, grid=GRID)
    state = state._replace(point=state.point.at[-1].set(p_kf),
                           static=state.static.at[-1].set(jnp.asarray(static)),
                           fresh=jnp.bool_(False))
    kf = _kf_flow(n, 2, pts_cur=p_cur, valid=valid)  # pts_kf zero: the state's points count
    pts = keyframe_points(state, kf, jnp.asarray(T_w_prev, jnp.float32), Params(), focal=525.0,
                          scale=init_noise(Params()), index=keyframe_index(GRID, 1))
    want = (np.linalg.inv(T_w_prev) @ T_w_kf @ np.c_[p_kf, np.ones(n)].T)[:3]
    keep = valid & static
    np.testing.assert_array_equal(np.asarray(pts.valid), keep)
    np.testing.assert_allclose(np.asarray(pts.src)[:, keep], want[:, keep], atol=1e-5)
    np.testing.assert_allclose(np.asarray(pts.dst)[:, keep], p_cur.T[:, keep], atol=1e-6)


def test_window_points_are_the_older_keyframes_points_in_the_previous_camera():
    """With ``keyframe_track_window``, slot ``k`` (1 .. K - 2) of the window enters as
    ``inv(T_w_prev) T_w_kf[k] p_k`` against its reading in window slot ``k - 1`` of the
    keyframe flow, each with the cell it lay in; the oldest slot and the latest are not
    among them, nor an empty slot, a point not static or not read (float64 numpy, 1e-5 m)."""
    rng = np.random.default_rng(1)
    n, K = GRID[0] * GRID[1], 4
    cfg = dataclasses.replace(UNIT_CFG, keyframe_window=K, keyframe_track_window=True)
    T_w_kf = np.stack([_pose(rng) for _ in range(K)])
    T_w_prev = _pose(rng)
    p = rng.uniform([-1, -1, 1], [1, 1, 4], (K, n, 3)).astype(np.float32)
    static = rng.random((K, n)) > 0.2
    taken = np.array([True, True, False, True])  # slot 2 empty: its points are not used
    state = init_keyframe(np.eye(4), cfg=cfg, grid=GRID)._replace(
        T_w_kf=jnp.asarray(T_w_kf, jnp.float32), point=jnp.asarray(p),
        static=jnp.asarray(static), taken=jnp.asarray(taken), fresh=jnp.bool_(False))
    cur = rng.uniform([-1, -1, 1], [1, 1, 4], (K - 1, n, 3)).astype(np.float32)
    read = rng.random((K - 1, n)) > 0.2
    cells = rng.integers(-1, n, (K - 1, n)).astype(np.int32)
    kf = _kf_flow(n, K - 1, win_cur=cur, win_valid=read, win_cell_prev=cells)
    pts, cell = window_points(state, kf, jnp.asarray(T_w_prev, jnp.float32), Params(),
                              focal=525.0, scale=init_noise(Params()),
                              index=keyframe_index(GRID, 1))
    assert pts.valid.shape == (2 * n,) and cell.shape == (2 * n,)
    for j, slot in enumerate((1, 2)):  # the flow's window slots 0 and 1
        part = slice(j * n, (j + 1) * n)
        keep = read[slot - 1] & static[slot] & taken[slot]
        want = (np.linalg.inv(T_w_prev) @ T_w_kf[slot] @ np.c_[p[slot], np.ones(n)].T)[:3]
        np.testing.assert_array_equal(np.asarray(pts.valid[part]), keep)
        np.testing.assert_allclose(np.asarray(pts.src)[:, part][:, keep], want[:, keep],
                                   atol=1e-5)
        np.testing.assert_array_equal(np.asarray(pts.dst)[:, part][:, keep],
                                      cur[slot - 1].T[:, keep])
        np.testing.assert_array_equal(np.asarray(cell[part]), cells[slot - 1])


@pytest.mark.parametrize("tracked", [False, True])
def test_the_fit_takes_the_older_keyframes_points_only_with_the_window_tracked(tracked):
    """keyframe_support joins the pair's points, the latest keyframe's and (with
    ``keyframe_track_window``) slots 1 .. K - 2's, each weighted as the cell it lay in: a
    point in a cell whose segment moves unlike the background has no weight."""
    rng = np.random.default_rng(2)
    n, K = GRID[0] * GRID[1], 4
    cfg = dataclasses.replace(UNIT_CFG, keyframe_window=K, keyframe_track_window=tracked)
    p = rng.uniform([-1, -1, 1], [1, 1, 4], (K, n, 3)).astype(np.float32)
    state = init_keyframe(np.eye(4), cfg=cfg, grid=GRID)._replace(
        point=jnp.asarray(p), static=jnp.ones((K, n), bool), taken=jnp.ones(K, bool),
        fresh=jnp.bool_(False))
    cur = p[1:] + np.float32(0.01)
    kf = _kf_flow(n, K - 1, pts_cur=cur[-1], valid=np.ones(n, bool), win_cur=cur,
                  win_valid=np.ones((K - 1, n), bool), cell_prev=np.arange(n, dtype=np.int32),
                  win_cell_prev=np.tile(np.arange(n, dtype=np.int32), (K - 1, 1)))
    pair = frame_points(jnp.asarray(p[0]), jnp.asarray(cur[0]), jnp.ones(n, bool), Params(),
                        focal=525.0)
    moving = np.arange(n) % 5 == 0  # believed in, but not used: its segment moves
    bg = SimpleNamespace(use=jnp.asarray(np.where(moving, 0.0, 1.0), jnp.float32),
                         belief=jnp.ones(n, jnp.float32))
    pts, use, _ = keyframe_support(state, SupportInputs(
        kf=kf, T_w_prev=jnp.eye(4), pts=pair, bg=bg, evidence=jnp.full(n, -5.0),
        focal=jnp.float32(525.0), scale=init_noise(Params())), Params(), cfg=cfg, grid=GRID)
    keyframes = 3 if tracked else 1
    assert pts.valid.shape == ((1 + keyframes) * n,)
    assert bool(jnp.all(pts.valid))
    for k in range(keyframes):
        part = slice((1 + k) * n, (2 + k) * n)
        np.testing.assert_array_equal(np.asarray(use[part]) > 0, ~moving)
    if tracked:  # slot 1's points, seen from the previous camera (the identity here)
        np.testing.assert_allclose(np.asarray(pts.src)[:, 2 * n:3 * n], p[1].T, atol=1e-6)


def test_a_keyframe_point_the_frames_motion_keeps_failing_to_explain_leaves_its_keyframe():
    """track_evidence: each slot's tracks' noise is the robust scale of its weighed points'
    residuals (here 2x the pair's in slot 1, at least 1 in the latest slot, as it was in
    slot 2 where nothing was weighed); a point whose residual stays beyond that noise
    (10 in its units, every frame) leaves its keyframe's static points after a few frames,
    one beyond it in a single frame (12) does not."""
    n, K = GRID[0] * GRID[1], 4
    cfg = dataclasses.replace(UNIT_CFG, keyframe_window=K, keyframe_track_window=True)
    state = init_keyframe(np.eye(4), cfg=cfg, grid=GRID)._replace(
        static=jnp.ones((K, n), bool), taken=jnp.ones(K, bool), fresh=jnp.bool_(False))
    rng = np.random.default_rng(3)
    chi2 = lambda scale: (scale * rng.standard_normal((n, 3))).__pow__(2).sum(1)
    weighed = np.ones((K - 1, n), bool)
    weighed[2] = False  # slot 2: none weighed
    moving, once = 7, 11
    for frame in range(8):
        d2 = np.stack([chi2(0.5), chi2(2.0), chi2(1.0)]).astype(np.float32)
        d2[0, moving], d2[1, moving] = 10.0, 40.0  # 10 in each slot's units, every frame
        if frame == 0:
            d2[1, once] = 48.0  # 12 in its units, once
        state = track_evidence(state, jnp.asarray(d2.ravel()), jnp.asarray(weighed.ravel()),
                               Params())
    noise = np.asarray(state.track_noise)
    assert noise[3] == 1.0 and noise[2] == 1.0 and noise[0] == 1.0  # latest: at least 1
    assert 1.7 < noise[1] < 2.3
    static = np.asarray(state.static)
    assert not static[3, moving] and not static[1, moving]  # the latest slot and slot 1
    assert static[1, once] and static[2, moving]  # one frame; slot 2 not weighed
    assert static.sum() >= K * n - 2 - 3  # a chance point or so of pure noise at most


def test_a_keyframe_point_its_frames_keep_explaining_counts_as_established_background():
    """track_evidence also keeps each point's own moving log-odds, updated by its residuals
    as the grid's cells are by theirs: after frames of residuals of pure noise at its
    keyframe's noise the point is established, and the fit then weighs it as established
    background (1) where its cell is only unestablished (0.1 before), still 0 where the
    cell is believed to move. A point its frames never weighed learns nothing."""
    n, K = GRID[0] * GRID[1], 4
    cfg = dataclasses.replace(UNIT_CFG, keyframe_window=K, keyframe_track_window=True)
    rng = np.random.default_rng(4)
    p = rng.uniform([-1, -1, 1], [1, 1, 4], (K, n, 3)).astype(np.float32)
    state = init_keyframe(np.eye(4), cfg=cfg, grid=GRID)._replace(
        point=jnp.asarray(p), static=jnp.ones((K, n), bool), taken=jnp.ones(K, bool),
        fresh=jnp.bool_(False))
    weighed = np.ones((K - 1, n), bool)
    weighed[:, 0] = False  # never weighed
    young = state
    for _ in range(6):
        d2 = (rng.standard_normal((K - 1, n, 3)) ** 2).sum(-1).astype(np.float32)
        state = track_evidence(state, jnp.asarray(d2.ravel()), jnp.asarray(weighed.ravel()),
                               Params())
    L = float(moving_logodds(Params()))
    e = np.asarray(state.point_evidence)[1:]
    assert np.all(e[:, 0] == 0.0)
    assert np.mean(e[:, 1:] <= -L) > 0.95
    cells = np.where(np.arange(n) % 3 == 0, 10.0, 0.0).astype(np.float32)  # moving / unknown
    kf = _kf_flow(n, K - 1, pts_cur=p[-1], valid=np.ones(n, bool), win_cur=p[1:],
                  win_valid=np.ones((K - 1, n), bool), cell_prev=np.arange(n, dtype=np.int32),
                  win_cell_prev=np.tile(np.arange(n, dtype=np.int32), (K - 1, 1)))
    pair = frame_points(jnp.asarray(p[0]), jnp.asarray(p[0]), jnp.ones(n, bool), Params(),
                        focal=525.0)
    bg = SimpleNamespace(use=jnp.ones(n, jnp.float32), belief=jnp.ones(n, jnp.float32))
    weights = []
    for st in (young, state):
        _, use, _ = keyframe_support(st, SupportInputs(
            kf=kf, T_w_prev=jnp.eye(4), pts=pair, bg=bg, evidence=jnp.asarray(cells),
            focal=jnp.float32(525.0), scale=init_noise(Params())), Params(), cfg=cfg,
            grid=GRID)
        weights.append(np.asarray(use[n:]).reshape(K - 1, n))
    unknown = cells == 0
    assert np.all(weights[0][:, unknown] == Params().unestablished_weight)
    established = (np.concatenate([e[-1:], e[:-1]]) <= -L) & unknown  # latest first
    assert np.all(weights[1][established] == 1.0)
    assert np.all(weights[1][:, ~unknown] == 0.0)


def _first_keyframe(seed: int, x: float, static):
    """A fresh window whose first pair taught it random points ``p0`` (n, 3), the camera
    ``T`` then ``x`` metres along x: ``(state, p0, T)``."""
    n = GRID[0] * GRID[1]
    p0 = np.random.default_rng(seed).uniform([-1, -1, 1], [1, 1, 4], (n, 3)).astype(np.float32)
    T = np.eye(4, dtype=np.float32)
    T[0, 3] = x
    st = init_keyframe(np.eye(4), cfg=UNIT_CFG, grid=GRID)
    return (*_update(st, _kf_flow(n, 2, pts_kf=p0, valid=np.ones(n, bool)), T, static), p0, T)


def _update(state, kf, T, static, ok=True):
    n = len(static)
    none = frame_points(jnp.zeros((n, 3)), jnp.zeros((n, 3)), jnp.zeros(n, bool), Params(),
                        focal=525.0)
    # the pair adds no information
    inputs = KeyframeInputs(kf=kf, T_w_c=jnp.asarray(T, jnp.float32),
                            static=jnp.asarray(static), T_cur_prev=jnp.eye(4),
                            T_w_prev=jnp.eye(4), pts=none, used=jnp.zeros(n, bool),
                            noise=init_noise(Params()), focal=525.0, ok=jnp.bool_(ok))
    return update_keyframe(state, inputs, Params(), cfg=UNIT_CFG, grid=GRID)


def test_update_keyframe_takes_a_keyframe_only_when_told():
    """Without ``renew`` the window keeps its keyframes (the first pair teaches it the first
    keyframe's points); with it the current frame becomes the latest keyframe with its own
    points and its readings of the window's points, the oldest slot leaving."""
    n = GRID[0] * GRID[1]
    static = np.arange(n) % 2 == 0
    same, out, p0, T = _first_keyframe(1, 1.0, static)
    np.testing.assert_array_equal(np.asarray(same.T_w_kf[-1]), np.eye(4))
    np.testing.assert_array_equal(np.asarray(out.T_w_c), T)  # no keyframe: the pose stays
    np.testing.assert_array_equal(np.asarray(same.point[-1]), p0)
    assert bool(same.static[-1].all()) and int(out.count) == 1 and not bool(same.fresh)
    p1 = p0 + np.float32(0.1)
    seen = np.zeros((2, n), bool)
    seen[1] = True
    kf = _kf_flow(n, 2, renew=np.bool_(True), new_kf=p1, win_cur=np.stack([p0, p1]),
                  win_valid=seen)
    new, out = _update(same, kf, T, static)
    assert int(out.count) == 2 and bool(new.taken[-1]) and bool(new.taken[-2])
    # the points are copied into their slots, then the window's refinement scales their
    # depths by (1 + s) with s about 0: exact readings leave s within float32 rounding (a
    # 2-core AMD EPYC moved 3 of 150 values by one float32 step, 2.4e-7), so compared
    # within 1e-6 relative; the flags, the readings and the poses without a keyframe are
    # copied or selected (jnp.where), bit for bit on any machine
    np.testing.assert_allclose(np.asarray(new.point[-1]), p1, rtol=1e-6, atol=0)
    np.testing.assert_array_equal(np.asarray(new.static[-1]), static)
    np.testing.assert_allclose(np.asarray(new.point[-2]), p0, rtol=1e-6, atol=0)  # shifted
    np.testing.assert_array_equal(np.asarray(new.seen[-1, -2]), np.ones(n, bool))
    np.testing.assert_array_equal(np.asarray(new.obs[-1, -2]), p1)
    assert not bool(new.seen[-1, 0].any())  # slot 0 is still empty


def test_a_keyframe_taken_where_the_ego_motion_was_not_measured_keeps_nothing():
    """A keyframe the host renews on a frame whose ego-motion failed (no background in
    view: a near object filling the image) holds no static point and reads none of the
    window's: its cells' evidence says nothing of the world, and its readings would tie
    the window's poses to the object. Its pose is the carried one, unrefined, and the
    window starts anew with it."""
    n = GRID[0] * GRID[1]
    static = np.ones(n, bool)
    first, _, p0, T = _first_keyframe(2, 0.5, static)
    seen = np.ones((2, n), bool)
    kf = _kf_flow(n, 2, renew=np.bool_(True), new_kf=p0 + np.float32(0.1),
                  win_cur=np.stack([p0, p0 + np.float32(0.3)]), win_valid=seen)
    taken, out = _update(first, kf, T, static, ok=True)
    assert bool(taken.static[-1].all()) and bool(taken.seen[-1, -2].all())
    blind, out = _update(first, kf, T, static, ok=False)
    assert int(out.count) == 2 and bool(blind.taken[-1])
    assert not bool(blind.static[-1].any()) and not bool(blind.seen[-1].any())
    np.testing.assert_array_equal(np.asarray(out.T_w_c), T)
    # nothing ties the window across it: the keyframe after starts the window anew (as a
    # new chain does on the host), no link, no reading of the keyframes before
    only_latest = [False] * (blind.taken.shape[0] - 1) + [True]
    assert list(np.asarray(blind.taken)) == only_latest and bool(blind.blind)
    after, out = _update(blind, kf, T, static, ok=True)
    assert list(np.asarray(after.taken)) == only_latest and not bool(after.blind)
    read = after.seen & after.taken[None, :, None]  # readings of keyframes in the window
    assert bool(after.static[-1].all()) and not bool(read.any())
    np.testing.assert_array_equal(np.asarray(out.T_w_c), T)


def _window(rng, K: int, m: int):
    """A window of K keyframes (the first at the origin) around m points a keyframe, each
    point read exactly by every later keyframe."""
    def pose(w, t):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(w).as_matrix()
        T[:3, 3] = t
        return T
    T = np.stack([np.eye(4)] + [pose(rng.normal(0, 0.05, 3), rng.normal(0, 0.1, 3))
                                for _ in range(K - 1)])
    Xw = np.stack([rng.uniform(-1, 1, (K, m)), rng.uniform(-1, 1, (K, m)),
                   rng.uniform(2, 3, (K, m))], -1)
    point = np.einsum("iba,imb->ima", T[:, :3, :3], Xw - T[:, None, :3, 3])
    obs = np.einsum("jba,jimb->jima", T[:, :3, :3], Xw[None] - T[:, None, None, :3, 3])
    seen = np.broadcast_to(np.tril(np.ones((K, K), bool), -1)[:, :, None], (K, K, m))
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    state = KeyframeState(f32(T), jnp.ones(K, bool), f32(point), jnp.ones((K, m), bool),
                          f32(obs), jnp.asarray(seen), jnp.int32(K), jnp.bool_(False),
                          f32(np.broadcast_to(np.eye(4), (K, 4, 4))), jnp.zeros((K, 6, 6)),
                          jnp.zeros((K, 6)))
    return T, state, pose


_refine = jax.jit(refine, static_argnums=2)


def test_window_refinement_finds_the_poses_the_readings_agree_on():
    """Exact readings, every pose but the oldest moved by about 1 cm and 0.6 degrees: the
    refinement brings each back to 1e-4 m and the depths to 1e-4 (float32)."""
    rng = np.random.default_rng(2)
    K, m = 4, 60
    T, state, pose = _window(rng, K, m)
    pb = _problem(state, 525.0, init_noise(Params()), Params())
    moved = T.copy()
    for k in range(1, K):
        moved[k] = pose(rng.normal(0, 0.01, 3), rng.normal(0, 0.01, 3)) @ T[k]
    assert np.abs(moved[:, :3, 3] - T[:, :3, 3]).max() > 5e-3
    refined, s = _refine(jnp.asarray(moved, jnp.float32), pb, 8)
    np.testing.assert_allclose(np.asarray(refined)[:, :3, 3], T[:, :3, 3], atol=1e-4)
    np.testing.assert_allclose(np.asarray(refined)[:, :3, :3], T[:, :3, :3], atol=1e-4)
    assert float(jnp.abs(s).max()) < 1e-4


def test_chain_factor_alone_holds_each_keyframe_where_the_chain_put_it():
    """No readings: the chain's factors (T_k_(k-1) measured, a strong information) are the
    whole cost, and the refinement puts every keyframe where the chain says, relative to
    the fixed oldest one."""
    rng = np.random.default_rng(3)
    K, m = 4, 60  # the shapes of the test above: the same compiled refinement
    T, state, pose = _window(rng, K, m)
    link = np.stack([np.eye(4)] + [np.linalg.inv(T[k]) @ T[k - 1] for k in range(1, K)])
    state = state._replace(seen=jnp.zeros_like(state.seen),
                           link_T=jnp.asarray(link, jnp.float32),
                           link_H=jnp.broadcast_to(1e6 * jnp.eye(6), (K, 6, 6)))
    moved = T.copy()
    for k in range(1, K):
        moved[k] = pose(rng.normal(0, 0.01, 3), rng.normal(0, 0.02, 3)) @ T[k]
    pb = _problem(state, 525.0, init_noise(Params()), Params())
    refined, _ = _refine(jnp.asarray(moved, jnp.float32), pb, 8)
    np.testing.assert_allclose(np.asarray(refined)[:, :3, 3], T[:, :3, 3], atol=1e-4)


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


@pytest.mark.parametrize("max_age, renewed_at", [(4, [4, 8]), (0, [])])
def test_a_keyframe_is_renewed_at_the_latest_after_its_age_bound(shifted_frames, max_age,
                                                                 renewed_at):
    """A still view keeps every point tracked, so the overlap never asks for a keyframe: one
    is taken every ``keyframe_max_age`` pairs, and never without the bound."""
    cfg = dataclasses.replace(CFG, keyframes=True, keyframe_max_age=max_age)
    chain = FrameChain(GridFlowTracker(K, cfg, height=H, width=W), min_valid=5, keyframes=True)
    still = bgr(shifted_frames[0])
    chain.push(still, plane(2.0))
    renewals = []
    for pair in range(1, 10):
        chain.push(still, plane(2.0))
        if chain.keyframe_flow.renew:
            renewals.append(pair)
    assert renewals == renewed_at


@pytest.fixture(scope="module")
def kf_seq():
    # test_pipeline.py's sequence: its frame-to-frame scan below is the program compiled there
    return make_sequence("handheld_slow", frames=12, seed=3)


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


def test_with_the_window_tracked_every_pair_reads_the_window_keyframes(shifted_frames):
    """``keyframe_track_window``: every pair, not only a keyframe's, reads the points of the
    window's older keyframes, 12 px per frame since that keyframe to the left (median, to
    0.2 px), with the cell of the previous image each lay in (where that keyframe's point
    was, 12 px further right per frame before); the latest keyframe's slot is the pair's
    own keyframe flow."""
    cfg = dataclasses.replace(CFG, keyframes=True, keyframe_window=3, keyframe_overlap=0.9,
                              keyframe_track_window=True)
    chain = FrameChain(GridFlowTracker(K, cfg, height=H, width=W), min_valid=5, keyframes=True)
    chain.push(bgr(shifted_frames[0]), plane(2.0))
    taken = [0]
    read_between = 0  # pairs that read an older keyframe without taking one
    for i, img in enumerate(shifted_frames[1:], start=1):
        chain.push(bgr(img), plane(2.0))
        kf = chain.keyframe_flow
        np.testing.assert_array_equal(kf.win_valid[-1], kf.valid)
        v = kf.win_valid[0]
        if len(taken) >= 2 and v.sum() >= 20:
            k = taken[-2]
            x = kf.win_cur[0, v, 0] * K.fx / kf.win_cur[0, v, 2] + K.cx + 12.0 * (i - k)
            f = (x - (cfg.cell - 1) / 2) / cfg.cell
            assert np.median(np.abs(f - np.round(f))) * cfg.cell < 0.2, (k, i)
            # the previous image held the point 12 px to the right of where it is now
            col = np.floor((x - 12.0 * (i - k) + 12.0) / cfg.cell).astype(int)
            got = kf.win_cell_prev[0, v] % (W // cfg.cell)
            assert np.mean(got == col) > 0.9
            read_between += not kf.renew
        if kf.renew:
            taken.append(i)
    assert len(taken) >= 3 and read_between >= 1


def test_a_new_keyframe_reads_the_points_of_the_window_keyframes(shifted_frames):
    """When a keyframe is taken, every window keyframe whose points are still in view gives
    readings in the new one: 12 px per frame since that keyframe to the left (median, to
    0.2 px), the latest keyframe's slot the pair's own keyframe flow, and the new keyframe's
    own points at its grid. (A keyframe every few frames: ``keyframe_overlap`` 0.9.)"""
    cfg = dataclasses.replace(CFG, keyframes=True, keyframe_window=3, keyframe_overlap=0.9)
    chain = FrameChain(GridFlowTracker(K, cfg, height=H, width=W), min_valid=5, keyframes=True)
    chain.push(bgr(shifted_frames[0]), plane(2.0))
    taken = [0]  # frame index of each keyframe
    older_read = 0
    for i, img in enumerate(shifted_frames[1:], start=1):
        chain.push(bgr(img), plane(2.0))
        kf = chain.keyframe_flow
        assert kf.win_valid.shape == (cfg.keyframe_window - 1, len(kf.valid))
        if not kf.renew:
            assert not kf.win_valid.any()
            continue
        np.testing.assert_array_equal(kf.win_valid[-1], kf.valid)
        np.testing.assert_array_equal(kf.win_cur[-1], kf.pts_cur)
        keys = taken[-(cfg.keyframe_window - 1):]
        for w, k in enumerate(keys, start=cfg.keyframe_window - 1 - len(keys)):
            v = kf.win_valid[w]
            if v.sum() < 20:
                continue
            older_read += w < cfg.keyframe_window - 2
            # a point read at x in the new image lay at x + 12 (i - k) in keyframe k's,
            # which is where keyframe k's grid point was
            x = kf.win_cur[w, v, 0] * K.fx / kf.win_cur[w, v, 2] + K.cx + 12.0 * (i - k)
            f = (x - (cfg.cell - 1) / 2) / cfg.cell
            assert np.median(np.abs(f - np.round(f))) * cfg.cell < 0.2, (w, k, i)
        assert (kf.new_kf[:, 2] > 0).sum() > 100
        taken.append(i)
    assert len(taken) >= 3 and older_read >= 1
