"""Levenberg-Marquardt for bundle adjustment's structure, as an optax transformation, and a
pair's points as a quadratic factor on its motion (device side; the pose perturbations it
steps in are :func:`jaxvo.core.geometry.perturb`).

The keyframe window (:mod:`jaxvo.core.keyframe`) solves for a few poses and many point
depths at once: its Gauss-Newton matrix is an arrow, dense over the poses, diagonal over
the depths, with their coupling. :func:`levenberg_marquardt` takes that matrix and the
gradient and returns the damped step by the Schur complement of the diagonal part (one
Cholesky of the dense part); a step that raised the cost is undone and retried with more
damping. A fixed number of iterations, no Python branch on traced values.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxvo.core.geometry import skew, tiny
from jaxvo.core.noise import mahalanobis
from jaxvo.core.points import Points
from jaxvo.core.robust import cauchy

# Levenberg-Marquardt damping (relative to the Gauss-Newton matrix's diagonal): start, the
# factors after a rejected and an accepted step, and its range.
_DAMPING = (1e-3, 10.0, 0.1, 1e-6, 1e6)


class ArrowCurvature(NamedTuple):
    """A Gauss-Newton matrix with an arrow structure: dense over a few parameters (the
    poses), diagonal over many (the tracks' depths), and their coupling."""

    dense: jax.Array  # (p, p) float32
    cross: jax.Array  # (p, m) float32
    diagonal: jax.Array  # (m,) float32


class LevenbergMarquardtState(NamedTuple):
    """State of :func:`levenberg_marquardt`, at the last accepted parameters."""

    damping: jax.Array  # () float32, relative to the Gauss-Newton matrix's diagonal
    value: jax.Array  # () float32, cost there (inf before any)
    grad: tuple  # (dense (p,), diagonal (m,)) float32 gradient there
    curvature: ArrowCurvature  # the Gauss-Newton matrix there
    step: tuple  # (dense (p,), diagonal (m,)) the last step taken from there


def _arrow_solve(C: ArrowCurvature, g_dense, g_diag, lam):
    """The damped Gauss-Newton step ``-(H + lam (diag H + eps))^-1 g`` of an arrow matrix,
    by the Schur complement of its diagonal part (one Cholesky of the dense part)."""
    d = jnp.diagonal(C.dense)
    A = C.dense + jnp.diag(lam * (d + 1e-6 * jnp.mean(d) + tiny()))
    a = C.diagonal * (1.0 + lam) + lam * (1e-6 * jnp.mean(C.diagonal) + tiny())
    W = C.cross / a
    S = A - W @ C.cross.T
    x = -jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(S), g_dense - W @ g_diag)
    y = -(g_diag + C.cross.T @ x) / a
    ok = jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(y))
    return jnp.where(ok, x, 0.0), jnp.where(ok, y, 0.0)


def levenberg_marquardt(
    damping: float = _DAMPING[0],
    *,
    up: float = _DAMPING[1],
    down: float = _DAMPING[2],
    lowest: float = _DAMPING[3],
    highest: float = _DAMPING[4],
) -> optax.GradientTransformationExtraArgs:
    """Levenberg-Marquardt as an optax gradient transformation, for parameters made of a
    dense part and a part with a diagonal Gauss-Newton block (bundle adjustment's structure).

    The parameters are a pair ``(dense, diagonal)`` of arrays (any shapes; flattened to p
    and m entries). ``update(grad, state, params, *, curvature, value)`` takes the cost's
    gradient at ``params`` (the same pair), its Gauss-Newton matrix as an
    :class:`ArrowCurvature` and the cost ``value`` there, and returns the step
    ``-(H + lambda (diag H + eps))^-1 g`` (Marquardt's scaling), solved by the Schur
    complement of the diagonal block. When ``value`` is higher than at the last accepted
    parameters (or not finite), the last step is undone and one with ``up`` times the
    damping is taken from there, with the gradient and matrix kept from there; after an
    accepted step the damping falls by ``down``.

    Rows that must not move (a gauge held fixed) are the caller's: give them a unit
    diagonal, no coupling and a zero gradient.
    """

    def init(params):
        p, m = (jnp.size(x) for x in params)
        zeros = (jnp.zeros((p,), jnp.float32), jnp.zeros((m,), jnp.float32))
        eye = ArrowCurvature(jnp.eye(p, dtype=jnp.float32), jnp.zeros((p, m), jnp.float32),
                             jnp.ones((m,), jnp.float32))
        return LevenbergMarquardtState(jnp.float32(damping), jnp.float32(jnp.inf), zeros, eye,
                                       zeros)

    def update(updates, state, params=None, *, curvature, value, **extra_args):
        del params, extra_args
        shapes = [jnp.shape(x) for x in jax.tree.leaves(updates)]
        g = tuple(jnp.ravel(x).astype(jnp.float32) for x in jax.tree.leaves(updates))
        worse = ~(value <= state.value)  # NaN counts as worse
        lam = jnp.clip(jnp.where(worse, state.damping * up, state.damping * down),
                       lowest, highest).astype(jnp.float32)
        g = jax.tree.map(lambda old, new: jnp.where(worse, old, new), state.grad, g)
        C = jax.tree.map(lambda old, new: jnp.where(worse, old, new), state.curvature,
                         curvature)
        step = _arrow_solve(C, *g, lam)
        out = jax.tree.map(lambda s, last: jnp.where(worse, s - last, s), step, state.step)
        new = LevenbergMarquardtState(
            lam, jnp.where(worse, state.value, value).astype(jnp.float32), g, C, step)
        leaves = [x.reshape(sh) for x, sh in zip(out, shapes)]
        return jax.tree.unflatten(jax.tree.structure(updates), leaves), new

    return optax.GradientTransformationExtraArgs(init, update)


def cross_cols(a, b):
    """Cross products of columns: (..., 3, n) x (..., 3, n)."""
    return jnp.stack([a[..., 1, :] * b[..., 2, :] - a[..., 2, :] * b[..., 1, :],
                      a[..., 2, :] * b[..., 0, :] - a[..., 0, :] * b[..., 2, :],
                      a[..., 0, :] * b[..., 1, :] - a[..., 1, :] * b[..., 0, :]], axis=-2)


def pair_factor(T, pts: Points, use, c2):
    """One pair's points as a quadratic factor on its relative pose, about its ego-motion.

    The normalised residuals ``T src - dst`` of the points the ego-motion used
    (:mod:`jaxvo.core.noise`: lateral and along-ray parts, each in units of its noise, Cauchy
    weights at ``T``), as their gradient and Gauss-Newton matrix for a left perturbation
    ``exp(delta) T`` (``delta = (omega, nu)`` in the current camera): the window's pose of
    the pair then costs ``g . delta + delta^T H delta / 2``. Linearised once, when the pair
    enters (during the refinement a pair's motion moves by a fraction of a millimetre), so
    an iteration costs O(K) for the pairs instead of O(K n). The gradient is that of this
    cost, not of the ego-motion's own (whose depth weighting and robust scale differ), so
    the window refines every pair against its points, wherever the ego-motion landed.

    Args:
      T: (4, 4) the pair's ego-motion; pts: the pair's points and their noise
        (:func:`jaxvo.core.points.frame_points`); use: (n,) bool; c2: () the robust loss's scale.

    Returns:
      ``(H (6, 6), g (6,))`` float32.
    """
    X = T[:3, :3] @ pts.src + T[:3, 3:4]  # (3, n), in the current camera
    noise = pts.noise
    u = noise.ray
    r = X - pts.dst
    along = jnp.sum(r * u, axis=0)
    d2 = mahalanobis(r, noise)
    w = jnp.where(use, cauchy(d2, c2)[1], 0.0)  # IRLS weight at T
    Mr = noise.w_lat * (r - along * u) + noise.w_ray * along * u  # (3, n)
    g = jnp.concatenate([jnp.sum(cross_cols(X, w * Mr), axis=1), Mr @ w])
    # A^T M A for A = [-[X]x | I], M = w_lat (I - u u^T) + w_ray u u^T: the w_lat A^T A part
    # from the moments of X, the rest through q = A^T u
    wl = w * noise.w_lat
    m0, m1 = jnp.sum(wl), X @ wl
    m2 = (X * wl) @ X.T
    eye3 = jnp.eye(3, dtype=T.dtype)
    AtA = jnp.concatenate([jnp.concatenate([jnp.trace(m2) * eye3 - m2, skew(m1)], -1),
                           jnp.concatenate([-skew(m1), m0 * eye3], -1)], axis=0)
    q = jnp.concatenate([cross_cols(X, u), u], axis=0)  # (6, n)
    return AtA + (q * (w * (noise.w_ray - noise.w_lat))) @ q.T, g
