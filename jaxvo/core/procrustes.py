"""Weighted rigid fit (thesis eqs. 2.1, 2.2), pure JAX (its residuals, eq. 2.19, are
:func:`jaxvo.core.noise.residuals`'s ``e2``).

The thesis writes the rotation as the polar factor ``R = M (M^T M)^(-1/2)`` of the
cross-covariance ``M = (X_k - P_k)(X_j - P_j)^T`` (eq. 2.1). That closed form is a reflection
when ``det M < 0`` and needs a matrix square root. We compute the same least-squares optimum
over *proper* rotations (eqs. 2.5, 2.6 with ``det R = +1``) with Horn's unit-quaternion
method: the optimal quaternion is the dominant eigenvector of a 4x4 symmetric matrix ``N``
built from ``M``. On the CPU a batched ``jnp.linalg.svd`` / ``eigh`` of thousands of tiny
matrices is slow, so the eigenvector is found by repeated squaring of the shifted matrix
``A = N / |M|_F + I`` (each squaring normalised by its trace), which is plain arithmetic that
XLA fuses across a ``vmap``. Translation is eq. (2.2) with weighted centroids.

One instance per call; ``jax.vmap`` at the call site batches fits.
"""

from __future__ import annotations

import chex
import jax.numpy as jnp
from jax import lax

from jaxvo.core.geometry import make_pose, tiny

# Squarings of the shifted Horn matrix: the power 2**20 ~ 1e6 drives the ratio of the
# second to the first eigenvalue, 1 - 2 (s2 + s3) / (l1 + 1) with the singular values of the
# normalised M, below float32 resolution for every set that passes the planarity check below.
_SQUARINGS = 20
# A set is degenerate (collinear) when the second eigenvalue of its scatter matrix is below
# this fraction of the largest, i.e. its thinnest extent is under about a hundredth of its
# longest.
_PLANARITY = 1e-4
# Coincident points: total scatter below this (m^2) leaves the rotation undetermined.
_MIN_SCATTER = 1e-10


# Below this many points, sums are written as broadcasts (fused elementwise code, also under
# vmap); above it as matrix products, which XLA's CPU backend runs faster on long rows.
_SMALL = 32


def _weighted_sum(x, w):
    """``sum_k w[k] x[i, k]`` for (d, n) columns."""
    if x.shape[-1] <= _SMALL:
        return jnp.sum(x * w, axis=-1)
    return x @ w


def _gram(x, w):
    """``sum_k w[k] x[i, k] x[j, k]`` for (d, n) columns."""
    if x.shape[-1] <= _SMALL:
        return jnp.sum((x * w)[:, None, :] * x[None, :, :], axis=-1)
    return (x * w) @ x.T


def _square_normalised(a):
    """``A @ A / tr(A @ A)``, as a sum of outer products rather than a matmul: XLA's CPU dot
    on 4x4 operands (batched under vmap) costs far more than its 64 multiply-adds. Kept in a
    loop: unrolled, the squarings compile slowly and run no faster."""
    a = sum(a[:, k, None] * a[None, k, :] for k in range(4))
    return a / jnp.maximum(jnp.trace(a), tiny(a.dtype))


def _spread_ok(c):
    """Whether a 3x3 PSD scatter matrix has at least two significant eigenvalues.

    Uses the invariants ``tr C`` and ``c2 = (tr(C)^2 - tr(C^2)) / 2`` (the sum of pairwise
    eigenvalue products): ``l1 l2 <= c2 <= 3 l1 l2`` and ``l1 <= tr <= 3 l1``, so
    ``c2 / tr^2`` measures ``l2 / l1`` within a factor of 27 without an eigen-decomposition.
    """
    tr = jnp.trace(c)
    c2 = 0.5 * (tr * tr - jnp.sum(c * c))
    return (tr > _MIN_SCATTER) & (c2 > _PLANARITY * tr * tr)


def _quat_to_rot(q):
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.stack(
        [
            jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )


def _horn_rotation(s):
    """Proper rotation maximising ``tr(R^T M)`` given ``s[i, j] = sum w a_i b_j`` (= M^T).

    Horn (1987), "Closed-form solution of absolute orientation using unit quaternions":
    the optimal quaternion is the eigenvector of the largest eigenvalue of ``N``.
    """
    sxx, sxy, sxz = s[0, 0], s[0, 1], s[0, 2]
    syx, syy, syz = s[1, 0], s[1, 1], s[1, 2]
    szx, szy, szz = s[2, 0], s[2, 1], s[2, 2]
    n = jnp.stack(
        [
            jnp.stack([sxx + syy + szz, syz - szy, szx - sxz, sxy - syx]),
            jnp.stack([syz - szy, sxx - syy - szz, sxy + syx, szx + sxz]),
            jnp.stack([szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy]),
            jnp.stack([sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]),
        ]
    )
    # The eigenvalues of N are sums +-s1 +-s2 +-s3 of the singular values of M; with
    # |M|_F = 1 the largest is l1 >= 0 and the smallest is >= -(l1 + 2 s3) with s3 <= 1/sqrt 3,
    # so a shift of 1 makes the wanted eigenvalue the unique one of largest magnitude.
    scale = jnp.sqrt(jnp.sum(s * s))
    a = n / jnp.maximum(scale, tiny(s.dtype)) + jnp.eye(4, dtype=s.dtype)
    a = lax.fori_loop(0, _SQUARINGS, lambda _, a: _square_normalised(a), a)
    # a ~ v v^T now: its largest column is a multiple of v.
    j = jnp.argmax(jnp.sum(a * a, axis=0))
    q = a[:, j]
    qn = jnp.sqrt(jnp.sum(q * q))
    good = qn > tiny(s.dtype)
    q = jnp.where(good, q / jnp.where(good, qn, 1.0), jnp.array([1.0, 0, 0, 0], s.dtype))
    return _quat_to_rot(q)


def fit_rigid(src, dst, w):
    """Weighted least-squares rigid motion mapping ``src`` onto ``dst`` (eqs. 2.1, 2.2).

    Minimises ``sum_i w_i |R src_i + t - dst_i|^2`` over proper rotations (``det R = +1``,
    never a reflection) and translations; ``t = P_dst - R P_src`` with weighted centroids.

    Args:
      src: (n, 3) points in metres (previous frame).
      dst: (n, 3) corresponding points in metres (current frame).
      w: (n,) non-negative weights; 0/1 weights fit the selected subset.

    Returns:
      T: (4, 4) pose ``T_dst_src``; the identity when not ``ok``.
      ok: () bool, False when fewer than 3 points carry positive weight or either point set
        is coincident or collinear (the rotation is then undetermined).
    """
    chex.assert_rank([src, dst], 2)
    chex.assert_equal_shape([src, dst])
    chex.assert_shape(w, (src.shape[0],))
    return fit_rigid_cols(src.T, dst.T, w)


def fit_rigid_cols(src_t, dst_t, w):
    """:func:`fit_rigid` on points stored as columns, ``(3, n)``.

    The column layout keeps every coordinate a contiguous ``(n,)`` vector, which XLA's CPU
    backend vectorises about ten times better than ``(n, 3)`` rows; callers that fit many
    times on the same points (the hypothesis search) transpose once and use this.
    """
    dtype = jnp.result_type(src_t.dtype, jnp.float32)
    x = jnp.concatenate([src_t, dst_t]).astype(dtype)  # (6, n)
    w = jnp.where(w > 0, w.astype(dtype), 0.0)
    wsum = jnp.sum(w)
    wsafe = jnp.where(wsum > 0, wsum, 1.0)
    # Two passes (centroids, then centred second moments) keep float32 exact enough for
    # small sets far from the origin, where one-pass raw moments would cancel badly.
    centroid = _weighted_sum(x, w) / wsafe  # (6,): P_src, P_dst of eq. (2.2)
    xc = x - centroid[:, None]
    g = _gram(xc, w) / wsafe  # (6, 6): [[C_src, S], [S^T, C_dst]]
    p_src, p_dst = centroid[:3], centroid[3:]
    s = g[:3, 3:]  # s[i, j] = sum w a_i b_j / W = M^T / W of eq. (2.18)
    c_src, c_dst = g[:3, :3], g[3:, 3:]
    ok = (jnp.sum(w > 0) >= 3) & _spread_ok(c_src) & _spread_ok(c_dst)
    R = _horn_rotation(s)
    R = jnp.where(ok, R, jnp.eye(3, dtype=dtype))
    t = jnp.where(ok, p_dst - R @ p_src, 0.0)
    return make_pose(R, t), ok
