"""Tests of jaxvo.core.robust: chi-square quantiles and constants against SciPy, the robust
scales against NumPy on samples of known spread, Huber's and Cauchy's weights against their
closed forms, and the "a motion explains a set of points" test."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.core.robust import (
    CHI2_1_MEDIAN,
    CHI2_2_MEDIAN,
    CHI_3_Q25,
    MAD_SIGMA,
    MOST,
    cauchy,
    chi2_quantile,
    explains,
    huber_weights,
    mad_scale,
    quantile_scale,
)

# ------------------------------------------------------------------ chi-square quantiles


def test_chi2_quantile_against_scipy_and_the_table():
    """Wilson-Hilferty: within 0.7 % of the exact quantile for 3 or more degrees of freedom
    at the confidences a study sweeps (0.9-0.99), within 2 % at 0.999; within 1 % for 1 and 2
    degrees of freedom at the default 0.99 (the tie test's chi2_1)."""
    q = jax.jit(chi2_quantile)
    # the table values the pipeline's tests stand on (chi2_1, chi2_3, chi2_6 at 0.99): 1 %
    for dof, value in ((1, 6.635), (3, 11.345), (6, 16.812)):
        assert float(q(dof, 0.99)) == pytest.approx(value, rel=0.01)
    stats = pytest.importorskip("scipy.stats")
    for dof in (3, 6, 9, 30):
        for p in (0.9, 0.95, 0.99):
            assert float(q(dof, p)) == pytest.approx(stats.chi2.ppf(p, dof), rel=0.007)
        assert float(q(dof, 0.999)) == pytest.approx(stats.chi2.ppf(0.999, dof), rel=0.02)
    for dof in (1, 2):
        assert float(q(dof, 0.99)) == pytest.approx(stats.chi2.ppf(0.99, dof), rel=0.01)


def test_chi2_quantile_takes_a_traced_confidence():
    ps = jnp.asarray([0.9, 0.99, 0.999], jnp.float32)
    got = np.asarray(jax.jit(jax.vmap(lambda p: chi2_quantile(3, p)))(ps))
    assert np.all(np.diff(got) > 0) and np.all(np.isfinite(got))


# ------------------------------------------------------------------ constants


def test_the_constants_against_scipy():
    stats = pytest.importorskip("scipy.stats")
    # exact to the 5 decimals written
    assert CHI2_1_MEDIAN == pytest.approx(stats.chi2.median(1), abs=1e-5)
    assert CHI2_2_MEDIAN == pytest.approx(stats.chi2.median(2), abs=1e-5)
    assert MAD_SIGMA == pytest.approx(1.0 / stats.norm.ppf(0.75), abs=1e-4)
    # the lower quartile's square root, exact to the 5 decimals written
    assert CHI_3_Q25 == pytest.approx(stats.chi2.ppf(0.25, 3) ** 0.5, abs=1e-5)


# ------------------------------------------------------------------ scales


def test_quantile_scale_is_the_noise_scale_of_pure_noise():
    """The lower quartile of 3-D Gaussian lengths over CHI_3_Q25 is sigma: within 1.2 %
    (20000 samples: the quartile's standard error is about 0.4 %, three of them)."""
    rng = np.random.default_rng(0)
    sigma = 0.37
    r = np.linalg.norm(rng.normal(0, sigma, (20000, 3)), axis=1).astype(np.float32)
    mask = np.ones(r.shape, bool)
    got = float(jax.jit(quantile_scale, static_argnums=(2, 3))(r, mask, 0.25, CHI_3_Q25))
    assert got == pytest.approx(sigma, rel=0.012)


def test_quantile_scale_ignores_masked_values_and_an_empty_mask_gives_0():
    x = jnp.asarray([1.0, 2.0, 3.0, 1e6, 1e6], jnp.float32)
    mask = jnp.asarray([True, True, True, False, False])
    # the order statistic floor(0.5 * 2) = 1 of (1, 2, 3), to 1/4096
    assert float(quantile_scale(x, mask, 0.5, 2.0)) == pytest.approx(1.0, rel=2.5e-4)
    assert float(quantile_scale(x, jnp.zeros(5, bool), 0.5, 2.0)) == 0.0


def test_mad_scale_against_numpy():
    """1.4826 median |x| against NumPy's median (to 1/4096: the bisection's precision; the
    lower middle value of an even count)."""
    rng = np.random.default_rng(1)
    x = np.abs(rng.normal(0, 2.0, 1001)).astype(np.float32)
    mask = rng.random(1001) < 0.8
    want = 2.0 * MAD_SIGMA * np.median(x[mask]) if mask.sum() % 2 else None
    got = float(mad_scale(jnp.asarray(x), jnp.asarray(mask), 2.0))
    lower = np.sort(x[mask])[(mask.sum() - 1) // 2]
    assert got == pytest.approx(2.0 * MAD_SIGMA * lower, rel=2.5e-4)
    if want is not None:
        assert got == pytest.approx(want, rel=2.5e-4)


# ------------------------------------------------------------------ weights


def test_huber_weights_closed_form():
    r = jnp.asarray([0.0, 0.5, 1.0, 2.0, 2.999, 3.0, 10.0], jnp.float32)
    w = jnp.asarray([1.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0], jnp.float32)
    got = np.asarray(huber_weights(r, 1.0, w))
    # exact: min(1, c / r) times w, 0 from three corners on
    np.testing.assert_allclose(got, [1.0, 1.0, 2.0, 0.5, 1.0 / 2.999, 0.0, 0.0], rtol=1e-6)


def test_cauchy_loss_and_weights_closed_form():
    d2 = jnp.asarray([0.0, 1.0, 4.0, 100.0], jnp.float32)
    loss, w = cauchy(d2, 4.0)
    want = 0.5 * 4.0 * np.sum(np.log1p(np.asarray(d2) / 4.0))
    assert float(loss) == pytest.approx(want, rel=1e-6)
    np.testing.assert_allclose(np.asarray(w), 1.0 / (1.0 + np.asarray(d2) / 4.0), rtol=1e-6)
    # the weights are the loss's derivative (float32 central differences: 1e-3)
    grad = jax.grad(lambda x: cauchy(x, 4.0)[0])(d2)
    np.testing.assert_allclose(np.asarray(grad), 0.5 * np.asarray(w), rtol=1e-3)


# ------------------------------------------------------------------ explains


def test_explains_counts_the_share_of_the_set_within_the_test():
    within = jnp.asarray([[True, True, False, False], [True, False, False, False],
                          [True, True, True, False], [False] * 4])
    member = jnp.asarray([[True] * 4, [True] * 4, [True] * 4, [False] * 4])
    # MOST: at least half; a set without points is explained by nothing
    np.testing.assert_array_equal(np.asarray(explains(within, member, MOST)),
                                  [True, False, True, False])
    # strict: more than the fraction
    np.testing.assert_array_equal(np.asarray(explains(within, member, 0.5, strict=True)),
                                  [False, False, True, False])
    # points outside the set do not count
    outside = jnp.asarray([[True, True, True, True]])
    only_two = jnp.asarray([[True, True, False, False]])
    assert bool(explains(outside, only_two, 1.0)[0])
