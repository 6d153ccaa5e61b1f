"""Ego-motion of the camera from the grid points labelled static background (device side).

The camera's motion between two frames is the inverse of the apparent rigid motion of the
static background: with ``p_cur = T_cur_prev p_prev`` for static points, the new camera
pose is ``T_w_cur = T_w_prev @ inv(T_cur_prev)``.

The fit is the weighted Procrustes of thesis eqs. (2.1), (2.2) on the static points,
refined by iteratively re-weighted least squares with Huber weights on the residuals in
units of the sensor noise (:mod:`jaxvo.core.noise`), so that a few points the temporal model
mislabels (object edges, late-detected objects) cannot pull the pose.
A last few Gauss-Newton steps (:func:`refine_reprojection`, our addition to the thesis)
weigh the image-plane and depth parts of the error separately, because RGB-D depth noise
lies along the viewing ray and biases the isotropic 3D fit.
"""

from __future__ import annotations

from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.geometry import invert_pose, make_pose, so3_exp, tiny
from jaxvo.core.noise import residuals, residuals_many
from jaxvo.core.points import Points, frame_points
from jaxvo.core.procrustes import fit_rigid_cols
from jaxvo.core.robust import (
    CHI_3_Q25,
    enough_points,
    huber_weights,
    mad_scale,
    quantile_scale,
)
from jaxvo.status import Status, first_failure

# The robust noise scale of a frame is the lower quartile of the normalised residual
# lengths over that of a 3-D standard normal vector (jaxvo.core.robust.CHI_3_Q25): a quarter
# of the usable points on the background suffice.
_QUARTILE = 0.25
# The frame's robust scale may differ from the noise model's by at most these factors:
# a frame whose usable points are mostly mislabelled cannot inflate the Huber threshold
# beyond twice the noise, nor shrink it below a quarter.
_SCALE_RANGE = (0.25, 2.0)


def _huber_threshold(x, mask):
    """Twice the robust standard deviation of ``x[mask]`` (``x >= 0``, :func:`mad_scale`).

    Not the re-weighting's lower quartile (``_QUARTILE``): the reprojection refines on the
    3D fit's inliers, where the question is their spread, not the noise among outliers, and
    the median measures it with less scatter; the quartile with the inlier test as corner
    here did worse on part of the validation split (docs/report/core_decisions.md)."""
    return mad_scale(x, mask, 2.0)


def refine_reprojection(T, src, dst, weights, iters):
    """Gauss-Newton on the image-plane and depth errors, each in units of its own scale.

    The 3D-3D fit treats a point's error as isotropic, but the depth noise of an RGB-D
    camera lies along the viewing ray and is several times the lateral error of the
    tracked pixel; least squares on such points shortens the estimated motion. The tracked
    pixel carries no depth noise: its
    direction is ``dst / dst_z``. So the pose is refined, from the 3D-3D estimate and on its
    inliers, on the error of ``T src`` in the current view split into an image-plane part
    (normalised image coordinates, the classic 3D-2D error) and a depth part, each divided
    by its robust scale (Huber weights as in the 3D re-weighting): the data say how much
    each is worth: the image error alone does not pay where the depth is not registered to
    the colour image exactly (figures: docs/report/core_decisions.md).

    Args:
      T: (4, 4) starting pose; src, dst: (3, n) columns; weights: (n,) bool or float.
      iters: Gauss-Newton steps (static).
    """
    w = jnp.asarray(weights, jnp.float32)
    m = dst[:2] / jnp.where(dst[2] > 0, dst[2], 1.0)  # (2, n) normalised image coordinates

    def gn(_, T):
        q = T[:3, :3] @ src + T[:3, 3:4]
        z = jnp.where(q[2] > 1e-6, q[2], 1e-6)
        u, v = q[0] / z, q[1] / z
        ru, rv = u - m[0], v - m[1]
        e = jnp.sqrt(ru * ru + rv * rv + tiny())
        c = jnp.maximum(_huber_threshold(e, w > 0), 1e-5)
        wr = huber_weights(e, c, w)
        # d(u, v)/d(q) times d(q)/d(xi) for a left perturbation xi = (omega, nu):
        # dq = -[q]x omega + nu
        iz = 1.0 / z
        du = jnp.stack([-u * q[1] * iz, iz * q[2] + u * q[0] * iz, -q[1] * iz,
                        iz, jnp.zeros_like(iz), -u * iz])
        dv = jnp.stack([-iz * q[2] - v * q[1] * iz, v * q[0] * iz, q[0] * iz,
                        jnp.zeros_like(iz), iz, -v * iz])
        rz = q[2] - dst[2]
        cz = jnp.maximum(_huber_threshold(jnp.abs(rz), wr > 0), 1e-6)
        wz = huber_weights(jnp.abs(rz), cz, wr)
        dz = jnp.stack([q[1], -q[0], jnp.zeros_like(iz), jnp.zeros_like(iz),
                        jnp.zeros_like(iz), jnp.ones_like(iz)])
        a, b = 1.0 / (c * c), 1.0 / (cz * cz)
        H = a * ((du * wr) @ du.T + (dv * wr) @ dv.T) + b * ((dz * wz) @ dz.T)
        g = a * ((du * wr) @ ru + (dv * wr) @ rv) + b * ((dz * wz) @ rz)
        H = H + 1e-9 * jnp.trace(H) * jnp.eye(6, dtype=H.dtype)
        xi = -jnp.linalg.solve(H, g)
        dR = so3_exp(xi[:3])
        R = dR @ T[:3, :3]
        t = dR @ T[:3, 3] + xi[3:]
        good = jnp.all(jnp.isfinite(xi)) & (jnp.sum(wr > 0) >= 6)
        return jnp.where(good, make_pose(R, t), T)

    return jax.lax.fori_loop(0, iters, gn, T)


def estimate_egomotion(pts_prev, pts_cur, weights, params: Params, *, cfg: StepOptions,
                       focal=525.0, scale=None, T_init=None):
    """Robust rigid motion of the static background between two frames.

    Each re-weighting iteration takes the residuals in units of the sensor noise
    (:mod:`jaxvo.core.noise`), a robust scale of the frame from the lower quartile of their
    lengths (so that mislabelled points cannot inflate it, and within ``_SCALE_RANGE`` of
    the noise model), and refits with Huber weights whose corner is the inlier test
    (``chi2_3(confidence)``) at that scale; points beyond three corners get weight 0.

    Args:
      pts_prev: (n, 3) previous-frame points, metres.
      pts_cur: (n, 3) the same points in the current frame, metres.
      weights: (n,) float, > 0 for points that may be used (static and valid).
      params: numeric settings (``confidence``, ``min_static_points``).
      cfg: static settings (``ego_iters`` re-weighting iterations).
      focal: () focal length, pixels; scale: the current :class:`jaxvo.core.noise.NoiseScale`
        (by default the starting values of ``params``).
      T_init: optional (4, 4) starting motion (the background segment's); the first
        weights are then taken from its residuals instead of a fit on all usable points,
        so that the re-weighting converges to the background, not to a compromise with an
        object not yet known to move.

    Returns:
      T_cur_prev: (4, 4) float32, maps previous-frame points into the current frame
        (identity when the status is not OK).
      status: () int32, ``Status.OK``, ``NO_STATIC`` or ``EGO_DEGENERATE``.
      inliers: (n,) bool, points the final fit explains within the inlier test at the
        frame's scale.
    """
    chex.assert_rank([pts_prev, pts_cur], 2)
    chex.assert_equal_shape([pts_prev, pts_cur])
    chex.assert_shape(weights, (pts_prev.shape[0],))
    pts = frame_points(pts_prev, pts_cur, weights > 0, params, focal=focal, scale=scale)
    return fit_egomotion(pts, weights, params, cfg=cfg, T_init=T_init)


def fit_egomotion(pts: Points, weights, params: Params, *, cfg: StepOptions, T_init=None,
                  belief=None, candidates=None):
    """:func:`estimate_egomotion` on a frame's points as the pipeline builds them once
    (:func:`jaxvo.core.points.frame_points`); ``weights`` (n,) > 0 where a point may be used.

    The fit starts from the candidate motion of least robust cost over ``weights``
    (``T_init``, the background segment's; ``candidates`` (k, 4, 4), the predicted motion
    and every segment's; and the plain weighted fit), so that the random hypotheses
    choose where the deterministic re-weighting starts, not where it ends. With ``belief``
    (n,) (:func:`jaxvo.core.background.belief_weights`: 1 where earlier frames established
    the point as background) the support grows with the fit: every established point that
    the current motion explains within the inlier test joins it, whatever segment it fell
    in this frame. A piece of the background that the spatial stage split off (and so
    left out of ``weights``) supports the pose again, while an established point that
    moves now stays out by the test.
    """
    src, dst = pts.src, pts.dst
    established = (jnp.zeros(weights.shape, bool) if belief is None
                   else (belief >= 1.0) & pts.valid)
    T, ok0 = _best_start(pts, weights, T_init=T_init, candidates=candidates)
    T, ok, inliers, support = _reweight(pts, weights, T, cfg.ego_iters, established)
    if cfg.ego_reprojection_iters > 0:
        T = refine_reprojection(T, src, dst, inliers, cfg.ego_reprojection_iters)
    status = jnp.where(
        ~enough_points(support > 0, params),
        jnp.int32(Status.NO_STATIC),
        jnp.where(ok & ok0, jnp.int32(Status.OK), jnp.int32(Status.EGO_DEGENERATE)),
    )
    T = jnp.where(status == Status.OK, T, jnp.eye(4, dtype=T.dtype))
    return T, status, inliers


def _precision(pts: Points):
    """``(w_ray (n,), scale ())`` a point's depth precision and the frame's largest: a point
    enters the fit with ``weights * w_ray / scale`` (1/sigma rather than the statistically
    optimal 1/sigma^2, which let near, mislabelled object points pull the fit;
    docs/report/robustness.md)."""
    w_ray = jnp.sqrt(pts.noise.w_ray)
    return w_ray, jnp.maximum(jnp.max(w_ray), tiny())


def _prior_weights(weights, precision):
    """(n,) float32 the weights the points enter the fit with (:func:`_precision`)."""
    w_ray, scale = precision
    return jnp.where(weights > 0, weights * w_ray / scale, 0.0).astype(jnp.float32)


def _reweight(pts: Points, weights, T, iters: int, established):
    """``iters`` Huber re-weightings of the fit from ``T``, each on a support that grows
    with the fit: the points of ``weights`` (n,) and every ``established`` (n,) point the
    current motion explains within the inlier test. Each iteration's Huber corner is the
    inlier test at the frame's robust scale (the lower quartile of the supporting points'
    residual lengths, within ``_SCALE_RANGE`` of the noise model).

    Returns ``(T, ok, inliers (n,) bool, support (n,) float32)``.
    """

    precision = _precision(pts)

    def scaled(T):
        d2 = residuals(T, pts.src, pts.dst, pts.noise)[0]
        support = jnp.where(weights > 0, weights,
                            jnp.where(established & (d2 <= pts.thr), 1.0, 0.0))
        r = jnp.sqrt(d2 + tiny())
        q = quantile_scale(r, support > 0, _QUARTILE, CHI_3_Q25)
        return r, jnp.sqrt(pts.thr) * jnp.clip(q, *_SCALE_RANGE), support

    def step(_, carry):
        T, _ok = carry
        r, c, support = scaled(T)
        return fit_rigid_cols(pts.src, pts.dst, huber_weights(r, c, _prior_weights(support, precision)))

    T, ok = jax.lax.fori_loop(0, iters, step, (T, jnp.bool_(True)))
    r, c, support = scaled(T)
    return T, ok, (support > 0) & (r <= c), support


def _best_start(pts: Points, weights, *, T_init, candidates):
    """The motion to start the re-weighting from: ``(T (4, 4), ok)``.

    The starts are ``T_init``, ``candidates`` and the plain weighted fit on ``weights``;
    the best has the least truncated cost (each point's normalised residual, capped at the
    inlier test, weighted by ``weights``)."""
    w0 = _prior_weights(weights, _precision(pts))
    T_fit, ok_fit = fit_rigid_cols(pts.src, pts.dst, w0)
    starts = [T_fit[None]]
    if T_init is not None:
        starts.append(jnp.asarray(T_init, jnp.float32)[None])
    if candidates is not None:
        starts.append(jnp.asarray(candidates, jnp.float32))
    starts = jnp.concatenate(starts)
    d2 = residuals_many(starts, pts.src, pts.dst, pts.noise)[0]
    # each point counts by its weight alone (its belief), not by its depth's precision too:
    # which motion is the background's is a question of how much of the scene follows it,
    # and a precision of 1 / z^2 let a near mover's many not-yet-established points
    # outweigh the background's established ones
    cost = jnp.sum(jnp.where(weights > 0, weights, 0.0)[None] * jnp.minimum(d2, pts.thr),
                   axis=1)
    best = jnp.argmin(jnp.where(jnp.all(jnp.isfinite(starts), axis=(1, 2)), cost, jnp.inf))
    return starts[best], (best > 0) | ok_fit


class EgoState(NamedTuple):
    """The camera's pose and its last measured motion (carried by the pipeline)."""

    T_w_c: jax.Array  # (4, 4) float32, pose of the latest camera (camera-to-world)
    T_last: jax.Array  # (4, 4) float32, the last accepted ego-motion T_cur_prev
    have_last: jax.Array  # () bool, whether T_last holds an accepted ego-motion yet


class EgoOut(NamedTuple):
    """One frame's ego-motion (:func:`update_egomotion`)."""

    T_cur_prev: jax.Array  # (4, 4) float32, the background's motion (carried: predicted)
    status: jax.Array  # () int32 Status code, OK or why the motion was carried
    ok: jax.Array  # () bool status is OK
    used: jax.Array  # (n,) bool points the fit used (usable, inlier) where ok


def init_ego(T_w_c0) -> EgoState:
    """The first camera pose (4, 4), no motion measured yet."""
    eye = jnp.eye(4, dtype=jnp.float32)
    return EgoState(jnp.asarray(T_w_c0, jnp.float32), eye, jnp.bool_(False))


def predicted_motion(state: EgoState):
    """(4, 4) the camera's motion expected for this frame: the last one measured, else none."""
    return jnp.where(state.have_last, state.T_last, jnp.eye(4, dtype=jnp.float32))


class EgoInputs(NamedTuple):
    """What one frame's ego-motion reads (:func:`update_egomotion`)."""

    pts: Points  # the points to fit: the frame's, with keyframes also the keyframe's
    weights: jax.Array  # (n,) float32 each point's weight as background (BackgroundOut.use)
    T_init: jax.Array  # (4, 4) float32 the background segment's motion, the first start
    # () int32 Status of the earlier stages (flow, segmentation, background): not OK
    # carries the predicted motion
    status: jax.Array
    belief: jax.Array | None = None  # (n,) float32 each point's belief as background
    # (k, 4, 4) float32 further starts (the predicted motion, every segment's); None: none
    candidates: jax.Array | None = None


def update_egomotion(state: EgoState, inputs: EgoInputs, params: Params, *, cfg: StepOptions):
    """One frame of the camera's motion: :func:`fit_egomotion` from the background's motion
    ``inputs.T_init`` (4, 4) on the points of ``inputs.weights`` (n,), and the pose chain.

    ``inputs.status`` () is the earlier stages' (flow, segmentation): a frame where one of
    them or the fit failed carries the predicted motion (:func:`predicted_motion`), so a
    moving camera is never frozen by a skipped pair. ``belief`` (n,) and ``candidates``
    (k, 4, 4): see :func:`fit_egomotion`.

    Returns ``(EgoState, EgoOut)``.
    """
    T_ego, ego_status, inliers = fit_egomotion(
        inputs.pts, inputs.weights, params, cfg=cfg, T_init=inputs.T_init,
        belief=inputs.belief, candidates=inputs.candidates)
    status = first_failure(inputs.status, ego_status)
    ok = status == Status.OK
    T_cur_prev = jnp.where(ok, T_ego, predicted_motion(state))
    T_w_c = state.T_w_c @ invert_pose(T_cur_prev)
    new = EgoState(T_w_c, jnp.where(ok, T_cur_prev, state.T_last), state.have_last | ok)
    return new, EgoOut(T_cur_prev, status, ok, inliers & ok)
