"""A frame pair's points as every stage reads them: columns, noise, validity, tests (device
side).

The step builds them once per frame (:func:`frame_points`), under the sensor noise model of
:mod:`jaxvo.core.noise`, and hands them to the spatial segmentation, the background choice,
the ego-motion, the moving evidence, the noise calibration and the keyframes.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.core.noise import NoiseScale, PointNoise, init_noise, point_noise
from jaxvo.core.robust import chi2_quantile


class Points(NamedTuple):
    """One frame pair's points as every stage reads them: columns, noise, validity, tests.

    Built once per frame (:func:`frame_points`) and handed to the spatial segmentation, the
    background choice, the ego-motion, the moving evidence, the noise calibration and the
    keyframes.
    """

    src: jax.Array  # (3, n) float32 previous points, metres (0 where invalid)
    dst: jax.Array  # (3, n) float32 current points, metres
    noise: PointNoise  # per-point weights of the normalised residual
    valid: jax.Array  # (n,) bool
    thr: jax.Array  # () float32 inlier test: chi2_3(confidence), noise units
    tie: jax.Array  # () float32 two motions explain a point alike: chi2_1(confidence)


def frame_points(pts_prev, pts_cur, valid, params, *, focal, scale: NoiseScale | None = None,
                 fb_error=None, depth_slope=None) -> Points:
    """One frame pair's points (n, 3) as columns with their noise and the tests' thresholds.

    Points that are non-finite or have non-positive depth count as invalid and are zeroed.
    ``scale`` is the sensor noise (:class:`~jaxvo.core.noise.NoiseScale`), by default
    ``params``' starting one; ``fb_error`` and ``depth_slope`` (n,) the tracker's quality of
    each point (:class:`jaxvo.host.frontend.flow.GridFlow`; see :func:`jaxvo.core.noise.point_noise`),
    by default none.
    """
    finite = jnp.all(jnp.isfinite(pts_prev), axis=1) & jnp.all(jnp.isfinite(pts_cur), axis=1)
    valid = valid & finite & (pts_prev[:, 2] > 0) & (pts_cur[:, 2] > 0)
    # Columns (3, n) from here on: each coordinate a contiguous vector (see
    # jaxvo.core.procrustes.fit_rigid_cols).
    src = jnp.where(valid, pts_prev.T, 0.0).astype(jnp.float32)
    dst = jnp.where(valid, pts_cur.T, 0.0).astype(jnp.float32)
    scale = init_noise(params) if scale is None else scale
    def per_point(x):
        return None if x is None else jnp.where(valid, jnp.asarray(x, jnp.float32), 0.0)

    noise = point_noise(src, dst, jnp.asarray(focal, jnp.float32), scale,
                        per_point(fb_error), per_point(depth_slope))
    return Points(src, dst, noise, valid, chi2_quantile(3, params.confidence),
                  chi2_quantile(1, params.confidence))
