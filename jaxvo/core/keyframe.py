"""Keyframes and their local window: the static points of the recent keyframes in the
ego-motion, and their poses and points refined together (device side; our addition).

Frame to frame, every pair adds its error to the pose chain, also while the camera hovers
over the same view. The host tracks the latest keyframe's grid points into each new image
(:class:`jaxvo.host.frontend.keyframes.KeyframeTracker`); here those tracks join the pair's points
in one ego-motion fit. A keyframe point ``P`` enters as the pair ``(T_prev_kf P, p_cur)``
with ``T_prev_kf = inv(T_w_prev) T_w_kf``: the same rigid motion ``T_cur_prev`` explains
it, so the fit, its robust weights and its noise model are those of the pair
(:func:`jaxvo.core.egomotion.update_egomotion`), and the keyframe's points anchor the pose
to the keyframe's instead of to the previous frame's only. Only the points the temporal
model held static on the keyframe's image (no moving evidence) are used.

The window. The last ``K = cfg.keyframe_window`` keyframes are kept with their points
(each keyframe's grid points, every ``cfg.keyframe_stride``-th row and column, in its own
camera). When a new keyframe is taken the host has found the window's points in it, so
each point holds readings from up to ``K`` keyframes: the one that took it and the later
ones that saw it. Then the window's poses (the oldest held fixed: the gauge) and each
point's depth along its keyframe's ray are refined together, as bundle adjustment does,
by Levenberg-Marquardt (:func:`jaxvo.core.lm.levenberg_marquardt`): every reading of a
point in a later keyframe is a residual whose lateral part (across the reading's ray,
the tracker's noise) and part along the ray (the depth noise) are each in units of the
sensor noise model (:mod:`jaxvo.core.noise`), under Cauchy's robust loss; the point's own
reading is one more, along its ray. RGB-D depth noise is independent from frame to frame,
so a point seen from several keyframes pins its depth, and the poses, better than any
single reading; a keyframe seen again from a later one ties the two directly instead of
through the chain of frames between them. The latest keyframe's refined points are what
the following frames are then tracked against, and its refined pose what they chain from.

The window as a local map (``cfg.keyframe_track_window``, off by default). The host then
finds the older window keyframes' points in every new image, not only in a new keyframe,
and each frame's fit takes them beside the latest keyframe's (:func:`window_points`: slots
``1 .. K - 2``; the oldest leaves at the next keyframe), each as the window refined it and
weighted as the cell of the previous image it lay in. A frame is then held to the poses
of up to ``K - 1`` keyframes. Each keyframe point also keeps a test of its own over the
frames (:func:`track_evidence`): its residual under each frame's motion, in units of its
keyframe's measured track noise (a keyframe's tracks err more than a pair's, and more
with their age), adds to a CUSUM, and a point whose sum crosses the inlier test leaves
for good: a box that kept still on a keyframe stops holding the frames once it moves.
And each point keeps its own moving log-odds, from its residuals at that noise as the
grid's cells have theirs from the pairs (:func:`jaxvo.core.evidence.update_evidence`); in
the fit a point's log-odds and its cell's add (two independent pieces of evidence), so a
room point its frames have kept explaining counts as established background where a
person passing over its cell took the cell's evidence away.
Measured in ``docs/report/keyframes.md``: it pays on the TUM clip and the synthetic
scenes, costs stop_start and about a fifth more time a frame, so it stays off.

Conventions (:mod:`jaxvo.core.geometry`): poses are camera-to-world ``T_w_c``, slots are
ordered oldest first, slot ``K - 1`` the latest keyframe; ``obs[j, i]`` is keyframe
``i``'s point read in keyframe ``j``'s camera (``j > i``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxvo.config import Params, StepOptions
from jaxvo.core.background import BackgroundOut, belief_weights
from jaxvo.core.evidence import static_loglik, update_evidence
from jaxvo.core.geometry import (
    adjoint,
    invert_pose,
    masked_median,
    orthonormal,
    perturb,
    skew,
    tiny,
)
from jaxvo.core.inputs import KeyframeFlow, keyframe_index
from jaxvo.core.lm import ArrowCurvature, levenberg_marquardt, pair_factor
from jaxvo.core.noise import NoiseScale
from jaxvo.core.points import Points, frame_points
from jaxvo.core.robust import cauchy, chi2_quantile


class KeyframeState(NamedTuple):
    """The window's keyframes (carried by the pipeline); ``m`` points a keyframe."""

    T_w_kf: jax.Array  # (K, 4, 4) float32 camera-to-world pose of each slot's keyframe
    taken: jax.Array  # (K,) bool the slot holds a keyframe
    point: jax.Array  # (K, m, 3) float32 metres, each keyframe's points in its camera
    static: jax.Array  # (K, m) bool the point has depth and was held static when taken
    obs: jax.Array  # (K, K, m, 3) float32 metres, obs[j, i]: keyframe i's point in camera j
    seen: jax.Array  # (K, K, m) bool obs holds a reading
    count: jax.Array  # () int32, keyframes taken so far (the first frame is one)
    # () bool the latest keyframe's points are not known yet: the first frame's come with
    # the first pair's keyframe flow (a new keyframe's with the pair that takes it)
    fresh: jax.Array
    # the chain between consecutive keyframes: slot k holds T_k_(k-1) as the frames between
    # them measured it, and the information of the pair that took keyframe k on it (a
    # quadratic factor, jaxvo.core.lm.pair_factor)
    link_T: jax.Array  # (K, 4, 4) float32
    link_H: jax.Array  # (K, 6, 6) float32
    link_g: jax.Array  # (K, 6) float32
    # () bool a frame since the latest keyframe (or that keyframe's own) had no measured
    # ego-motion: the next keyframe starts a new window, as a new chain does on the host
    blind: jax.Array = np.bool_(False)
    # (cfg.keyframe_track_window; init_keyframe sizes them, the defaults only let a window
    # built by hand for its refinement leave them out) each slot's tracks' noise over the
    # pair's noise model, the robust scale of their residuals under the frames' motions,
    # (K,) float32, and each point's evidence sum (K, m) float32 (track_evidence)
    track_noise: jax.Array = np.ones(1, np.float32)
    cusum: jax.Array = np.zeros((1, 1), np.float32)
    # (K, m) float32 each point's own moving log-odds, from its track's residuals as the
    # grid's cells have theirs from the pairs' (track_evidence); 0 when its keyframe is taken
    point_evidence: jax.Array = np.zeros((1, 1), np.float32)


class KeyframeOut(NamedTuple):
    """What one keyframe update gives back."""

    T_w_c: jax.Array  # (4, 4) float32 the current camera's pose after the window's refinement
    count: jax.Array  # () int32 keyframes taken so far: the latest keyframe's number


def init_keyframe(T_w_c0, *, cfg: StepOptions, grid: tuple[int, int]) -> KeyframeState:
    """The first frame is the first keyframe (its points come with the first pair's
    keyframe flow); nothing is known to move yet."""
    K, m = max(cfg.keyframe_window, 1), len(keyframe_index(grid, cfg.keyframe_stride))
    T0 = jnp.asarray(T_w_c0, jnp.float32)
    return KeyframeState(
        T_w_kf=jnp.broadcast_to(T0, (K, 4, 4)),
        taken=jnp.zeros((K,), bool).at[K - 1].set(True),
        point=jnp.zeros((K, m, 3), jnp.float32),
        static=jnp.zeros((K, m), bool),
        obs=jnp.zeros((K, K, m, 3), jnp.float32),
        seen=jnp.zeros((K, K, m), bool),
        count=jnp.int32(1),
        fresh=jnp.bool_(True),
        link_T=jnp.broadcast_to(jnp.eye(4, dtype=jnp.float32), (K, 4, 4)),
        link_H=jnp.zeros((K, 6, 6), jnp.float32),
        link_g=jnp.zeros((K, 6), jnp.float32),
        track_noise=jnp.ones((K,), jnp.float32),
        cusum=jnp.zeros((K, m), jnp.float32),
        point_evidence=jnp.zeros((K, m), jnp.float32),
    )


def keyframe_points(state: KeyframeState, kf, T_w_prev, params: Params, *, focal,
                    scale: NoiseScale, index) -> Points:
    """The latest keyframe's static points tracked into this image, as pairs ``(previous
    frame, current frame)``.

    Args:
      state: the window; kf: the pair's ``KeyframeFlow`` (``pts_kf``, ``pts_cur`` (n, 3)
        metres, ``valid`` (n,)); T_w_prev: (4, 4) pose of the pair's previous camera.
      params, focal, scale: as :func:`jaxvo.core.points.frame_points`.
      index: (m,) the grid points a keyframe offers (:func:`keyframe_index`).
    Returns:
      :class:`Points` (m of them) with ``src`` in the previous camera's frame: the
      keyframe's points as the window refined them (its own reading until then).
    """
    P = jnp.where(state.fresh, kf.pts_kf[index], state.point[-1])
    use = kf.valid[index] & (state.fresh | state.static[-1]) & (P[:, 2] > 0)
    T_prev_kf = invert_pose(T_w_prev) @ state.T_w_kf[-1]
    src = P @ T_prev_kf[:3, :3].T + T_prev_kf[:3, 3]
    return frame_points(src, kf.pts_cur[index], use, params, focal=focal, scale=scale)


def window_points(state: KeyframeState, kf, T_w_prev, params: Params, *, focal,
                  scale: NoiseScale, index) -> tuple[Points, jax.Array]:
    """The older window keyframes' static points tracked into this image
    (``cfg.keyframe_track_window``), as :func:`keyframe_points` gives the latest's: slots
    ``1 .. K - 2`` (the oldest is not tracked: it leaves at the next keyframe), each
    keyframe's points as the window refined them.

    Returns:
      ``(Points, cell)``: ``(K - 2) m`` points, slot by slot, and the cell of the pair's
      previous image each lay in (``kf.win_cell_prev``; -1 unknown).
    """
    K = state.T_w_kf.shape[0]
    older = slice(1, K - 1)  # window slots 0 .. W - 2 of the keyframe flow
    P = state.point[older]  # (K - 2, m, 3)
    use = (kf.win_valid[:K - 2][:, index] & state.static[older] & state.taken[older, None]
           & ~state.fresh & (P[..., 2] > 0))
    T_prev_kf = invert_pose(T_w_prev)[None] @ state.T_w_kf[older]
    src = jnp.einsum("kab,kmb->kma", T_prev_kf[:, :3, :3], P) + T_prev_kf[:, None, :3, 3]
    flat = lambda x: x.reshape(-1, *x.shape[2:])
    pts = frame_points(flat(src), flat(kf.win_cur[:K - 2][:, index]), flat(use), params,
                       focal=focal, scale=scale)
    return pts, flat(kf.win_cell_prev[:K - 2][:, index])


def track_evidence(state: KeyframeState, d2, weighed, params: Params) -> KeyframeState:
    """A keyframe point's own test over frames (cfg.keyframe_track_window).

    Each slot's tracks' noise is the robust scale (median) of its ``weighed`` points'
    normalised residuals ``d2`` ((K - 1) m,: the latest keyframe's, then slots
    1 .. K - 2's) under the frame's motion, over the pair's noise model (at least 1; as it
    was where too few were weighed). At that noise each point's residual adds to a CUSUM,
    ``S <- max(0, S + d2 / s^2 - 2 * 3)`` (3 the mean of chi-square(3)), and a point whose
    sum crosses the inlier test leaves its keyframe's static points for good. At the same
    noise the residual is also the point's evidence, moving over static, as a cell's is
    (:func:`jaxvo.core.evidence.static_loglik`, :func:`jaxvo.core.evidence.update_evidence`:
    decayed, bounded; a point not weighed learns nothing), which
    :func:`keyframe_support` adds to its cell's."""
    K, m = state.static.shape
    order = _fitted_slots(K)
    d2, weighed = d2.reshape(-1, m), weighed.reshape(-1, m)
    med = jax.vmap(lambda x, w: masked_median(x, w, 12))(d2, weighed)
    was = state.track_noise[order]
    s = jnp.sqrt(jnp.maximum(med / chi2_quantile(3, 0.5), 1.0))
    s = jnp.where(jnp.sum(weighed, axis=1) >= params.min_static_points, s, was)
    z2 = d2 / (s * s)[:, None]  # in units of the slot's track noise
    S = jnp.maximum(state.cusum[order] + jnp.where(weighed, z2 - 6.0, 0.0), 0.0)
    out = S > chi2_quantile(3, params.confidence)
    e = update_evidence(state.point_evidence[order], static_loglik(z2, params), weighed,
                        ~weighed, params)
    return state._replace(track_noise=state.track_noise.at[order].set(s),
                          cusum=state.cusum.at[order].set(jnp.where(out, 0.0, S)),
                          static=state.static.at[order].set(state.static[order] & ~out),
                          point_evidence=state.point_evidence.at[order].set(e))


def _fitted_slots(K: int):
    """(K - 1,) the slots whose points the ego-motion fits, in the order it takes them: the
    latest keyframe's, then slots ``1 .. K - 2``'s (:func:`keyframe_support`)."""
    return jnp.concatenate([jnp.array([K - 1]), jnp.arange(1, K - 1)])


def join_points(a: Points, b: Points) -> Points:
    """The points of ``a`` then those of ``b`` (n_a + n_b) as one set, ``a``'s tests."""
    cat = lambda x, y: jnp.concatenate([x, y], axis=-1)
    return Points(cat(a.src, b.src), cat(a.dst, b.dst), jax.tree.map(cat, a.noise, b.noise),
                  cat(a.valid, b.valid), a.thr, a.tie)


class SupportInputs(NamedTuple):
    """What the keyframe's support of the ego-motion reads (:func:`keyframe_support`)."""

    kf: KeyframeFlow  # the pair's keyframe flow (jaxvo.host.frontend.keyframes.KeyframeTracker)
    T_w_prev: jax.Array  # (4, 4) float32 the previous camera's pose
    pts: Points  # the pair's points
    # the background's output (jaxvo.core.background.BackgroundOut): its use and belief
    bg: BackgroundOut
    evidence: jax.Array  # (n,) float32 each cell's moving log-odds entering the frame
    focal: jax.Array  # () float32 focal length, pixels
    scale: NoiseScale  # the sensor noise model


def keyframe_support(state: KeyframeState, inputs: SupportInputs, params: Params, *,
                     cfg: StepOptions, grid):
    """The ego-motion's points, weights and beliefs with the latest keyframe's points joined
    to the pair's (``(Points, weights, belief)``, the keyframe's after the pair's).

    A keyframe point counts as the cell of the pair's previous image it lay in
    (``kf.cell_prev``): by what earlier frames say of that cell (its belief,
    :func:`jaxvo.core.background.belief_weights` of ``evidence``), and not at all where this
    frame's segment there moves unlike the background (``bg``, the background's output:
    a valid point it believes in but does not use). So a keyframe taken while a box stood
    still does not pull the ego-motion along once the box moves. With the window tracked,
    a point counts by its own moving log-odds and its cell's together (their sum, where
    the cell is not believed to move; :func:`track_evidence`).
    """
    kf, T_w_prev, pts, bg, evidence, focal, scale = inputs
    index = keyframe_index(grid, cfg.keyframe_stride)
    kpts = keyframe_points(state, kf, T_w_prev, params, focal=focal, scale=scale, index=index)
    cell = kf.cell_prev[index]
    tracked = cfg.keyframe_track_window and cfg.keyframe_window > 2
    if tracked:
        wpts, wcell = window_points(state, kf, T_w_prev, params, focal=focal, scale=scale,
                                    index=index)
        kpts, cell = join_points(kpts, wpts), jnp.concatenate([cell, wcell])
    moving_seg = pts.valid & (bg.belief > 0) & (bg.use == 0)
    at = jnp.maximum(cell, 0)
    weight = belief_weights(evidence, params)[at]  # as its cell
    if tracked:
        # a point's own track and its cell are independent evidence: their log-odds add,
        # where the cell is not believed to move
        mine = state.point_evidence[_fitted_slots(state.static.shape[0])].reshape(-1)
        weight = jnp.where(weight > 0, belief_weights(mine + evidence[at], params), 0.0)
    belief = jnp.where(kpts.valid & (cell >= 0), weight, 0.0)
    use = jnp.where(moving_seg[at], 0.0, belief)
    return (join_points(pts, kpts), jnp.concatenate([bg.use, use.astype(bg.use.dtype)]),
            jnp.concatenate([bg.belief, belief.astype(bg.belief.dtype)]))


# ------------------------------------------------------------------ the window's problem


class _Problem(NamedTuple):
    """The refinement's data, fixed during its iterations (window coordinates)."""

    point: jax.Array  # (K, m, 3) each keyframe's points in its camera (the readings)
    obs: jax.Array  # (K, K, m, 3) obs[j, i]: keyframe i's point read in camera j
    ray: jax.Array  # (K, K, m, 3) unit ray of each reading
    w_lat: jax.Array  # (K, K, m) 1/m^2 information across the ray (0: no reading)
    w_ray: jax.Array  # (K, K, m) 1/m^2 information along it
    w_own: jax.Array  # (K, m) information of the point's own depth reading on its s (its
    # relative depth change): 1 / (sigma_z / z)^2
    free: jax.Array  # (K,) bool slots whose pose is refined
    c2: jax.Array  # () Cauchy scale, squared normalised residual (3 degrees of freedom)
    link_T: jax.Array  # (K, 4, 4) the chain's T_k_(k-1)
    link_H: jax.Array  # (K, 6, 6) its information (0 where slot k - 1 or k is empty)
    link_g: jax.Array  # (K, 6) its gradient there


class WindowParams(NamedTuple):
    """What the refinement solves for (the pair :func:`levenberg_marquardt` expects)."""

    xi: jax.Array  # (K, 6) left perturbation (rotation, translation) of each keyframe's pose
    s: jax.Array  # (K, m) relative change of each point's depth


def _residuals(T, s, pb: _Problem):
    """Each reading's residual in its camera (K, K, m, 3), the points in window coordinates
    (K, m, 3) and the cameras' rotations: ``R_j^T (R_i P (1 + s) + t_i - t_j) - obs``."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    X = jnp.einsum("iab,imb->ima", R, pb.point * (1.0 + s)[..., None]) + t[:, None]
    d = X[None] - t[:, None, None]  # (K_j, K_i, m, 3) from camera j to the point
    r = jnp.einsum("jba,jimb->jima", R, d) - pb.obs
    return r, X


def _d2(r, pb: _Problem):
    """Squared normalised residuals (K, K, m) of the readings."""
    along = jnp.sum(r * pb.ray, axis=-1)
    lat2 = jnp.sum(r * r, axis=-1) - along * along
    return pb.w_lat * lat2 + pb.w_ray * along * along


def window_cost(T, s, pb: _Problem):
    """The window's robust cost at poses ``T`` (K, 4, 4) and depth changes ``s`` (K, m)."""
    r, _ = _residuals(T, s, pb)
    own = pb.w_own * s * s
    delta, _ = link_terms(T, pb.link_T)
    link = jnp.sum(delta * pb.link_g[1:]) \
        + 0.5 * jnp.einsum("ka,kab,kb->", delta, pb.link_H[1:], delta)
    return cauchy(_d2(r, pb), pb.c2)[0] + cauchy(own, pb.c2)[0] + link


def normal_equations(T, s, pb: _Problem):
    """Gradient, Gauss-Newton matrix and cost of :func:`window_cost` by iteratively
    re-weighted least squares.

    Left perturbations ``xi = (omega, nu)`` of the camera-to-world poses move a point
    ``X`` of keyframe ``i`` as ``X + omega_i x X + nu_i`` and camera ``j`` the other way,
    so a reading's residual, in world axes, moves by ``A (xi_i - xi_j)``, ``A = [-[X]x | I]``,
    and with the point's depth change by ``e = R_i P``. Its metric there is ``M = R_j (w_lat
    (I - u u^T) + w_ray u u^T) R_j^T``. Each reading adds ``A^T M A`` to the blocks ``(i, i)``
    and ``(j, j)`` and subtracts it from ``(i, j)``, and couples both poses with its point
    (the arrow's cross block); the points' own readings add to the diagonal only.
    """
    K, m = s.shape
    R = T[:, :3, :3]
    r, X = _residuals(T, s, pb)
    value, w = cauchy(_d2(r, pb), pb.c2)
    rw = jnp.einsum("jab,jimb->jima", R, r)  # residuals in world axes
    u = jnp.einsum("jab,jimb->jima", R, pb.ray)  # rays in world axes
    wl, wr = w * pb.w_lat, w * pb.w_ray

    # each reading's metric in world axes, M = w_lat (I - u u^T) + w_ray u u^T
    M = wl[..., None, None] * jnp.eye(3) + (wr - wl)[..., None, None] * (
        u[..., :, None] * u[..., None, :])
    e = jnp.einsum("iab,imb->ima", R, pb.point)[None]  # (1, K_i, m, 3)
    Xb = jnp.broadcast_to(X[None], r.shape)

    def At(v):  # A^T v = (X x v, v) for the 6 rows (omega, nu)
        return jnp.concatenate([jnp.cross(Xb, v), v], axis=-1)

    Mr = jnp.einsum("...ab,...b->...a", M, rw)
    Me = jnp.einsum("...ab,...b->...a", M, jnp.broadcast_to(e, r.shape))
    g_obs = At(Mr)  # (K_j, K_i, m, 6)
    c_obs = At(Me)  # d/dxi_i of the coupling with the point
    # A^T M A per reading, summed over the points of each (j, i)
    skX = skew(Xb)  # [X]x
    MA_om, MA_nu = -M @ skX, M
    MA = jnp.concatenate([MA_om, MA_nu], axis=-1)  # (.., 3, 6)
    AtMA = jnp.concatenate([skX @ MA, MA], axis=-2)  # A^T = [[ [X]x ], [I]] (6, 3)
    B = jnp.sum(AtMA, axis=2)  # (K_j, K_i, 6, 6)
    eye = jnp.eye(K, dtype=T.dtype)
    diag = jnp.sum(B, axis=0) + jnp.sum(B, axis=1)  # (K, 6, 6): as i, and as j
    blocks = eye[:, :, None, None] * diag[:, None] - jnp.swapaxes(B, 0, 1) - B
    H = jnp.transpose(blocks, (0, 2, 1, 3)).reshape(6 * K, 6 * K)
    g = jnp.sum(g_obs, axis=(0, 2)) - jnp.sum(g_obs, axis=(1, 2))  # (K, 6)
    # the cross block: pose a with point (i, p): delta(a, i) sum_j c[j, i, p] - c[a, i, p]
    cross = eye[:, :, None, None] * jnp.sum(c_obs, axis=0)[None] - c_obs  # (K_a, K_i, m, 6)
    own_value, w_own = cauchy(pb.w_own * s * s, pb.c2)
    d_s = jnp.sum(jnp.sum(e * Me, axis=-1), axis=0) + w_own * pb.w_own
    g_s = jnp.sum(jnp.sum(e * Mr, axis=-1), axis=0) + w_own * pb.w_own * s
    H_link, g_link, value_link = link_equations(T, pb.link_T, pb.link_H, pb.link_g)
    H, g, value = H + H_link, g + g_link, value + value_link
    free = jnp.repeat(pb.free, 6)
    H = jnp.where(free[:, None] & free[None, :], H, jnp.diag(jnp.where(free, 0.0, 1.0)))
    g = jnp.where(pb.free[:, None], g, 0.0)
    cross = jnp.where(pb.free[:, None, None, None], cross, 0.0)
    C = ArrowCurvature(H, jnp.transpose(cross, (0, 3, 1, 2)).reshape(6 * K, K * m),
                       d_s.reshape(-1))
    return WindowParams(g, g_s), C, value + own_value


def link_terms(T, link_T):
    """Each consecutive pair of slots' deviation ``delta`` (K-1, 6) from the chain's
    measured motion, ``T_k^-1 T_(k-1) = exp(delta) T_meas`` (first order), and the adjoints
    ``Ad(T_k^-1)`` (K-1, 6, 6) that map the window's perturbations to it."""
    T_rel = invert_pose(T[1:]) @ T[:-1]
    E = T_rel @ invert_pose(link_T[1:])
    S = 0.5 * (E[:, :3, :3] - jnp.swapaxes(E[:, :3, :3], 1, 2))
    delta = jnp.stack([S[:, 2, 1], S[:, 0, 2], S[:, 1, 0], E[:, 0, 3], E[:, 1, 3], E[:, 2, 3]],
                      axis=1)
    return delta, adjoint(invert_pose(T[1:]))


def link_equations(T, link_T, link_H, link_g):
    """The chain's quadratic factors on consecutive slots as the window's Gauss-Newton
    matrix (6K, 6K), gradient (K, 6) and cost: slot pair ``(k - 1, k)`` moves its deviation
    by ``D (xi_(k-1) - xi_k)``, ``D = Ad(T_k^-1)``."""
    K = T.shape[0]
    delta, D = link_terms(T, link_T)
    Hd = jnp.einsum("kab,kb->ka", link_H[1:], delta)
    gp = link_g[1:] + Hd
    value = jnp.sum(delta * link_g[1:]) + 0.5 * jnp.sum(delta * Hd)
    SL = jnp.einsum("kba,kbc,kcd->kad", D, link_H[1:], D)
    gl = jnp.einsum("kba,kb->ka", D, gp)
    zero = jnp.zeros((1, 6, 6), T.dtype)
    diag = jnp.concatenate([SL, zero]) + jnp.concatenate([zero, SL])
    g = jnp.concatenate([gl, zero[:, 0]]) - jnp.concatenate([zero[:, 0], gl])
    up = jnp.eye(K, k=1, dtype=T.dtype)[:, :, None, None] * jnp.concatenate([SL, zero])[:, None]
    blocks = jnp.eye(K, dtype=T.dtype)[:, :, None, None] * diag[:, None] - up \
        - jnp.swapaxes(up, 0, 1)
    return jnp.transpose(blocks, (0, 2, 1, 3)).reshape(6 * K, 6 * K), g, value


def refine(T, pb: _Problem, iters: int):
    """``iters`` Levenberg-Marquardt iterations on the poses ``T`` (K, 4, 4) and the points'
    depths, a last step undone if it raised the cost: the refined poses and each point's
    relative depth change (K, m)."""
    opt = levenberg_marquardt()
    x0 = WindowParams(jnp.zeros((T.shape[0], 6), jnp.float32),
                      jnp.zeros(pb.point.shape[:2], jnp.float32))

    def body(_, carry):
        x, opt_state = carry
        grad, C, value = normal_equations(perturb(T, x.xi), x.s, pb)
        step, opt_state = opt.update(grad, opt_state, x, curvature=C, value=value)
        return optax.apply_updates(x, step), opt_state

    x, opt_state = jax.lax.fori_loop(0, iters, body, (x0, opt.init(x0)))
    worse = ~(window_cost(perturb(T, x.xi), x.s, pb) <= opt_state.value)
    last = WindowParams(opt_state.step[0].reshape(x.xi.shape),
                        opt_state.step[1].reshape(x.s.shape))
    x = jax.tree.map(lambda v, d: jnp.where(worse, v - d, v), x, last)
    return perturb(T, x.xi), x.s


def _problem(st: KeyframeState, focal, scale: NoiseScale, params: Params) -> _Problem:
    """The refinement's data from the window ``st``: each reading's noise from the sensor
    noise model (a depth reading and a tracked pixel each)."""
    K = st.T_w_kf.shape[0]
    seen = st.seen & st.taken[:, None, None] & st.taken[None, :, None] & st.static[None]
    z = st.obs[..., 2]
    norm = jnp.linalg.norm(st.obs, axis=-1)
    zp = st.point[..., 2]
    fixed = jnp.argmax(st.taken)
    both = st.taken & jnp.concatenate([jnp.zeros((1,), bool), st.taken[:-1]])
    # a pose is refined only where something measures it: enough readings it takes or
    # offers, or the chain to a neighbour (a keyframe of skipped pairs has neither)
    reads = jnp.sum(seen, axis=(1, 2)) + jnp.sum(seen, axis=(0, 2))
    linked = both & (jnp.trace(st.link_H, axis1=1, axis2=2) > 0)
    chained = linked | jnp.concatenate([linked[1:], jnp.zeros((1,), bool)])
    measured = (reads >= params.min_static_points) | chained
    free = st.taken & (jnp.arange(K) != fixed) & measured
    return _Problem(
        point=st.point,
        obs=st.obs,
        ray=st.obs / jnp.maximum(norm, tiny())[..., None],
        w_lat=jnp.where(seen, focal * focal / jnp.maximum((scale.pixel_sigma * z) ** 2, tiny()),
                        0.0),
        w_ray=jnp.where(seen, 1.0 / jnp.maximum((scale.depth_coeff * z * z) ** 2, tiny()), 0.0),
        w_own=jnp.where(st.static, 1.0 / jnp.maximum((scale.depth_coeff * zp) ** 2, tiny()), 0.0),
        free=free,
        c2=chi2_quantile(3, params.confidence),
        link_T=st.link_T,
        link_H=jnp.where(both[:, None, None], st.link_H, 0.0),
        link_g=jnp.where(both[:, None], st.link_g, 0.0),
    )


# ------------------------------------------------------------------------ the update


def _shift(x, new):
    """Drop slot 0 of ``x`` (K, ...) and append ``new`` (...) as slot K - 1."""
    return jnp.concatenate([x[1:], new[None]], axis=0)


def _take(state: KeyframeState, kf, T_w_c, static, index, link, measured) -> KeyframeState:
    """The window with the current frame as its latest keyframe: the oldest leaves, the
    new one brings its points and its readings of the window's points (none where its
    ego-motion was not ``measured``: nothing then says which of them are the world's)."""
    K = state.T_w_kf.shape[0]
    W = K - 1
    point = _shift(state.point, kf.new_kf[index])
    stat = _shift(state.static, static[index] & (kf.new_kf[index, 2] > 0))
    obs = jnp.zeros_like(state.obs).at[:W, :W].set(state.obs[1:, 1:])
    seen = jnp.zeros_like(state.seen).at[:W, :W].set(state.seen[1:, 1:])
    if W:
        obs = obs.at[W, :W].set(kf.win_cur[:, index])
        seen = seen.at[W, :W].set(kf.win_valid[:, index] & measured)
    T_meas, H, g = link
    return KeyframeState(_shift(state.T_w_kf, T_w_c), _shift(state.taken, jnp.bool_(True)),
                         point, stat, obs, seen, state.count + 1, jnp.bool_(False),
                         _shift(state.link_T, T_meas), _shift(state.link_H, H),
                         _shift(state.link_g, g), state.blind,
                         _shift(state.track_noise, jnp.float32(1.0)),
                         _shift(state.cusum, jnp.zeros_like(state.cusum[0])),
                         _shift(state.point_evidence, jnp.zeros_like(state.point_evidence[0])))


def _learn_first(state: KeyframeState, kf, index) -> KeyframeState:
    """The first keyframe's points from the first pair's keyframe flow (the points it
    tracked; nothing is known to move yet)."""
    ok = kf.valid[index] & (kf.pts_kf[index, 2] > 0)
    return state._replace(
        point=state.point.at[-1].set(jnp.where(ok[:, None], kf.pts_kf[index], 0.0)),
        static=state.static.at[-1].set(ok), fresh=jnp.bool_(False))


class KeyframeInputs(NamedTuple):
    """What the keyframe window reads after the pair (:func:`update_keyframe`)."""

    kf: KeyframeFlow  # the pair's keyframe flow (jaxvo.host.frontend.keyframes.KeyframeTracker)
    T_w_c: jax.Array  # (4, 4) float32 the current camera's pose from the ego-motion
    static: jax.Array  # (n,) bool grid points of the current image the temporal model holds static
    # the pair's ego-motion, the previous camera's pose, the pair's points and those the
    # ego-motion used: the chain's motion from the latest keyframe to the current camera
    # and the pair's information on it (jaxvo.core.lm.pair_factor), the window's tie
    # between a new keyframe and the one before
    T_cur_prev: jax.Array  # (4, 4) float32
    T_w_prev: jax.Array  # (4, 4) float32
    pts: Points
    used: jax.Array  # (n,) bool
    noise: NoiseScale  # the sensor noise model
    focal: jax.Array  # () float32 focal length, pixels
    # () bool the pair's ego-motion was measured (EgoOut.ok): a keyframe taken where it was
    # not (no background in view, too few points) keeps no point and reads nothing
    ok: jax.Array
    # (cfg.keyframe_track_window) the keyframe points' normalised residuals under the
    # pair's ego-motion ((K - 1) m,) and which of them it weighed
    track_d2: jax.Array | None = None
    track_weighed: jax.Array | None = None


def update_keyframe(state: KeyframeState, inputs: KeyframeInputs, params: Params, *,
                    cfg: StepOptions, grid):
    """After the pair: where the host renews the keyframe (``kf.renew``), the current frame
    joins the window as its latest keyframe and the window is refined.

    Args:
      state: the window; inputs: the pair's :class:`KeyframeInputs`.
      params: numeric settings (``confidence``).
      cfg: static settings (``keyframe_window``, ``keyframe_iters``, ``keyframe_stride``);
      grid: static ``(rows, cols)``.

    Returns:
      ``(KeyframeState, KeyframeOut)``; the output's pose is the refined latest keyframe's
      where a keyframe was taken, else ``T_w_c``.
    """
    index = keyframe_index(grid, cfg.keyframe_stride)
    kf, T_w_c, static, T_cur_prev, T_w_prev, pts, used, noise, focal, ok, d2, weighed = inputs
    if d2 is not None:
        state = jax.lax.cond(ok, lambda st: track_evidence(st, d2, weighed, params),
                             lambda st: st, state)

    def take(st):  # on keyframe frames only (lax.cond): the pair's factor is built here
        # after frames whose ego-motion was not measured (no background in view) nothing
        # ties this keyframe to the window's: neither the chain of carried poses nor its
        # readings of their points (found on whatever filled the view); it starts anew
        anew = st.blind | ~ok
        st = st._replace(taken=st.taken & ~anew, seen=st.seen & ~anew)
        T_cur_kf = T_cur_prev @ invert_pose(T_w_prev) @ st.T_w_kf[-1]
        link = (T_cur_kf, *pair_factor(T_cur_prev, pts, used, pts.thr))
        st = _take(st, kf, T_w_c, static & ok, index, link, ok)._replace(blind=~ok)
        if cfg.keyframe_window < 2 or not cfg.keyframe_iters:
            return st
        fixed = jnp.argmax(st.taken)
        T_ref = st.T_w_kf[fixed]
        pb = _problem(st, focal, noise, params)
        T_local, s = refine(invert_pose(T_ref)[None] @ st.T_w_kf, pb, cfg.keyframe_iters)
        T_new = jnp.where(pb.free[:, None, None], orthonormal(T_ref[None] @ T_local),
                          st.T_w_kf)
        return st._replace(T_w_kf=T_new, point=st.point * (1.0 + s)[..., None])

    state = jax.lax.cond(state.fresh, lambda st: _learn_first(st, kf, index), lambda st: st,
                         state)
    new = jax.lax.cond(kf.renew, take, lambda st: st._replace(blind=st.blind | ~ok), state)
    T_out = jnp.where(kf.renew, new.T_w_kf[-1], T_w_c)
    return new, KeyframeOut(T_out, new.count)

