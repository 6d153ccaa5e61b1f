"""Weighted rigid fit (thesis eqs. 2.1, 2.2) against a float64 numpy SVD (Kabsch) reference."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.core.procrustes import fit_rigid, fit_rigid_cols

# float32 fit against a float64 reference: rotation entries and translations (metres) agree
# to this for well-conditioned sets of points spread over ~1 m.
ROT_TOL = 2e-4
TRANS_TOL = 5e-4


def kabsch(src, dst, w):
    """Proper weighted Kabsch in float64: U diag(1, 1, det) V^T of the cross-covariance."""
    w = np.asarray(w, np.float64)
    ps = (w[:, None] * src).sum(0) / w.sum()
    pd = (w[:, None] * dst).sum(0) / w.sum()
    m = ((dst - pd) * w[:, None]).T @ (src - ps)  # eq. (2.18)
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return r, pd - r @ ps, np.linalg.det(u @ vt)


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def batched_fit():
    return jax.jit(jax.vmap(fit_rigid))


@pytest.fixture(scope="module")
def single_fit():
    return jax.jit(fit_rigid)


@pytest.mark.parametrize("n", [4, 500])  # 500 takes the matrix-product path for sums
def test_matches_svd_reference_on_random_rotations(batched_fit, n):
    rng = np.random.default_rng(n)
    b = 64
    src = rng.uniform(-0.5, 0.5, (b, n, 3)) + np.array([0.0, 0.0, 2.0])
    rots = np.stack([random_rotation(rng) for _ in range(b)])
    t = rng.normal(scale=0.5, size=(b, 3))
    dst = np.einsum("bij,bnj->bni", rots, src) + t[:, None] + rng.normal(0, 0.005, (b, n, 3))
    w = rng.uniform(0.2, 1.0, (b, n))
    T, ok = batched_fit(*(jnp.asarray(x, jnp.float32) for x in (src, dst, w)))
    T = np.asarray(T, np.float64)
    assert np.all(np.asarray(ok))
    for i in range(b):
        r_ref, t_ref, _ = kabsch(src[i], dst[i], w[i])
        np.testing.assert_allclose(T[i, :3, :3], r_ref, atol=ROT_TOL)
        np.testing.assert_allclose(T[i, :3, 3], t_ref, atol=TRANS_TOL)
        np.testing.assert_allclose(T[i, 3], [0, 0, 0, 1], atol=0)
        # a proper rotation: orthonormal with det +1
        np.testing.assert_allclose(T[i, :3, :3] @ T[i, :3, :3].T, np.eye(3), atol=1e-5)
        assert abs(np.linalg.det(T[i, :3, :3]) - 1.0) < 1e-5


def test_reflection_gives_the_best_proper_rotation(batched_fit):
    rng = np.random.default_rng(1)
    b, n = 64, 4  # the shape of the first test: no recompile
    # Anisotropic clouds (distinct singular values, so the proper optimum is unique) mirrored
    # through a plane: the unconstrained polar factor of eq. (2.1) would be a reflection.
    src = rng.normal(size=(b, n, 3)) * np.array([0.6, 0.3, 0.1])
    mirror = np.diag([1.0, 1.0, -1.0])
    rots = np.stack([random_rotation(rng) for _ in range(b)])
    dst = np.einsum("bij,jk,bnk->bni", rots, mirror, src) + rng.normal(0, 1e-3, (b, n, 3))
    w = np.ones((b, n))
    T, ok = batched_fit(*(jnp.asarray(x, jnp.float32) for x in (src, dst, w)))
    T = np.asarray(T, np.float64)
    assert np.all(np.asarray(ok))
    for i in range(b):
        r_ref, t_ref, det_polar = kabsch(src[i], dst[i], w[i])
        assert det_polar < 0  # the case under test: the SVD's U V^T is a reflection
        assert abs(np.linalg.det(T[i, :3, :3]) - 1.0) < 1e-5
        np.testing.assert_allclose(T[i, :3, :3], r_ref, atol=ROT_TOL)
        np.testing.assert_allclose(T[i, :3, 3], t_ref, atol=TRANS_TOL)


@pytest.mark.parametrize(
    "case",
    ["two_points", "collinear", "coincident", "zero_weights", "one_weighted", "dst_collinear"],
)
def test_degenerate_sets_are_flagged_and_finite(single_fit, case):
    rng = np.random.default_rng(2)
    n = 6
    src = rng.normal(size=(n, 3))
    w = np.ones(n)
    if case == "two_points":
        w[2:] = 0.0
    elif case == "collinear":
        src = np.outer(rng.normal(size=n), [0.3, -0.2, 0.9]) + np.array([0.1, 0.2, 2.0])
    elif case == "coincident":
        src = np.tile([0.1, 0.2, 2.0], (n, 1))
    elif case == "zero_weights":
        w[:] = 0.0
    elif case == "one_weighted":
        w[1:] = 0.0
    dst = src + np.array([0.05, 0.0, -0.02])
    if case == "dst_collinear":
        dst = np.outer(rng.normal(size=n), [1.0, 0.0, 0.0])
    T, ok = single_fit(*(jnp.asarray(x, jnp.float32) for x in (src, dst, w)))
    assert not bool(ok)
    np.testing.assert_array_equal(np.asarray(T), np.eye(4))


def test_weighted_fit_equals_fit_on_subset(single_fit):
    rng = np.random.default_rng(3)
    n = 40
    src = rng.uniform(-1, 1, (n, 3)) + np.array([0, 0, 2.5])
    r = random_rotation(rng)
    dst = src @ r.T + np.array([0.1, -0.2, 0.3])
    dst[20:] += rng.normal(0, 0.3, (20, 3))  # outliers, weighted out below
    w = np.r_[np.ones(20), np.zeros(20)]
    T_w, ok_w = single_fit(*(jnp.asarray(x, jnp.float32) for x in (src, dst, w)))
    T_s, ok_s = single_fit(*(jnp.asarray(x, jnp.float32) for x in (src[:20], dst[:20], w[:20])))
    assert bool(ok_w) and bool(ok_s)
    np.testing.assert_allclose(np.asarray(T_w), np.asarray(T_s), atol=1e-5)
    np.testing.assert_allclose(np.asarray(T_w)[:3, :3], r, atol=ROT_TOL)


def test_the_column_layout_fits_as_the_rows(single_fit):
    rng = np.random.default_rng(4)
    n = 6  # the shape of the degenerate-set tests: no recompile of single_fit
    src = rng.normal(size=(n, 3)).astype(np.float32)
    dst = (src @ random_rotation(rng).T + 0.1 + rng.normal(0, 0.01, (n, 3))).astype(np.float32)
    w = np.ones(n, np.float32)
    T_rows, _ = single_fit(src, dst, w)
    T_cols, _ = jax.jit(fit_rigid_cols)(src.T, dst.T, w)
    np.testing.assert_allclose(np.asarray(T_rows), np.asarray(T_cols), atol=1e-6)


class FitVariants(chex.TestCase):
    """The public fit with and without jit (the eager path runs the Python-level shape
    checks and branches on static shapes that jit only traces once)."""

    @chex.variants(with_jit=True, without_jit=True)
    def test_fit_matches_the_svd_reference(self):
        rng = np.random.default_rng(11)
        src = rng.uniform(-0.5, 0.5, (200, 3)) + np.array([0.0, 0.0, 2.0])
        R = random_rotation(rng)
        dst = src @ R.T + np.array([0.1, -0.2, 0.05]) + rng.normal(0, 0.003, (200, 3))
        w = rng.uniform(0.2, 1.0, 200)
        T, ok = self.variant(fit_rigid)(jnp.asarray(src, jnp.float32),
                                        jnp.asarray(dst, jnp.float32),
                                        jnp.asarray(w, jnp.float32))
        R_ref, t_ref, _ = kabsch(src, dst, w)
        assert bool(ok)
        np.testing.assert_allclose(np.asarray(T)[:3, :3], R_ref, atol=ROT_TOL)
        np.testing.assert_allclose(np.asarray(T)[:3, 3], t_ref, atol=TRANS_TOL)

    def test_mismatched_shapes_are_caught_at_the_call(self):
        with pytest.raises(AssertionError):
            fit_rigid(jnp.zeros((10, 3)), jnp.zeros((9, 3)), jnp.ones(10))
