"""Sliding-window refinement of the most recent camera poses (device side).

Our addition to the thesis, whose odometry, like OpenCV's and Open3D's, is frame to frame:
every pair's error adds to the pose chain. The window keeps the last ``K = cfg.window``
frames and refines their poses jointly against points tracked through all of them, the
oldest pose held fixed. A frame's pose is final once it leaves the window.

Tracks. Each track is seeded at a grid point of a pair's previous image that the
ego-motion used (static background, inlier), keeping that point's 3D position (its first
observation's depth) in the seeding frame, its *anchor*. It is chained through every later
pair by interpolating that pair's grid flow bilinearly at the track's position
(:func:`chain_tracks`); the track dies where one of the four neighbouring grid points is
not one the pair's ego-motion used, where their depths disagree (a depth edge), or where it
leaves the grid: only points labelled static throughout stay alive. Each chained
observation is the 3D point at the track's new pixel, from the same neighbours: inverse
depth interpolated (exact on a plane, where ``1/z`` is affine in the pixel), and the
viewing ray of the new pixel from the neighbours' rays (the pixel-to-ray map is affine).
When its anchor leaves the window, a track is re-expressed in the new oldest frame, whose
pose is fixed from then on: it goes on constraining the window as a point of the map.
A dead track's slot is seeded again at its grid point as soon as that point is usable.

Refinement. The window's cost has two kinds of terms, each residual in units of the sensor
noise model (:mod:`jaxvo.core.noise`) and under Cauchy's robust loss ``c^2 / 2 log(1 + d2 /
c^2)`` (``c^2`` the chi-square quantile at ``params.confidence``):

* pair terms: each pair's points the ego-motion used, their residuals ``T src - dst``
  split into the lateral part (across the tracked point's ray: the reprojection error
  times the depth) and the part along the ray (the depth error). Linearised once, when the
  pair enters, about its ego-motion (:func:`pair_factor`): a 6 x 6 quadratic factor on the
  pair's relative pose. These hold every pair's information for as long as both frames
  are in the window;
* depth terms: each track observation's depth reading against its track's point, whose
  depth along the anchor's ray is a parameter of its own (the anchor's reading is one
  more observation of it). The depth noise of RGB-D sensors is independent from frame to
  frame, so a point seen in K frames pins its depth, and the translation along it, better
  than any pair.

The tracks give no lateral terms: a chained observation's pixel error is the sum of the
tracker errors of every pair it went through (a random walk), so the pixel information
between two frames is the pair's own, already in the pair terms; treating chained pixels
as independent observations gave the far frames too much weight and the near ones too
little (7-Scenes ATE 15.7 -> 17.0 mm, synthetic 1.7 -> 2.8 mm). The poses (left
perturbations, the oldest held fixed) and the depths are solved jointly by
Levenberg-Marquardt, written as an optax gradient transformation
(:func:`levenberg_marquardt`) over the arrow-structured Gauss-Newton matrix (dense over
the poses, diagonal over the depths; the Schur complement of the depths leaves one
``6K x 6K`` Cholesky); gradient and matrix come from iteratively re-weighted least
squares, and a step that raises the cost is undone and retried with more damping. A fixed
number of iterations, no Python branch on traced values: the window is explicit state of
the per-frame step, so scan, streaming and study runs agree bit for bit.

Conventions as everywhere (:mod:`jaxvo.core.geometry`): poses are camera-to-world ``T_w_c``;
the window's slots are ordered oldest first, slot ``K - 1`` is the newest frame.
"""

from __future__ import annotations

from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxvo.config import Config, Params
from jaxvo.core.geometry import invert_pose
from jaxvo.core.lm import (
    ArrowCurvature,
    adjoint,
    cross_cols,
    levenberg_marquardt,
    orthonormal,
    pair_factor,
    perturb,
)
from jaxvo.core.noise import NoiseScale, Points
from jaxvo.core.robust import cauchy, chi2_quantile

# A track continues where its four neighbours' depths agree within this fraction: across a
# depth edge the interpolated flow mixes two motions (parallax).
_DEPTH_AGREE = 0.05
_TINY = 1e-12
# Tracks are seeded at every second grid row and column: a quarter of the grid points
# gave the same accuracy as all of them (synthetic room, 40 frames: position error 1.55
# against 1.75 mm; 7-Scenes within 0.3 mm) at a quarter of the depth terms' cost.
_SEED_STRIDE = 2


class WindowState(NamedTuple):
    """The last ``K`` frames and the points tracked through them (carried by the pipeline).

    Frames are slots ``0 .. K-1``, oldest first; track slots ``0 .. cap-1`` each belong to one
    grid point, where the slot is seeded.
    """

    # the frames
    T_w_c: jax.Array  # (K, 4, 4) float32 camera-to-world pose of each slot's frame
    frame_id: jax.Array  # (K,) int32 frame number (0 = the first frame), -1 for an empty slot
    # the tracks
    anchor: jax.Array  # (cap,) int32 frame slot the track's point is expressed in
    point: jax.Array  # (cap, 3) float32 metres, the point in the anchor's camera frame
    uv: jax.Array  # (cap, 2) float32 pixels, the track's position in the newest image
    alive: jax.Array  # (cap,) bool the track can be chained through the next pair
    obs: jax.Array  # (K, cap, 3) float32 metres, the track observed in each frame's camera
    seen: jax.Array  # (K, cap) bool whether ``obs`` holds an observation
    # the pairs: slot k holds the ego-motion of the pair (k - 1, k) and its information
    pair_T: jax.Array  # (K, 4, 4) float32 the pair's ego-motion T_k_(k-1)
    pair_H: jax.Array  # (K, 6, 6) float32 Gauss-Newton matrix of the pair's points there
    pair_g: jax.Array  # (K, 6) float32 their gradient there (left perturbations, camera k)


class WindowOut(NamedTuple):
    """What one window update gives back."""

    T_w_c: jax.Array  # (K, 4, 4) float32 refined camera-to-world poses, oldest first
    frame_id: jax.Array  # (K,) int32 frame numbers of the slots, -1 empty
    T_w_left: jax.Array  # (4, 4) float32 final pose of the frame that left the window
    left_id: jax.Array  # () int32 its frame number, -1 when no frame left this step
    observations: jax.Array  # () int32 track observations the refinement used
    refined: jax.Array  # () bool the newest frame had enough observations to be refined


def seed_index(grid: tuple[int, int]) -> np.ndarray:
    """The grid points (row-major indices) that seed tracks, one track slot each: every
    ``_SEED_STRIDE``-th row and column of the ``(rows, cols)`` grid."""
    rows, cols = grid
    r, c = np.meshgrid(np.arange(0, rows, _SEED_STRIDE), np.arange(0, cols, _SEED_STRIDE),
                       indexing="ij")
    return (r * cols + c).ravel().astype(np.int32)


def seed_points(grid: tuple[int, int]) -> int:
    """Number of track slots for a ``(rows, cols)`` grid (:func:`seed_index`)."""
    return len(seed_index(grid))


def init_window(*, cfg: Config, grid: tuple[int, int], T_w_c0=None) -> WindowState:
    """A window that holds the first frame only (pose ``T_w_c0``, default identity), no
    tracks.

    Args:
      cfg: static settings (``cfg.window`` frames, at least 2).
      grid: static ``(rows, cols)`` of the flow grid.
      T_w_c0: (4, 4) camera-to-world pose of the first frame.
    """
    K, cap = cfg.window, seed_points(grid)
    T0 = jnp.eye(4, dtype=jnp.float32) if T_w_c0 is None else jnp.asarray(T_w_c0, jnp.float32)
    chex.assert_shape(T0, (4, 4))
    poses = jnp.broadcast_to(jnp.eye(4, dtype=jnp.float32), (K, 4, 4)).at[K - 1].set(T0)
    return WindowState(
        T_w_c=poses,
        frame_id=jnp.full((K,), -1, jnp.int32).at[K - 1].set(0),
        anchor=jnp.zeros((cap,), jnp.int32),
        point=jnp.zeros((cap, 3), jnp.float32),
        uv=jnp.zeros((cap, 2), jnp.float32),
        alive=jnp.zeros((cap,), bool),
        obs=jnp.zeros((K, cap, 3), jnp.float32),
        seen=jnp.zeros((K, cap), bool),
        pair_T=jnp.broadcast_to(jnp.eye(4, dtype=jnp.float32), (K, 4, 4)),
        pair_H=jnp.zeros((K, 6, 6), jnp.float32),
        pair_g=jnp.zeros((K, 6), jnp.float32),
    )


# --------------------------------------------------------------------------- tracks


def _neighbours(uv, grid, cell):
    """Bilinear neighbours on the flow grid of pixel positions ``uv`` (m, 2).

    Returns ``(idx (m, 4) int32, w (m, 4) float32, inside (m,) bool)``: the four grid points
    around each position (row-major indices), their bilinear weights, and whether the
    position lies within the grid's cell centres (``cell`` pixels apart, the first at
    ``(cell - 1) / 2``; :func:`jaxvo.host.camera.grid_pixels`). A grid point placed off its
    cell's centre (``Config.textured_points``) stands for its cell.
    """
    rows, cols = grid
    f = (uv - 0.5 * (cell - 1)) / cell
    i0 = jnp.clip(jnp.floor(f[:, 0]), 0, cols - 2)
    j0 = jnp.clip(jnp.floor(f[:, 1]), 0, rows - 2)
    a, b = f[:, 0] - i0, f[:, 1] - j0
    inside = (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1) & jnp.all(jnp.isfinite(uv), axis=1)
    a, b = jnp.clip(a, 0, 1), jnp.clip(b, 0, 1)
    base = (j0 * cols + i0).astype(jnp.int32)
    idx = jnp.stack([base, base + 1, base + cols, base + cols + 1], axis=1)
    w = jnp.stack([(1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b], axis=1)
    return idx, w.astype(jnp.float32), inside


def chain_tracks(uv, flow, usable, grid, cell):
    """Each track's position and 3D observation in the pair's current image.

    The pair's grid flow is interpolated bilinearly at ``uv`` from the four neighbouring
    grid points: the displacement ``uv_cur - uv_prev``, the inverse depth of their current
    points (exact on a plane, where ``1/z`` is affine in the pixel), and their viewing rays
    in normalised image coordinates (``x / z, y / z``: the pixel-to-ray map is affine, so
    the interpolated ray is the ray of the interpolated pixel). A track goes on only where
    all four neighbours are ``usable`` and their depths agree within ``_DEPTH_AGREE``:
    across a depth edge the neighbours move differently (parallax) and the interpolated
    depth lies between the two surfaces. Where two surfaces meet at a crease without a
    depth edge, ``1/z`` is not affine and the interpolated depth is off by up to a few
    millimetres at 3 m (the synthetic room's wall corners, within the sensor's noise there);
    nothing here can tell those apart from a plane.

    Args:
      uv: (m, 2) positions in the pair's previous image, pixels.
      flow: the pair's ``GridFlow`` (device arrays).
      usable: (n,) bool grid points whose flow may be used (valid, static).
      grid: static ``(rows, cols)``; cell: static, the grid cell's side, pixels.

    Returns:
      ``(uv_new (m, 2) pixels, Q (m, 3) metres in the current camera, ok (m,) bool)``; ``ok``
      is False where a neighbour is not usable, their depths disagree, or the position is
      off the grid.
    """
    idx, w, inside = _neighbours(uv, grid, cell)
    z = flow.pts_cur[idx, 2]  # (m, 4) metres
    use = usable[idx] & (z > 0)
    every = jnp.all(use, axis=1)
    zs = jnp.where(use, z, 1.0)
    disp = flow.uv_cur - flow.uv_prev
    uv_new = uv + jnp.einsum("mi,mic->mc", w, disp[idx])
    ray = flow.pts_cur[idx, :2] / zs[..., None]  # (m, 4, 2) normalised image coordinates
    m = jnp.einsum("mi,mic->mc", w, ray)
    z_new = 1.0 / jnp.maximum(jnp.sum(w / zs, axis=1), _TINY)
    Q = jnp.concatenate([m * z_new[:, None], z_new[:, None]], axis=1)
    agree = (jnp.max(zs, axis=1) - jnp.min(zs, axis=1)) <= _DEPTH_AGREE * z_new
    ok = inside & every & agree & jnp.all(jnp.isfinite(Q), axis=1)
    return uv_new, jnp.where(ok[:, None], Q, 0.0), ok


def _shift(x, new):
    """Drop slot 0 of ``x`` (K, ...) and append ``new`` (...) as slot K - 1."""
    return jnp.concatenate([x[1:], new[None]], axis=0)


# ------------------------------------------------------------------------ the solver


class WindowParams(NamedTuple):
    """What the refinement solves for (the pair :func:`levenberg_marquardt` expects)."""

    xi: jax.Array  # (K, 6) left perturbation (rotation, translation) of each frame's pose
    s: jax.Array  # (cap,) relative change of each track's depth


class _Problem(NamedTuple):
    """The refinement's data, fixed during the iterations (window-local coordinates).

    Pair terms: each pair's points as a quadratic factor on its relative pose about its
    ego-motion (:func:`pair_factor`; index ``k`` for the pair ``(k - 1, k)``). Depth terms: each track observation's depth reading against its track's point
    (index ``k``, the anchor's own reading included), points stored as columns.
    """

    pair_T: jax.Array  # (K, 4, 4) measured T_k_(k-1)
    pair_H: jax.Array  # (K, 6, 6) Gauss-Newton matrix of the pair's points (0 unused)
    pair_g: jax.Array  # (K, 6) their gradient at pair_T
    anchor1h: jax.Array  # (cap, K) float32 one-hot anchor slot of each track
    point: jax.Array  # (3, cap) metres, the track's point in the anchor's camera frame
    obs: jax.Array  # (K, 3, cap) metres, observations in each frame's camera
    ray: jax.Array  # (K, 3, cap) unit viewing ray of each observation
    w_dep: jax.Array  # (K, cap) 1/m^2 information of the depth term at k (0 unused)
    free: jax.Array  # (K,) bool slots whose pose is refined
    c2_dep: jax.Array  # () Cauchy scale of the depth terms, squared normalised residual


def _pair_terms(T, pb: _Problem):
    """Each pair's deviation ``delta`` (K-1, 6) from its measured motion, with
    ``T_k^-1 T_(k-1) = exp(delta) T_meas`` (first order: the window moves poses by
    millimetres), and the adjoints ``Ad(T_k^-1)`` (K-1, 6, 6) that map the window's
    perturbations to it."""
    T_rel = invert_pose(T[1:]) @ T[:-1]
    E = T_rel @ invert_pose(pb.pair_T[1:])
    S = 0.5 * (E[:, :3, :3] - jnp.swapaxes(E[:, :3, :3], 1, 2))
    delta = jnp.stack([S[:, 2, 1], S[:, 0, 2], S[:, 1, 0], E[:, 0, 3], E[:, 1, 3], E[:, 2, 3]],
                      axis=1)
    return delta, adjoint(invert_pose(T[1:]))


def _depth_terms(T, s, pb: _Problem):
    """The tracks' points in window coordinates (3, cap) and their depth residuals along
    each observation's ray (K, cap), metres."""
    Ta = (pb.anchor1h @ T.reshape(T.shape[0], 16)).reshape(-1, 4, 4)  # (cap, 4, 4)
    P = pb.point * (1.0 + s)
    Xa = jnp.einsum("nij,jn->in", Ta[:, :3, :3], P) + Ta[:, :3, 3].T
    pa = jnp.einsum("kij,kin->kjn", T[:, :3, :3], Xa[None] - T[:, :3, 3, None])
    return Xa, jnp.sum(pa * pb.ray, axis=1) - jnp.linalg.norm(pb.obs, axis=1)


def window_cost(T, s, pb: _Problem):
    """The window's cost at poses ``T`` (K, 4, 4) and depth changes ``s`` (cap,): the pairs'
    quadratic image-plane terms plus the tracks' robust depth terms."""
    delta, _ = _pair_terms(T, pb)
    pair = jnp.sum(delta * pb.pair_g[1:]) \
        + 0.5 * jnp.einsum("ka,kab,kb->", delta, pb.pair_H[1:], delta)
    _, rd = _depth_terms(T, s, pb)
    return pair + cauchy(pb.w_dep * rd * rd, pb.c2_dep)[0]


def normal_equations(T, s, pb: _Problem):
    """Gradient, Gauss-Newton matrix and cost of :func:`window_cost` at poses ``T`` (K, 4,
    4) and depth changes ``s`` (cap,), by iteratively re-weighted least squares.

    Left perturbations ``xi`` of the camera-to-world poses (window coordinates). A pair
    ``(k - 1, k)`` moves its deviation by ``D (xi_(k-1) - xi_k)``, ``D = Ad(T_k^-1)``: it
    adds ``D^T H D`` to the blocks ``(k-1, k-1)`` and ``(k, k)`` and subtracts it from ``(k-1,
    k)``. A track's point ``X`` attached to its anchor ``a`` and seen in camera ``k`` moves
    along the observed ray ``u`` by ``q . (xi_a - xi_k)``, ``q = (X x R_k u, R_k u)``, and
    with the track's depth change ``s`` by ``e = (R_k u) . (R_a P)``: it adds ``w q q^T`` to
    the blocks ``(a, a)``, ``(k, k)``, subtracts it from ``(a, k)``, and couples the two
    slots with the track (the arrow's cross block). Fixed and empty slots get a unit
    diagonal and no coupling.

    Returns:
      ``(WindowParams gradient, ArrowCurvature, cost)``.
    """
    K = T.shape[0]
    R = T[:, :3, :3]
    # pair terms, pair (k - 1, k) at index k - 1
    delta, D = _pair_terms(T, pb)
    Hd = jnp.einsum("kab,kb->ka", pb.pair_H[1:], delta)
    gp = pb.pair_g[1:] + Hd
    value_p = jnp.sum(delta * pb.pair_g[1:]) + 0.5 * jnp.sum(delta * Hd)
    SL = jnp.einsum("kab,kbc,kcd->kad", jnp.swapaxes(D, 1, 2), pb.pair_H[1:], D)
    gl = jnp.einsum("kba,kb->ka", D, gp)
    zero = jnp.zeros((1, 6, 6), T.dtype)
    diag_l = jnp.concatenate([SL, zero]) + jnp.concatenate([zero, SL])
    grad_l = jnp.concatenate([gl, zero[:, 0]]) - jnp.concatenate([zero[:, 0], gl])
    up = jnp.eye(K, k=1, dtype=T.dtype)  # (k - 1, k) pairs

    # depth terms
    Xa, rd = _depth_terms(T, s, pb)
    value_d, wd = cauchy(pb.w_dep * rd * rd, pb.c2_dep)
    rho = jnp.einsum("kij,kjn->kin", R, pb.ray)  # rays in window axes, (K, 3, cap)
    wdep = wd * pb.w_dep
    qd = jnp.concatenate([cross_cols(Xa[None], rho), rho], axis=1)  # (K, 6, cap)
    Ra = (pb.anchor1h @ R.reshape(K, 9)).reshape(-1, 3, 3)
    RP = jnp.einsum("nij,jn->in", Ra, pb.point)
    e = jnp.sum(rho * RP[None], axis=1)  # d(depth residual)/ds, (K, cap)
    not_anchor = 1.0 - pb.anchor1h.T  # (K, cap)
    wq = (wdep * not_anchor)[:, None, :] * qd
    own = jnp.einsum("kxn,kyn->kxy", wq, qd)
    cross = jnp.einsum("kxn,na,kyn->kaxy", wq, pb.anchor1h, qd)
    at_anchor = jnp.sum(cross, axis=0)
    gq = wq * rd[:, None, :]
    grad_d = jnp.einsum("kxn,na->ax", gq, pb.anchor1h) - jnp.sum(gq, axis=2)
    ewq = e[:, None, :] * wq  # (K, 6, cap)
    h = pb.anchor1h.T[:, None, :] * jnp.sum(ewq, axis=0)[None] - ewq  # (K, 6, cap)

    eye_k = jnp.eye(K, dtype=T.dtype)
    off = up[:, :, None, None] * jnp.concatenate([SL, zero])[:, None] + cross
    blocks = eye_k[:, :, None, None] * (diag_l + own + at_anchor)[:, None] - off \
        - jnp.swapaxes(off, 0, 1)  # every 6 x 6 block is symmetric
    H = jnp.transpose(blocks, (0, 2, 1, 3)).reshape(6 * K, 6 * K)
    g = grad_l + grad_d
    free = jnp.repeat(pb.free, 6)
    H = jnp.where(free[:, None] & free[None, :], H, jnp.diag(jnp.where(free, 0.0, 1.0)))
    g = jnp.where(pb.free[:, None], g, 0.0)
    h = jnp.where(pb.free[:, None, None], h, 0.0)
    curvature = ArrowCurvature(H, h.reshape(6 * K, -1), jnp.sum(wdep * e * e, axis=0))
    grad = WindowParams(g, jnp.sum(wdep * e * rd, axis=0))
    return grad, curvature, value_p + value_d


def refine(T, pb: _Problem, iters: int):
    """``iters`` Levenberg-Marquardt iterations (:func:`levenberg_marquardt`) on the poses
    ``T`` (K, 4, 4) and the tracks' depths, a last step undone if it raised the cost.

    Returns the refined poses (K, 4, 4) and each track's relative depth change (cap,).
    """
    opt = levenberg_marquardt()
    x0 = WindowParams(jnp.zeros((T.shape[0], 6), jnp.float32),
                      jnp.zeros(pb.point.shape[1:], jnp.float32))

    def body(_, carry):
        x, opt_state = carry
        grad, C, value = normal_equations(perturb(T, x.xi), x.s, pb)
        step, opt_state = opt.update(grad, opt_state, x, curvature=C, value=value)
        return optax.apply_updates(x, step), opt_state

    x, opt_state = jax.lax.fori_loop(0, iters, body, (x0, opt.init(x0)))
    worse = ~(window_cost(perturb(T, x.xi), x.s, pb) <= opt_state.value)
    last = WindowParams(opt_state.step[0].reshape(x.xi.shape), opt_state.step[1])
    x = jax.tree.map(lambda v, d: jnp.where(worse, v - d, v), x, last)
    return perturb(T, x.xi), x.s


# ----------------------------------------------------------------------- the update


def update_window(state: WindowState, flow, pts: Points, T_cur_prev, static,
                  noise_scale: NoiseScale, params: Params, *, cfg: Config,
                  grid: tuple[int, int]):
    """Add this pair's current frame to the window, chain and seed tracks, refine the poses.

    Args:
      state: the carried :class:`WindowState`.
      flow: this pair's ``GridFlow`` (``pts_prev``, ``pts_cur`` (n, 3) metres, ``uv_prev``,
        ``uv_cur`` (n, 2) pixels, ``valid`` (n,) bool, ``focal`` () pixels).
      pts: the pair's points and their noise as the step built them
        (:func:`jaxvo.core.noise.frame_points`).
      T_cur_prev: (4, 4) this pair's ego-motion (previous camera points -> current).
      static: (n,) bool grid points of the previous image the ego-motion used (static
        background, inliers); only these seed and carry tracks.
      noise_scale: the sensor noise model (:class:`jaxvo.core.noise.NoiseScale`).
      params: numeric settings (``confidence`` sets the robust loss's scale,
        ``min_static_points`` the fewest usable static points of the pair to call it
        refined).
      cfg: static settings (``window`` frames K >= 2, ``window_iters``).
      grid: static ``(rows, cols)``.

    Returns:
      ``(WindowState, WindowOut)``.
    """
    K, n = cfg.window, grid[0] * grid[1]
    cap = seed_points(grid)
    chex.assert_shape([flow.pts_prev, flow.pts_cur], (n, 3))
    chex.assert_shape([flow.uv_prev, flow.uv_cur], (n, 2))
    chex.assert_shape([flow.valid, static], (n,))
    chex.assert_shape(T_cur_prev, (4, 4))
    chex.assert_shape(state.obs, (K, cap, 3))
    chex.assert_type([flow.pts_prev, flow.pts_cur, T_cur_prev], jnp.float32)

    usable = flow.valid & static
    advanced = _advance(state, flow, pts, T_cur_prev, usable, grid=grid, cell=cfg.cell)
    pb, seen, fixed, frame_valid = _problem(advanced, noise_scale, params)
    # 3. the refinement, in the coordinates of the oldest frame (held fixed)
    T_ref = advanced.T_w_c[fixed]
    T_local, s = refine(invert_pose(T_ref)[None] @ advanced.T_w_c, pb, cfg.window_iters)
    T_w_c = jnp.where(frame_valid[:, None, None], orthonormal(T_ref[None] @ T_local),
                      advanced.T_w_c)
    point = advanced.point * (1.0 + s)[:, None]

    observations = jnp.sum(seen)
    refined = jnp.sum(usable) >= params.min_static_points
    new_state = advanced._replace(T_w_c=T_w_c, point=point, seen=seen)
    out = WindowOut(T_w_c, advanced.frame_id, state.T_w_c[0], state.frame_id[0],
                    observations.astype(jnp.int32), refined)
    return new_state, out


def _advance(state: WindowState, flow, pts: Points, T_cur_prev, usable, *, grid, cell):
    """The window moved on by one pair, before its refinement: the oldest frame leaves, the
    pair's current frame enters, tracks chained and seeded, the pair's factor added."""
    K = state.T_w_c.shape[0]
    # 1. the oldest frame leaves; tracks anchored on it are re-expressed in the next one,
    # the new oldest, whose pose is fixed from now on
    T_1_0 = invert_pose(state.T_w_c[1]) @ state.T_w_c[0]
    rebase = (state.anchor == 0)[:, None]
    point = jnp.where(rebase, state.point @ T_1_0[:3, :3].T + T_1_0[:3, 3], state.point)
    anchor = jnp.maximum(state.anchor - 1, 0)
    prev_id = state.frame_id[K - 1]
    T_new = state.T_w_c[K - 1] @ invert_pose(T_cur_prev)
    T_w_c = _shift(state.T_w_c, T_new)
    frame_id = _shift(state.frame_id, prev_id + 1)

    # 2. tracks: chain the living ones, seed dead slots at their usable grid points (the
    # seed's own reading is its observation in the anchor frame)
    uv_new, Q, ok = chain_tracks(state.uv, flow, usable, grid, cell)
    ok = ok & state.alive
    at = seed_index(grid)
    seed = ~ok & usable[at]
    anchor = jnp.where(seed, K - 2, anchor)
    point = jnp.where(seed[:, None], flow.pts_prev[at], point)
    Q = jnp.where(seed[:, None], flow.pts_cur[at], Q)
    alive = ok | seed
    uv = jnp.where(ok[:, None], uv_new, jnp.where(seed[:, None], flow.uv_cur[at], state.uv))
    seen = _shift(jnp.where(seed[None], jnp.arange(K)[:, None] == K - 1, state.seen), alive)
    obs = state.obs.at[K - 1].set(jnp.where(seed[:, None], flow.pts_prev[at],
                                            state.obs[K - 1]))
    obs = _shift(obs, Q)
    H_pair, g_pair = pair_factor(T_cur_prev, pts, usable, pts.thr)
    return WindowState(T_w_c, frame_id, anchor, point, uv, alive, obs, seen,
                       _shift(state.pair_T, T_cur_prev), _shift(state.pair_H, H_pair),
                       _shift(state.pair_g, g_pair))


def _problem(st: WindowState, noise_scale: NoiseScale, params: Params):
    """The refinement's data (:class:`_Problem`) from the moved-on window ``st``: returns
    ``(problem, seen (K, cap) bool observations that count, fixed () slot of the oldest
    frame, frame_valid (K,) bool)``."""
    K = st.T_w_c.shape[0]
    frame_valid = st.frame_id >= 0
    fixed = jnp.argmax(frame_valid)
    free = frame_valid & (jnp.arange(K) != fixed)
    seen = st.seen & frame_valid[:, None] & (st.obs[..., 2] > 0)
    both = frame_valid & jnp.concatenate([jnp.zeros((1,), bool), frame_valid[:-1]])
    obs = st.obs
    z2 = obs[..., 2] * obs[..., 2]
    pb = _Problem(
        pair_T=st.pair_T,
        pair_H=jnp.where(both[:, None, None], st.pair_H, 0.0),
        pair_g=jnp.where(both[:, None], st.pair_g, 0.0),
        anchor1h=jax.nn.one_hot(st.anchor, K, dtype=jnp.float32),
        point=st.point.T,
        obs=jnp.swapaxes(obs, 1, 2),
        ray=jnp.swapaxes(obs, 1, 2)
        / jnp.maximum(jnp.linalg.norm(obs, axis=-1), _TINY)[:, None, :],
        w_dep=jnp.where(seen, 1.0 / jnp.maximum((noise_scale.depth_coeff * z2) ** 2, _TINY),
                        0.0),
        free=free,
        c2_dep=chi2_quantile(1, params.confidence),
    )
    return pb, seen, fixed, frame_valid


def final_poses(left_id, T_w_left, frame_id, T_w_c, poses):
    """Every frame's final pose: ``poses`` (N, 4, 4) with each frame that left the window
    replaced by its pose then, and each frame still in it by its pose there.

    The one assembly of a windowed run's trajectory, for a whole run's outputs
    (:func:`window_trajectory`) and for a stream of them (``jaxvo.Odometry``).

    Args:
      left_id: (L,) int32 frame numbers that left the window, -1 where none did;
      T_w_left: (L, 4, 4) their poses when they left;
      frame_id: (K,) int32 frame numbers of the last window's slots, -1 empty;
      T_w_c: (K, 4, 4) their poses there;
      poses: (N, 4, 4) the poses of the frames in neither (frames 0 .. N-1).
    """
    count = poses.shape[0]
    left = jnp.where(left_id >= 0, left_id, count)
    poses = jnp.asarray(poses).at[left].set(T_w_left, mode="drop")
    last = jnp.where(frame_id >= 0, frame_id, count)
    return poses.at[last].set(T_w_c, mode="drop")


def window_trajectory(outs: WindowOut):
    """Every frame's final pose from the window outputs of a whole run (:func:`final_poses`).

    Args:
      outs: :class:`WindowOut` stacked over the T steps of a run (frames 0 .. T).

    Returns:
      (T + 1, 4, 4) camera-to-world poses: each frame's pose when it left the window, and
      for the frames still in the window after the last step, their poses there.
    """
    T = outs.left_id.shape[0]
    return final_poses(outs.left_id, outs.T_w_left, outs.frame_id[-1], outs.T_w_c[-1],
                       jnp.zeros((T + 1, 4, 4), outs.T_w_c.dtype))
