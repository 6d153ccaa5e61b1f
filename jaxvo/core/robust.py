"""Robust statistics that every stage asks for, each written once (device side).

* A robust scale: a quantile of residual sizes over the matching quantile of pure noise
  (:func:`quantile_scale`), or the median absolute deviation (:func:`mad_scale`).
* Robust weights: Huber's (:func:`huber_weights`, the ego-motion's re-weighting) and
  Cauchy's loss with its weights (:func:`cauchy`, the keyframe window's refinement).
* Chi-square quantiles: :func:`chi2_quantile` for a confidence that may be traced (a study
  sweeps it), and the constants the scales above compare with.
* "A motion explains a set of points" (:func:`explains`): the share of the set's points
  within the inlier test, against a named fraction (:data:`MOST`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxvo.core.geometry import masked_median, masked_quantile, tiny

# The standard deviation of Gaussian residuals over their median absolute value:
# 1 / Phi^-1(3/4).
MAD_SIGMA = 1.4826
# Medians of chi-square with 1 and 2 degrees of freedom (a residual's part along the
# viewing ray, and across it): the noise calibration compares each part's median with these.
CHI2_1_MEDIAN = 0.45494
CHI2_2_MEDIAN = 1.38629
# The lower quartile of the length of a 3-D standard normal vector, sqrt of chi-square
# with 3 degrees of freedom's (scipy.stats.chi2.ppf(0.25, 3) ** 0.5; Wilson and Hilferty's
# approximation, 1.1078, is 6e-3 high there, relatively).
CHI_3_Q25 = 1.10115
# Named fractions of a set of points for :func:`explains`: a motion explains a segment
# when it explains at least half of its points.
MOST = 0.5


def chi2_quantile(dof, p):
    """The ``p`` quantile of chi-square with ``dof`` degrees of freedom, Wilson and Hilferty's
    cube-root normal approximation (for 3 degrees of freedom within a relative 6e-3 at
    p = 0.9, 3e-3 at 0.99, 1.75e-2 at 0.999, 3.5e-2 at 0.9999; closer with more degrees of
    freedom;
    ``p`` may be traced, so a study can sweep the confidence)."""
    k = jnp.asarray(dof, jnp.float32)
    z = jax.scipy.special.ndtri(jnp.asarray(p, jnp.float32))
    c = 2.0 / (9.0 * k)
    return k * (1.0 - c + z * jnp.sqrt(c)) ** 3


def quantile_scale(x, mask, q: float, reference: float):
    """The ``q`` quantile of ``x[mask]`` (n,) over ``reference``, the same quantile of the
    same quantity for pure noise: the noise's scale, which a share ``1 - q`` of outliers
    (``x`` above the quantile) cannot inflate. To a relative 1/4096; 0 for an empty mask."""
    return masked_quantile(x, mask, q, precision_bits=12) / reference


def mad_scale(x, mask, times: float = 1.0):
    """``times`` robust standard deviations of residual sizes ``x[mask]`` (``x >= 0``): the
    median absolute deviation about 0 times :data:`MAD_SIGMA`, to a relative 1/4096."""
    return times * MAD_SIGMA * masked_median(x, mask, precision_bits=12)


def enough_points(mask, params):
    """(...,) bool whether the points of ``mask`` (..., n) bool are enough to fit and judge
    the camera's motion: at least ``params.min_static_points`` (the ego-motion's fit, the
    noise calibration, the window's refinement of a pair, a background in view)."""
    return jnp.sum(mask, axis=-1) >= params.min_static_points


def huber_weights(r, c, w):
    """Weights ``w`` times Huber's ``min(1, c / r)`` for residual sizes ``r >= 0`` and corner
    ``c``; 0 beyond three corners (``3 c``): such a point is an outlier, not a large error."""
    return jnp.where(r < 3.0 * c, w * jnp.minimum(1.0, c / jnp.maximum(r, tiny())), 0.0)


def cauchy(d2, c2):
    """Cauchy's loss ``c^2 / 2 log(1 + d2 / c^2)`` of squared residuals ``d2``, summed, and
    the iteratively re-weighted least squares weights (its derivative ``1 / (1 + d2 / c^2)``)."""
    return 0.5 * c2 * jnp.sum(jnp.log1p(d2 / c2)), 1.0 / (1.0 + d2 / c2)


def explains(within, member, fraction: float, *, strict: bool = False):
    """(...,) bool whether a motion explains a set of points: of the set's points
    (``member`` (..., n) bool), more than ``fraction`` (at least, unless ``strict``) are
    ``within`` (..., n) bool its test; a set without points is explained by nothing.

    ``fraction``: :data:`MOST`, or ``1 - eps`` for "all but a share ``eps``" (the spatial
    stage's merge rules)."""
    count = jnp.sum(member, axis=-1)
    fits = jnp.sum(member & within, axis=-1)
    if strict:
        return fits > fraction * count
    return (count > 0) & (fits >= fraction * count)
