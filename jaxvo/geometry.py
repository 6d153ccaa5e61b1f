"""Rigid-body helpers, and the masked median, shared by the device-side stages (pure
``jax.numpy``).

Conventions, used everywhere in jaxvo:

* points are rows, ``(..., n, 3)``, in metres;
* poses are homogeneous ``(..., 4, 4)`` matrices; names carry frames: ``T_w_c`` maps
  camera points to the world, ``T_cur_prev`` maps previous-frame points into the current
  camera frame;
* the camera frame is OpenCV's: x right, y down, z forward (depth).
"""

from __future__ import annotations

import jax.numpy as jnp


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


def transform_points(T, points):
    """Apply ``(..., 4, 4)`` pose ``T`` to ``(..., n, 3)`` points."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    return jnp.einsum("...ij,...nj->...ni", R, points) + t[..., None, :]


def masked_median(x, mask):
    """Median of ``x[mask]`` for a fixed-shape ``(n,)`` vector, 0 when the mask is empty.

    One sort with the masked-out lanes moved to the end (a finite sentinel, so no
    ``inf - inf`` can appear downstream); the mean of the two middle values.
    """
    n = x.shape[0]
    k = jnp.sum(mask)
    srt = jnp.sort(jnp.where(mask, x, 1e30))
    lo = srt[jnp.clip((k - 1) // 2, 0, n - 1)]
    hi = srt[jnp.clip(k // 2, 0, n - 1)]
    return jnp.where(k > 0, 0.5 * (lo + hi), 0.0)
