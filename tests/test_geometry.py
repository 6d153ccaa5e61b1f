"""Device-side pose helpers and the masked median against numpy and SciPy references
(SciPy's rotations and polar decomposition for the perturbations and the re-orthonormalised
poses)."""

import jax.numpy as jnp
import numpy as np
from scipy.linalg import polar
from scipy.spatial.transform import Rotation

from jaxvo.core.geometry import (
    invert_pose,
    make_pose,
    masked_median,
    orthonormal,
    perturb,
    transform_points,
)


def _random_pose(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))  # a proper rotation
    return np.asarray(make_pose(jnp.asarray(q, jnp.float32), jnp.asarray(rng.normal(size=3),
                                                                          jnp.float32)))


def test_invert_and_transform_match_numpy():
    rng = np.random.default_rng(0)
    T = _random_pose(rng)
    # float32 rounding: 1e-5
    np.testing.assert_allclose(np.asarray(invert_pose(jnp.asarray(T))), np.linalg.inv(T),
                               atol=1e-5)
    pts = rng.normal(size=(50, 3)).astype(np.float32)
    ref = pts @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(np.asarray(transform_points(jnp.asarray(T), pts)), ref, atol=1e-5)


def test_masked_median_matches_numpy_and_is_zero_when_empty():
    rng = np.random.default_rng(1)
    for n_sel in (1, 2, 7, 40):
        x = rng.normal(size=64).astype(np.float32)
        mask = np.zeros(64, bool)
        mask[rng.choice(64, n_sel, replace=False)] = True
        # exact up to float32 rounding of the middle mean: 1e-6
        np.testing.assert_allclose(float(masked_median(x, mask)), np.median(x[mask]), atol=1e-6)
    assert float(masked_median(jnp.ones(5), jnp.zeros(5, bool))) == 0.0
    # ties, signed zeros, huge magnitudes: the bisection works on the float bit patterns
    x = np.array([-0.0, 0.0, 3.0, 3.0, -1e30, 1e30, -2.5, 7.0], np.float32)
    for sel in ([0, 1], [2, 3, 6], [4, 5], [4, 6, 7, 2], list(range(8))):
        mask = np.isin(np.arange(8), sel)
        assert float(masked_median(x, mask)) == np.median(x[mask])


def test_masked_median_to_12_bits_is_the_lower_middle_value_to_one_part_in_4096():
    rng = np.random.default_rng(2)
    for sign in (1.0, -1.0):
        for n_sel in (1, 2, 7, 40, 1200):
            x = (sign * rng.lognormal(-5.0, 2.0, size=1200)).astype(np.float32)
            mask = np.zeros(1200, bool)
            mask[rng.choice(1200, n_sel, replace=False)] = True
            lower = float(np.sort(x[mask])[(n_sel - 1) // 2])
            got = float(masked_median(x, mask, precision_bits=12))
            # at most 2^-12 of its size below the lower middle value, never above it
            assert lower - abs(lower) * 2.0**-12 <= got <= lower, (sign, n_sel, got, lower)
    assert float(masked_median(jnp.ones(5), jnp.zeros(5, bool), precision_bits=12)) == 0.0
    x = np.array([-2.0, 0.0, 0.0, 3.0, 1e30], np.float32)  # zeros, signs, huge values
    assert float(masked_median(x, np.array([False, True, True, True, False]), precision_bits=12)) == 0.0
    got = float(masked_median(x, x > 1.0, precision_bits=12))  # of 3 and 1e30
    assert 3.0 * (1 - 2.0**-12) <= got <= 3.0
    got = float(masked_median(x, x != 0.0, precision_bits=12))  # of -2, 3, 1e30
    assert 3.0 * (1 - 2.0**-12) <= got <= 3.0


def test_so3_exp_is_the_rotation_about_the_axis_and_exact_near_zero():
    from jaxvo.core.geometry import so3_exp

    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    for angle in (0.0, 1e-7, 0.3, 2.5):
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        ref = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
        got = np.asarray(so3_exp(jnp.asarray(axis * angle, jnp.float32)))
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(got, ref, atol=2e-6)


def _poses(rng, k):
    T = np.tile(np.eye(4), (k, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, (k, 3))).as_matrix()
    T[:, :3, 3] = rng.normal(0, 1.0, (k, 3))
    return T


def test_perturb_rotates_and_shifts_each_pose_on_the_left():
    rng = np.random.default_rng(1)
    T = _poses(rng, 4)
    xi = np.concatenate([rng.normal(0, 0.3, (4, 3)), rng.normal(0, 0.1, (4, 3))], axis=1)
    got = np.asarray(perturb(jnp.asarray(T, jnp.float32), jnp.asarray(xi, jnp.float32)))
    left = np.tile(np.eye(4), (4, 1, 1))
    left[:, :3, :3] = Rotation.from_rotvec(xi[:, :3]).as_matrix()
    left[:, :3, 3] = xi[:, 3:]
    # tolerance: 1e-5 (float32 rotations of rotation vectors up to about 1 rad, metres)
    np.testing.assert_allclose(got, left @ T, atol=1e-5)


def test_orthonormal_pulls_a_drifted_rotation_back_onto_so3():
    rng = np.random.default_rng(2)
    T = _poses(rng, 3)
    drifted = T.copy()
    # float32 rounding compounded over many steps: an error of 5e-4 in each entry
    drifted[:, :3, :3] += rng.normal(0, 5e-4, (3, 3, 3))
    before = [np.abs(D.T @ D - np.eye(3)).max() for D in drifted[:, :3, :3]]
    got = np.asarray(orthonormal(jnp.asarray(drifted, jnp.float32)), np.float64)
    R = got[:, :3, :3]
    # one Newton-Schulz step leaves about 1.5 times the squared error (a few 1e-6) of the
    # nearest rotation, SciPy's polar factor; tolerance 1e-5 (float32)
    assert min(before) > 5e-4
    for k in range(3):
        np.testing.assert_allclose(R[k], polar(drifted[k, :3, :3])[0], atol=1e-5)
        np.testing.assert_allclose(R[k].T @ R[k], np.eye(3), atol=1e-5)
    np.testing.assert_allclose(got[:, :3, 3], drifted[:, :3, 3], atol=1e-6)  # translation kept
    np.testing.assert_array_equal(got[:, 3], np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
