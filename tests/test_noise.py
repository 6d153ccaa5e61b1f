"""The sensor noise model (jaxvo.core.noise): the Mahalanobis length against the full covariance,
the chi-square quantiles against SciPy, the inlier rate of pure model noise, and the online
calibration's convergence.

Noise is generated in float64 NumPy as the model describes it: each depth reading's noise
along its viewing ray (``depth_coeff * z^2``), the tracker's pixel noise across the current
point's ray (``pixel_sigma * z / f`` per axis).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.config import Params
from jaxvo.core.noise import (
    NoiseInputs,
    NoiseScale,
    mahalanobis,
    point_noise,
    residuals,
    residuals_many,
    update_noise,
)
from jaxvo.core.points import frame_points
from jaxvo.core.robust import chi2_quantile

FOCAL = 525.0
TRUE = NoiseScale(1.2, 2.0e-3)  # the noise the frames are generated with
FLOOR, CEILING = NoiseScale(0.1, 3e-4), NoiseScale(2.0, 4e-3)


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


MOTION = np.eye(4)
MOTION[:3, :3] = _rotation([0.2, 1.0, 0.1], 0.02)
MOTION[:3, 3] = [0.02, -0.01, 0.015]


def _unit(p):
    return p / np.linalg.norm(p, axis=0, keepdims=True)


def _across(ray, rng):
    """(3, n) a standard normal vector in the plane across each unit ray (two axes)."""
    a = np.cross(ray.T, [0.0, 0.0, 1.0]).T
    a = np.where(np.linalg.norm(a, axis=0) > 1e-9, a, np.cross(ray.T, [1.0, 0.0, 0.0]).T)
    a = _unit(a)
    b = np.cross(ray.T, a.T).T
    return a * rng.normal(size=ray.shape[1]) + b * rng.normal(size=ray.shape[1])


def rigid_scene(rng, n, T=MOTION):
    """Noise-free column points (3, n) of a rigid scene before and after it moves by ``T``:
    ``(true_prev, true_cur)`` float64, depths 0.8-4 m over a 640 x 480 view."""
    z = rng.uniform(0.8, 4.0, n)
    u, v = rng.uniform(-320, 320, n), rng.uniform(-240, 240, n)
    true_prev = np.stack([u * z / FOCAL, v * z / FOCAL, z])
    return true_prev, T[:3, :3] @ true_prev + T[:3, 3:4]


def noisy_pairs(rng, n, scale=TRUE, T=MOTION):
    """Column points (3, n) of a rigid scene moving by ``T`` with the model's noise:
    ``(src, dst)`` float64 (:func:`rigid_scene`)."""
    true_prev, true_cur = rigid_scene(rng, n, T)
    c = scale.depth_coeff
    src = true_prev + _unit(true_prev) * rng.normal(size=n) * c * true_prev[2] ** 2
    ray = _unit(true_cur)
    dst = (true_cur + ray * rng.normal(size=n) * c * true_cur[2] ** 2
           + _across(ray, rng) * scale.pixel_sigma * true_cur[2] / FOCAL)
    return src, dst


def _f32(*xs):
    return [jnp.asarray(x, jnp.float32) for x in xs]


# ------------------------------------------------------------------ Mahalanobis length


def test_mahalanobis_equals_the_full_covariance_quadratic_form():
    """Against an independent float64 computation: each point's 3x3 covariance is the sum
    of its two readings' depth noise along the current ray and the pixel noise across it,
    and ``d2 = r^T C^-1 r`` by a linear solve."""
    rng = np.random.default_rng(0)
    n = 500
    src, dst = noisy_pairs(rng, n)
    r = rng.normal(size=(3, n)) * 0.01
    scale = NoiseScale(0.9, 1.3e-3)
    ray = _unit(dst)
    var_lat = (scale.pixel_sigma * dst[2] / FOCAL) ** 2
    var_ray = scale.depth_coeff ** 2 * (src[2] ** 4 + dst[2] ** 4)
    outer = np.einsum("in,jn->nij", ray, ray)
    cov = var_lat[:, None, None] * (np.eye(3) - outer) + var_ray[:, None, None] * outer
    want = np.einsum("ni,ni->n", r.T, np.linalg.solve(cov, r.T[..., None])[..., 0])

    noise = jax.jit(point_noise)(*_f32(src, dst, FOCAL), NoiseScale(*_f32(*scale)))
    got = np.asarray(jax.jit(mahalanobis)(jnp.asarray(r, jnp.float32), noise))
    # float32 on residuals of ~1 cm against noise of 0.1-30 mm: 1e-4 relative
    np.testing.assert_allclose(got, want, rtol=1e-4)

    # residuals() is the same length of T src - dst, with the raw squared distance beside it
    T = jnp.asarray(MOTION, jnp.float32)
    d2, e2 = jax.jit(residuals)(T, *_f32(src, dst), noise)
    res = MOTION[:3, :3] @ src + MOTION[:3, 3:4] - dst
    want = np.einsum("ni,ni->n", res.T, np.linalg.solve(cov, res.T[..., None])[..., 0])
    # float32 rounding of the transformed points (metres, 6e-8 relative) against residuals
    # of a few millimetres: 2e-3 relative
    np.testing.assert_allclose(np.asarray(d2), want, rtol=2e-3, atol=1e-3)
    np.testing.assert_allclose(np.asarray(e2), np.sum(res**2, axis=0), rtol=2e-3, atol=1e-10)
    # and under several motions at once, each row as residuals() gives it (jitted against
    # not: float32 cancellation in |r|^2 - along^2, 1e-3 relative)
    Ts = jnp.stack([T, jnp.eye(4), T.at[:3, 3].add(0.01)])
    d2_k, e2_k = jax.jit(residuals_many)(Ts, *_f32(src, dst), noise)
    for k in range(3):
        one_d2, one_e2 = residuals(Ts[k], *_f32(src, dst), noise)
        np.testing.assert_allclose(np.asarray(d2_k[k]), np.asarray(one_d2), rtol=1e-3)
        np.testing.assert_allclose(np.asarray(e2_k[k]), np.asarray(one_e2), rtol=1e-3)


def test_a_point_without_depth_weighs_nothing():
    src = np.array([[0.1, 0.2], [0.0, 0.1], [2.0, 0.0]])  # the second has no depth
    dst = src + 0.01
    noise = point_noise(*_f32(src, dst, FOCAL), NoiseScale(*_f32(*TRUE)))
    assert float(noise.w_lat[0]) > 0 and float(noise.w_ray[0]) > 0
    assert float(noise.w_lat[1]) == 0.0 and float(noise.w_ray[1]) == 0.0
    d2 = mahalanobis(jnp.full((3, 2), 0.05, jnp.float32), noise)
    assert np.all(np.isfinite(np.asarray(d2))) and float(d2[1]) == 0.0


# ------------------------------------------------------------------ the inlier test


@pytest.mark.parametrize("confidence", [0.9, 0.99])
def test_pure_model_noise_passes_the_inlier_test_at_its_confidence(confidence):
    """Points that follow the motion, with exactly the model's noise, are inliers
    (``d2 <= chi2_3(p)``) at the rate ``p``: within 0.01 (binomial standard error 0.002 at
    0.9 and 0.0007 at 0.99 over 20000 points; the rest is the Wilson-Hilferty quantile and
    the previous reading's noise turning with the motion, 1-2 degrees)."""
    rng = np.random.default_rng(1)
    src, dst = noisy_pairs(rng, 20000)
    noise = point_noise(*_f32(src, dst, FOCAL), NoiseScale(*_f32(*TRUE)))
    d2, _ = jax.jit(residuals)(jnp.asarray(MOTION, jnp.float32), *_f32(src, dst), noise)
    rate = float(np.mean(np.asarray(d2) <= float(chi2_quantile(3, confidence))))
    assert rate == pytest.approx(confidence, abs=0.01)
    # with noise three times the model's, far fewer pass: the test has power
    src, dst = noisy_pairs(rng, 20000, NoiseScale(3 * TRUE.pixel_sigma, 3 * TRUE.depth_coeff))
    noise = point_noise(*_f32(src, dst, FOCAL), NoiseScale(*_f32(*TRUE)))
    d2, _ = jax.jit(residuals)(jnp.asarray(MOTION, jnp.float32), *_f32(src, dst), noise)
    assert float(np.mean(np.asarray(d2) <= float(chi2_quantile(3, confidence)))) < 0.6


def test_the_trackers_own_quality_sets_each_points_noise():
    """Points whose tracks differ in quality: each with its own pixel error per axis
    ``s^2 = pixel_sigma^2 + (fb / 2)^2`` (``fb`` its forward-backward error, 0-1 px as the
    tracker keeps them) across the ray, and along it, besides the depth readings, its depth
    read ``s`` pixels off on a surface of slope ``g`` (0-20 mm/px: a wall at a grazing
    angle, an edge's smoothed ramp). With both per-point terms the inlier rate is the
    confidence; with the sequence-wide scales alone, far fewer pass; and the terms reach
    the points :func:`frame_points` builds (0 where a point is invalid)."""
    rng = np.random.default_rng(4)
    n, confidence = 20000, 0.95
    base = NoiseScale(0.3, 1.0e-3)
    fb = rng.uniform(0.0, 1.0, n)
    slope = rng.uniform(0.0, 0.02, n)
    s = np.sqrt(base.pixel_sigma ** 2 + 0.25 * fb ** 2)  # per axis, pixels
    true_prev, true_cur = rigid_scene(rng, n)
    c = base.depth_coeff
    src = true_prev + _unit(true_prev) * rng.normal(size=n) * c * true_prev[2] ** 2
    ray = _unit(true_cur)
    # the depth read at a pixel error (dx, dy) on a surface of gradient g: g . (dx, dy)
    along = np.hypot(c * true_cur[2] ** 2, slope * s) * rng.normal(size=n)
    dst = true_cur + ray * along + _across(ray, rng) * s * true_cur[2] / FOCAL
    thr = float(chi2_quantile(3, confidence))
    T = jnp.asarray(MOTION, jnp.float32)
    scale = NoiseScale(*_f32(*base))

    def inliers(noise):
        d2, _ = jax.jit(residuals)(T, *_f32(src, dst), noise)
        return float(np.mean(np.asarray(d2) <= thr))

    both = jax.jit(point_noise)(*_f32(src, dst, FOCAL), scale, *_f32(fb, slope))
    assert inliers(both) == pytest.approx(confidence, abs=0.01)
    # each term is needed (measured 0.75 without either, 0.87 with fb alone, 0.81 with
    # the slope alone)
    assert inliers(point_noise(*_f32(src, dst, FOCAL), scale)) < 0.8
    assert inliers(point_noise(*_f32(src, dst, FOCAL), scale, _f32(fb)[0])) < 0.9
    assert inliers(point_noise(*_f32(src, dst, FOCAL), scale, None, _f32(slope)[0])) < 0.9

    # frame_points hands the terms to point_noise, and ignores them at invalid points
    valid = rng.random(n) < 0.8
    pts = frame_points(*_f32(src.T, dst.T), jnp.asarray(valid), Params(pixel_sigma=0.3,
                       depth_coeff=1.0e-3), focal=FOCAL, fb_error=_f32(fb)[0],
                       depth_slope=_f32(slope)[0])
    for got, want in ((pts.noise.w_lat, both.w_lat), (pts.noise.w_ray, both.w_ray)):
        np.testing.assert_allclose(np.asarray(got)[valid], np.asarray(want)[valid], rtol=1e-5)
        assert not np.asarray(got)[~valid].any()


# ------------------------------------------------------------------ calibration


@jax.jit
def _calibrate(scale, src, dst, used, rate):
    T = jnp.asarray(MOTION, jnp.float32)
    r = T[:3, :3] @ src + T[:3, 3:4] - dst
    noise = point_noise(src, dst, jnp.float32(FOCAL), scale)
    return update_noise(scale, NoiseInputs(r, used, noise), Params(noise_rate=rate), floor=FLOOR,
                        ceiling=CEILING)


def _run_calibration(start, true, frames=40, rate=0.3, seed=2, n=1500):
    rng = np.random.default_rng(seed)
    scale = NoiseScale(*_f32(*start))
    used = jnp.ones((n,), bool)
    for _ in range(frames):
        src, dst = noisy_pairs(rng, n, true)
        scale = _calibrate(scale, *_f32(src, dst), used, jnp.float32(rate))
    return NoiseScale(float(scale.pixel_sigma), float(scale.depth_coeff))


@pytest.mark.parametrize("start", [NoiseScale(0.3, 5e-4), NoiseScale(1.9, 3.8e-3)],
                         ids=["too_small", "too_large"])
def test_calibration_converges_to_the_true_noise(start):
    """From a quarter of the true scales and from nearly twice them, 40 frames of 1500
    points at rate 0.3 end within 4 % of the truth (1.5 % measured at three seeds: the
    median of 1500 squared normal components spreads by about 4 %, the log-space average
    over about three frames narrows it; the previous reading's noise turns with the
    motion)."""
    got = _run_calibration(start, TRUE)
    assert got.pixel_sigma == pytest.approx(TRUE.pixel_sigma, rel=0.04)
    assert got.depth_coeff == pytest.approx(TRUE.depth_coeff, rel=0.04)


def test_calibration_stays_within_floor_and_ceiling():
    """Noise beyond the ceiling (and below the floor) ends at it exactly, never past it."""
    high = _run_calibration(NoiseScale(1.0, 1e-3), NoiseScale(4.0, 8e-3), frames=30)
    assert high == NoiseScale(pytest.approx(CEILING.pixel_sigma, rel=1e-6),
                              pytest.approx(CEILING.depth_coeff, rel=1e-6))
    low = _run_calibration(NoiseScale(1.0, 1e-3), NoiseScale(0.02, 5e-5), frames=30)
    assert low == NoiseScale(pytest.approx(FLOOR.pixel_sigma, rel=1e-6),
                             pytest.approx(FLOOR.depth_coeff, rel=1e-6))


def test_calibration_needs_twelve_points_and_a_rate():
    rng = np.random.default_rng(3)
    src, dst = noisy_pairs(rng, 200, NoiseScale(1.8, 3.5e-3))
    start = NoiseScale(*_f32(*TRUE))
    few = jnp.arange(200) < 11
    same = _calibrate(start, *_f32(src, dst), few, jnp.float32(0.3))
    assert (float(same.pixel_sigma), float(same.depth_coeff)) == (float(start.pixel_sigma),
                                                                  float(start.depth_coeff))
    fixed = _calibrate(start, *_f32(src, dst), jnp.ones(200, bool), jnp.float32(0.0))
    assert (float(fixed.pixel_sigma), float(fixed.depth_coeff)) == (float(start.pixel_sigma),
                                                                    float(start.depth_coeff))
    # rate 0 leaves a scale outside the calibration's floor and ceiling as it is (a
    # simulator's 0.05 px, below the 0.1 px floor, stays 0.05)
    below = NoiseScale(*_f32(0.05, 1e-4))
    kept = _calibrate(below, *_f32(src, dst), jnp.ones(200, bool), jnp.float32(0.0))
    assert (float(kept.pixel_sigma), float(kept.depth_coeff)) == (float(below.pixel_sigma),
                                                                  float(below.depth_coeff))
    moved = _calibrate(start, *_f32(src, dst), jnp.arange(200) < 12, jnp.float32(0.3))
    assert float(moved.pixel_sigma) != float(start.pixel_sigma)  # 12 points: it calibrates
    assert float(moved.depth_coeff) != float(start.depth_coeff)
