"""Rigid-body helpers (SE(3): poses, their inverse, Rodrigues, left perturbations, the
adjoint), and the masked median, shared by the device-side stages (pure ``jax.numpy``).

Conventions, used everywhere in jaxvo:

* points are rows, ``(..., n, 3)``, in metres;
* poses are homogeneous ``(..., 4, 4)`` matrices; names carry frames: ``T_w_c`` maps
  camera points to the world, ``T_cur_prev`` maps previous-frame points into the current
  camera frame;
* the camera frame is OpenCV's: x right, y down, z forward (depth).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jax import lax


def full_precision(fn):
    """``fn`` traced with every float32 matrix product at full float32 precision.

    JAX lets a GPU run float32 products in TF32 (a 10-bit mantissa) by default, which
    moves every transformed point and fit by far more than the sensor's noise
    (docs/report/core_decisions.md). The CPU computes in float32 anyway; the products here are
    small, so the cost is nil.
    """
    @functools.wraps(fn)
    def traced(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)
    return traced


def tiny(dtype=jnp.float32) -> float:
    """The one guard of a division or a square root in the traced code, as jaxlie's
    ``get_epsilon(dtype)``: the square root of the smallest normal number of ``dtype``
    (about 1e-19 in float32). A denominator floored at it, or a square root's argument
    raised by it, stays finite where the value is 0 (masked-out lanes, empty sets); nothing
    the pipeline measures (residuals, variances, scatter, weights) comes near it, so it
    changes no result, and a value up to ``1 / tiny`` divided by it is still finite."""
    return math.sqrt(float(jnp.finfo(dtype).tiny))


def make_pose(R, t):
    """``(..., 3, 3)`` rotation and ``(..., 3)`` translation -> ``(..., 4, 4)`` pose."""
    top = jnp.concatenate([R, t[..., :, None]], axis=-1)
    bottom = jnp.broadcast_to(
        jnp.array([0.0, 0.0, 0.0, 1.0], dtype=R.dtype), top.shape[:-2] + (1, 4)
    )
    return jnp.concatenate([top, bottom], axis=-2)


def invert_pose(T):
    """Inverse of a rigid ``(..., 4, 4)`` pose without a general matrix inverse."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    Rt = jnp.swapaxes(R, -1, -2)
    return make_pose(Rt, -jnp.einsum("...ij,...j->...i", Rt, t))


def so3_exp(w):
    """Rodrigues: the rotation (3, 3) of the rotation vector ``w`` (3,), radians; Taylor
    terms near 0 so that no 0 / 0 appears."""
    theta2 = jnp.sum(w * w)
    theta = jnp.sqrt(theta2 + tiny(w.dtype))
    small = theta2 < 1e-10
    a = jnp.where(small, 1.0 - theta2 / 6.0, jnp.sin(theta) / theta)
    b = jnp.where(small, 0.5 - theta2 / 24.0, (1.0 - jnp.cos(theta)) / (theta2 + tiny(w.dtype)))
    zero = jnp.zeros_like(w[0])
    k = jnp.stack([
        jnp.stack([zero, -w[2], w[1]]),
        jnp.stack([w[2], zero, -w[0]]),
        jnp.stack([-w[1], w[0], zero]),
    ])
    return jnp.eye(3, dtype=w.dtype) + a * k + b * (k @ k)


def transform_points(T, points):
    """Apply ``(..., 4, 4)`` pose ``T`` to ``(..., n, 3)`` points."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    return jnp.einsum("...ij,...nj->...ni", R, points) + t[..., None, :]


def perturb(T, xi):
    """Left perturbation ``exp(xi) T`` of poses ``T`` (K, 4, 4) by ``xi`` (K, 6) = (omega,
    nu): points move as ``X + omega x X + nu`` to first order."""
    R = jax.vmap(so3_exp)(xi[:, :3])
    return make_pose(R @ T[:, :3, :3], jnp.einsum("kij,kj->ki", R, T[:, :3, 3]) + xi[:, 3:])


def orthonormal(T):
    """Poses ``T`` (..., 4, 4) with rotations pulled back onto SO(3) by one Newton-Schulz
    step of the polar decomposition, ``R (3 I - R^T R) / 2``. The window maps its poses into
    the oldest frame's coordinates and back every step (``T_ref (T_ref^-1 T)`` with the
    transpose as the inverse); without this a rotation's float32 rounding compounded from
    step to step (orthogonality errors from 3e-5 to 3e-3 in ten frames of 7-Scenes)."""
    R = T[..., :3, :3]
    RtR = jnp.swapaxes(R, -1, -2) @ R
    R = R @ (1.5 * jnp.eye(3, dtype=R.dtype) - 0.5 * RtR)
    return make_pose(R, T[..., :3, 3])


def skew(v):
    """(..., 3) -> (..., 3, 3) cross-product matrices ``[v]x``."""
    z = jnp.zeros_like(v[..., 0])
    return jnp.stack([jnp.stack([z, -v[..., 2], v[..., 1]], -1),
                      jnp.stack([v[..., 2], z, -v[..., 0]], -1),
                      jnp.stack([-v[..., 1], v[..., 0], z], -1)], axis=-2)


def adjoint(T):
    """Adjoint (..., 6, 6) of poses (..., 4, 4) for ``xi = (omega, nu)``: ``T exp(xi)
    T^-1 = exp(Ad_T xi)``, ``Ad_T = [[R, 0], [[t]x R, R]]``."""
    R, t = T[..., :3, :3], T[..., :3, 3]
    zero = jnp.zeros_like(R)
    return jnp.concatenate([jnp.concatenate([R, zero], -1),
                            jnp.concatenate([skew(t) @ R, R], -1)], axis=-2)


def _order_key(x):
    """float32 -> int32 with the same order (negative floats have their magnitude bits
    flipped), so that an order statistic can be found by bisection on integers."""
    i = lax.bitcast_convert_type(x.astype(jnp.float32), jnp.int32)
    return i ^ ((i >> 31) & 0x7FFFFFFF)


def _from_order_key(i):
    return lax.bitcast_convert_type(i ^ ((i >> 31) & 0x7FFFFFFF), jnp.float32)


def _kth_key(keys, mask, k, halvings=32):
    """The ``k``-th smallest (0-based) of ``keys[mask]``: halvings of the int32 range, each
    one counting the keys at or below the midpoint. 32 give it exactly; fewer, a lower
    bound within ``2**(32 - halvings)``."""

    def halve(_, bounds):
        lo, hi = bounds
        mid = (lo >> 1) + (hi >> 1) + (lo & hi & 1)  # floor((lo + hi) / 2) without overflow
        enough = jnp.sum(mask & (keys <= mid)) >= k + 1
        return jnp.where(enough, lo, mid + 1), jnp.where(enough, mid, hi)

    lo, _ = lax.fori_loop(0, halvings, halve, (jnp.int32(-(2**31)), jnp.int32(2**31 - 1)))
    return lo


def masked_quantile(x, mask, q: float, precision_bits: int = 12):
    """The ``q`` quantile of ``x[mask]`` (the order statistic ``floor(q (k - 1))`` of the
    ``k`` masked values) to a relative ``2**-precision_bits``, 0 when the mask is empty
    (bisection on the float bit patterns, as :func:`masked_median`)."""
    k = jnp.sum(mask)
    j = jnp.maximum(jnp.floor(q * (k - 1)).astype(jnp.int32), 0)
    value = _from_order_key(_kth_key(_order_key(x), mask, j, halvings=9 + int(precision_bits)))
    return jnp.where(k > 0, value, 0.0).astype(x.dtype)


def masked_median(x, mask, precision_bits: int | None = None):
    """Median of ``x[mask]`` for a fixed-shape ``(n,)`` vector, 0 when the mask is empty.

    Exact (the mean of the two middle values), found by bisection on the float bit
    patterns rather than a sort: 32 fused count-reductions cost a fifth of an XLA CPU sort
    of a grid's values (docs/report/core_decisions.md), and the ego-motion takes a median per
    iteration.

    With ``precision_bits`` b: the lower middle value to a relative ``2**-b`` (at most
    that much toward -inf), one order statistic by ``9 + b`` halvings instead of two by 32
    (the last ``23 - b`` mantissa bits are left open). A robust scale or a fill-in
    displacement needs no more: b = 12 is a third of the work.
    """
    k = jnp.sum(mask)
    keys = _order_key(x)
    lower = jnp.maximum((k - 1) // 2, 0)  # index of the lower middle value
    if precision_bits is None:
        both = jax.vmap(lambda j: _kth_key(keys, mask, j))(jnp.stack([lower, k // 2]))
        value = 0.5 * (_from_order_key(both[0]) + _from_order_key(both[1]))
    else:
        value = _from_order_key(_kth_key(keys, mask, lower, halvings=9 + int(precision_bits)))
    return jnp.where(k > 0, value, 0.0).astype(x.dtype)
