"""The sensor noise model of an RGB-D point pair, and the tests built on it (device side).

Every place where the pipeline compares a point with a motion (is it an inlier, which of two
motions does it follow, does it move unlike the background) asks one question: is the
residual ``r = T p_prev - p_cur`` larger than the sensor's noise explains? The noise of a
tracked RGB-D point has two parts of very different size:

* along the viewing ray, the depth noise: ``sigma_ray = depth_coeff * z^2`` for each of the
  two depth readings (structured light and stereo sensors: Khoshelham and Elberink 2012,
  ``1.4e-3 z^2`` for a raw Kinect reading);
* across the ray, the tracker's pixel noise: ``sigma_lat = pixel_sigma * z / f`` metres per
  axis (``f`` the focal length in pixels).

The squared Mahalanobis distance ``d2 = r_ray^2 / sigma_ray^2 + |r_lat|^2 / sigma_lat^2``
of a point that does follow ``T`` is chi-square with 3 degrees of freedom, so a test at
confidence ``p`` is ``d2 <= chi2_3(p)``, at every depth and for every sensor, in place of
millimetre thresholds tuned per scene.

The two scales are not constants of a sensor: the tracker's noise grows with motion blur,
the depth noise after :func:`jaxvo.host.frontend.flow.refine_depth` depends on the sensor's spatial
correlation, and colour-to-depth misregistration adds to both (measured against ground
truth by ``bench/calibrate_noise.py``; the figures in docs/report/core_decisions.md). Every test uses the model of
:class:`jaxvo.config.Params`' ``pixel_sigma`` and ``depth_coeff`` (a real sensor's values,
measured on the development frames); with ``Config.noise_calibration`` the pipeline also
calibrates both online from the residuals of the background under its own ego-motion
(:func:`update_noise`). That is off by default: it did not pay on the validation split
(``docs/report/robustness.md``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.core.geometry import tiny
from jaxvo.core.robust import CHI2_1_MEDIAN, CHI2_2_MEDIAN, enough_points, quantile_scale


class NoiseScale(NamedTuple):
    """The calibrated noise of the current sequence (carried by the pipeline state)."""

    pixel_sigma: jax.Array  # () float32, tracker noise across the ray, pixels per axis
    depth_coeff: jax.Array  # () float32, depth noise along the ray over z^2, 1/m


# The calibration stays within these: LK is not more precise than about 0.1 px (and a
# simulator's noise can be far below a real sensor's), and a sensor noisier than 2 px and
# 4e-3 z^2 (three times a Kinect's raw depth noise) is not one the method can work with;
# without the ceiling, frames whose ego-motion followed an object measured the background's
# residuals as noise, and the model grew until every motion merged (to 4 px, 5e-3 z^2).
NOISE_FLOOR = NoiseScale(0.1, 3e-4)  # plain floats: a JAX array here would start the
NOISE_CEILING = NoiseScale(2.0, 4e-3)  # backend at import (jax.distributed needs it unstarted)


class PointNoise(NamedTuple):
    """Per-point weights of the Mahalanobis distance, for points stored as columns."""

    ray: jax.Array  # (3, n) float32 unit viewing ray of each current point
    w_lat: jax.Array  # (n,) float32 1 / sigma_lat^2, 1/m^2 (0 where invalid)
    w_ray: jax.Array  # (n,) float32 1 / sigma_ray^2, 1/m^2 (0 where invalid)


def init_noise(params) -> NoiseScale:
    """The starting noise of a sequence: ``params.pixel_sigma`` and ``params.depth_coeff``."""
    return NoiseScale(jnp.asarray(params.pixel_sigma, jnp.float32),
                      jnp.asarray(params.depth_coeff, jnp.float32))


def point_noise(pts_prev, pts_cur, focal, scale: NoiseScale, fb_error=None,
                depth_slope=None) -> PointNoise:
    """Noise of each point pair (columns ``(3, n)``, metres) under ``scale`` and the tracker's
    own quality of each point.

    The tracker's error of a point, per image axis, has the variance
    ``s^2 = pixel_sigma^2 + (fb_error / 2)^2`` pixels^2: the sequence's scale (which covers
    what a forward-backward check cannot see, an error LK makes alike both ways) plus what
    this track's forward-backward error shows (with independent forward and backward errors
    of ``s`` each, the round trip's error has ``2 s^2`` per axis, ``4 s^2`` over both, so
    ``(fb / 2)^2`` estimates one way's per axis). Across the ray that is ``s z1 / f`` metres;
    along it, besides the two depth readings' noise, the tracked position's error moves the
    current depth reading by the surface's slope: ``depth_slope^2 s^2`` (a depth edge or a
    grazing surface reads a different depth a pixel away).

    Args:
      pts_prev, pts_cur: (3, n) previous and current points, metres (0 where invalid).
      focal: () focal length, pixels.
      scale: the calibrated :class:`NoiseScale`.
      fb_error: (n,) forward-backward error of each track, pixels (default 0).
      depth_slope: (n,) slope of the current depth surface at each tracked point, metres
        per pixel (default 0).
    """
    z0, z1 = pts_prev[2], pts_cur[2]
    norm = jnp.sqrt(pts_cur[0] * pts_cur[0] + pts_cur[1] * pts_cur[1] + pts_cur[2] * pts_cur[2])
    ray = pts_cur / jnp.maximum(norm, tiny())
    px2 = scale.pixel_sigma ** 2
    if fb_error is not None:
        px2 = px2 + 0.25 * fb_error * fb_error
    var_lat = px2 / (focal * focal) * z1 * z1
    var_ray = scale.depth_coeff ** 2 * (z0 ** 4 + z1 ** 4)
    if depth_slope is not None:
        var_ray = var_ray + depth_slope * depth_slope * px2
    ok = (z0 > 0) & (z1 > 0)
    return PointNoise(ray, jnp.where(ok, 1.0 / jnp.maximum(var_lat, tiny()), 0.0),
                      jnp.where(ok, 1.0 / jnp.maximum(var_ray, tiny()), 0.0))


# Every function below works on coordinate planes: a vector quantity over many points is
# three arrays, one per axis, never an array with an axis of 3 to reduce over, which XLA's
# CPU backend vectorises far worse (docs/report/core_decisions.md).


def components(r, noise: PointNoise):
    """Squared lateral and along-ray parts of difference vectors ``r`` (3, ...) given as
    coordinate planes (``r[0]``, ``r[1]``, ``r[2]``, each broadcasting against (n,)), m^2."""
    along = r[0] * noise.ray[0] + r[1] * noise.ray[1] + r[2] * noise.ray[2]
    total = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    return jnp.maximum(total - along * along, 0.0), along * along


def mahalanobis(r, noise: PointNoise):
    """Squared Mahalanobis length of difference vectors ``r`` (3, ..., n): (..., n) in units
    of the noise (chi-square with 3 degrees of freedom for pure noise)."""
    lat2, ray2 = components(r, noise)
    return lat2 * noise.w_lat + ray2 * noise.w_ray


def transfer(T, src):
    """``T`` (4, 4) applied to column points ``src`` (3, n): (3, n)."""
    return jnp.stack(transfer_many(T[None], src))[:, 0]


def transfer_many(Ts, src):
    """The column points ``src`` (3, n) under each of ``Ts`` (k, 4, 4): three coordinate
    planes (k, n). A difference of two poses maps ``src`` to the difference of their
    images."""
    return [Ts[:, c, 0, None] * src[0] + Ts[:, c, 1, None] * src[1]
            + Ts[:, c, 2, None] * src[2] + Ts[:, c, 3, None] for c in range(3)]


def residuals_many(Ts, src, dst, noise: PointNoise):
    """:func:`residuals` under each of ``Ts`` (k, 4, 4): ``(d2 (k, n), e2 (k, n))``."""
    r = [p - dst[c] for c, p in enumerate(transfer_many(Ts, src))]
    lat2, ray2 = components(r, noise)
    return lat2 * noise.w_lat + ray2 * noise.w_ray, lat2 + ray2


def residuals(T, src, dst, noise: PointNoise):
    """Normalised squared residuals ``d2`` (n,) of ``T src - dst`` and the raw squared
    distances ``e2`` (n,) m^2 of thesis eq. (2.19), for points stored as columns."""
    d2, e2 = residuals_many(T[None], src, dst, noise)
    return d2[0], e2[0]


class NoiseInputs(NamedTuple):
    """What one frame's noise calibration reads (:func:`update_noise`)."""

    r: jax.Array  # (3, n) float32 residuals T src - dst under the ego-motion, metres
    used: jax.Array  # (n,) bool the points the ego-motion was fitted to (where it is OK)
    noise: PointNoise  # those points' point_noise under the current scale


def update_noise(scale: NoiseScale, inputs: NoiseInputs, params, *,
                 floor: NoiseScale = NOISE_FLOOR, ceiling: NoiseScale = NOISE_CEILING):
    """Calibrate the noise from the residuals ``inputs.r`` (3, n) of the points the
    ego-motion ``used`` (n,) bool under the motion just estimated; ``inputs.noise`` is those
    points' :func:`point_noise` under ``scale``.

    Each part's scale is measured as the median of its squared residuals over those
    points, in units of the current model, over the median of its chi-square (1 degree of
    freedom along the ray, 2 across). The points are those the ego-motion was fitted to:
    the background as the pipeline believes it (not yet known to move, not in a segment
    that moves unlike it), whatever their residuals, so that no inlier test cuts the
    distribution short. Two sets did worse (docs/report/core_decisions.md): the inliers of the
    background segment (a real scene is not exactly rigid, and the model shrank to the
    spread within one segment until the background split into regional segments, each split
    shrinking it further), and a quantile over all valid points (objects covering half the
    view then set the noise of the background). The scale moves towards the
    measurement in log space at ``rate = params.noise_rate`` per frame and stays within
    ``floor`` and ``ceiling`` (by default :data:`NOISE_FLOOR`, :data:`NOISE_CEILING`); at
    ``rate`` 0 it is left exactly as given, outside those bounds too. The pipeline calls it
    only with ``Config.noise_calibration``.

    Returns the new :class:`NoiseScale` (unchanged where the points are not
    :func:`jaxvo.core.robust.enough_points`).
    """
    r, used, noise = inputs
    rate = params.noise_rate
    lat2, ray2 = components(r, noise)
    m_lat = quantile_scale(lat2 * noise.w_lat, used, 0.5, CHI2_2_MEDIAN)
    m_ray = quantile_scale(ray2 * noise.w_ray, used, 0.5, CHI2_1_MEDIAN)
    moves = enough_points(used, params) & (rate > 0)

    def step(value, ratio2, low, high):
        # ratio2 is (measured / modelled)^2: move log(value) by rate * log(ratio)
        new = value * jnp.exp(0.5 * rate * jnp.log(jnp.clip(ratio2, 1e-4, 1e4)))
        return jnp.where(moves, jnp.clip(new, low, high), value).astype(jnp.float32)

    return NoiseScale(step(scale.pixel_sigma, m_lat, floor.pixel_sigma, ceiling.pixel_sigma),
                      step(scale.depth_coeff, m_ray, floor.depth_coeff, ceiling.depth_coeff))
