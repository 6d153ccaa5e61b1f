"""Levenberg-Marquardt as an optax transformation and a pair's points as a quadratic factor
(jaxvo.core.lm), each against an independent reference: numpy's least squares, SciPy's
rotations, a float64 Jacobian written out point by point and central differences."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxvo.core.lm import ArrowCurvature, levenberg_marquardt, pair_factor
from jaxvo.core.noise import PointNoise
from jaxvo.core.points import Points


def test_levenberg_marquardt_reaches_the_least_squares_solution_of_an_arrow_problem():
    # residuals r = A x + B y - c, x dense (3), y one per block of rows (5): the Schur
    # solve must give numpy's least squares solution of the full system
    rng = np.random.default_rng(0)
    m, rows = 5, 4
    A = rng.normal(size=(m * rows, 3))
    B = np.kron(np.eye(m), rng.normal(size=(rows, 1)))
    c = rng.normal(size=m * rows)
    J = np.concatenate([A, B], axis=1)
    ref = np.linalg.lstsq(J, c, rcond=None)[0]

    def curvature_and_grad(x, y):
        r = A @ x + B @ y - c
        Hd, Hc, Hy = A.T @ A, A.T @ B, np.sum(B * B, axis=0)
        return (jnp.asarray(A.T @ r, jnp.float32), jnp.asarray(B.T @ r, jnp.float32)), \
            ArrowCurvature(*(jnp.asarray(v, jnp.float32) for v in (Hd, Hc, Hy))), \
            jnp.float32(0.5 * r @ r)

    opt = levenberg_marquardt(damping=1e-6)
    params = (jnp.zeros(3, jnp.float32), jnp.zeros(m, jnp.float32))
    state = opt.init(params)
    for _ in range(3):
        g, C, value = curvature_and_grad(*(np.asarray(p, np.float64) for p in params))
        step, state = opt.update(g, state, params, curvature=C, value=value)
        params = tuple(p + s for p, s in zip(params, step))
    # tolerance: 1e-4 (float32 normal equations of a well-conditioned 20 x 8 system)
    np.testing.assert_allclose(np.concatenate(params), ref, atol=1e-4)


def test_levenberg_marquardt_undoes_a_step_that_raised_the_cost():
    opt = levenberg_marquardt(damping=1e-3)
    params = (jnp.zeros(2, jnp.float32), jnp.zeros(1, jnp.float32))
    C = ArrowCurvature(jnp.eye(2, dtype=jnp.float32), jnp.zeros((2, 1), jnp.float32),
                       jnp.ones(1, jnp.float32))
    g = (jnp.float32([1.0, -2.0]), jnp.float32([0.5]))
    state = opt.init(params)
    first, state = opt.update(g, state, params, curvature=C, value=jnp.float32(1.0))
    moved = tuple(p + s for p, s in zip(params, first))
    # the cost went up: the next update starts by going back to where the first began
    second, state2 = opt.update(g, state, moved, curvature=C, value=jnp.float32(2.0))
    back = tuple(p + s for p, s in zip(moved, second))
    # the accepted first update lowered the damping tenfold (1e-4); the rejection raises it
    # tenfold again (1e-3) and keeps the accepted cost
    assert float(state.damping) == pytest.approx(1e-4)
    assert float(state2.damping) == pytest.approx(1e-3)
    assert float(state2.value) == 1.0
    # a shorter step from the origin in the same direction: -g / (1 + lambda) per entry
    np.testing.assert_allclose(np.concatenate(first), -np.concatenate(g) / 1.0001, rtol=1e-5)
    np.testing.assert_allclose(np.concatenate(back), -np.concatenate(g) / 1.001, rtol=1e-5)


def test_pair_factor_is_the_gauss_newton_model_of_the_pairs_weighted_residuals():
    rng = np.random.default_rng(3)
    n = 60
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix()  # a frame's motion
    T[:3, 3] = rng.normal(0, 0.02, 3)
    src = rng.uniform([-1.5, -1.0, 1.0], [1.5, 1.0, 3.5], (n, 3))
    dst = src @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 3e-3, (n, 3))
    dst[:6] += 0.05  # outliers: the Cauchy weights bring them down
    u = dst / np.linalg.norm(dst, axis=1, keepdims=True)
    w_lat = 1.0 / rng.uniform(1e-3, 3e-3, n) ** 2
    w_ray = 1.0 / rng.uniform(2e-3, 1e-2, n) ** 2
    use = rng.random(n) > 0.2
    c2 = 11.34  # chi-square(3) at 0.99

    def f32(a):
        return jnp.asarray(a, jnp.float32)

    pts = Points(f32(src.T), f32(dst.T), PointNoise(f32(u.T), f32(w_lat), f32(w_ray)),
                 jnp.ones(n, bool), jnp.float32(c2), jnp.float32(6.63))
    H, g = (np.asarray(a, np.float64) for a in pair_factor(f32(T), pts, jnp.asarray(use), c2))

    # the reference, float64, point by point: M = w_lat (I - u u^T) + w_ray u u^T, the
    # Cauchy weight 1 / (1 + d2 / c2) at T, and the Jacobian [-[X]x | I] of exp(delta) X
    X = src @ T[:3, :3].T + T[:3, 3]
    M = (w_lat[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])
         + w_ray[:, None, None] * u[:, :, None] * u[:, None, :])
    r = X - dst
    d2 = np.einsum("ni,nij,nj->n", r, M, r)
    w = np.where(use, 1.0 / (1.0 + d2 / c2), 0.0)
    J_rot = np.stack([np.cross(e, X) for e in np.eye(3)], axis=2)  # d(w x X)/dw_j = e_j x X
    J = np.concatenate([J_rot, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (n, 3, 6)
    H_ref = np.einsum("n,nia,nij,njb->ab", w, J, M, J)
    g_ref = np.einsum("n,nia,nij,nj->a", w, J, M, r)
    # tolerance: 1e-4 of the largest entry (float32 sums of 60 terms of up to 1e7)
    np.testing.assert_allclose(H, H_ref, atol=1e-4 * np.abs(H_ref).max())
    np.testing.assert_allclose(g, g_ref, atol=1e-4 * np.abs(g_ref).max())

    # g is the gradient, at delta = 0, of the weighted cost of exp(delta) T: central
    # differences of it in float64 (rotation by SciPy)
    def cost(delta):
        Xd = X @ Rotation.from_rotvec(delta[:3]).as_matrix().T + delta[3:]
        rd = Xd - dst
        return 0.5 * np.sum(w * np.einsum("ni,nij,nj->n", rd, M, rd))

    eps = 1e-6
    numeric = np.array([(cost(eps * e) - cost(-eps * e)) / (2 * eps) for e in np.eye(6)])
    np.testing.assert_allclose(g, numeric, atol=1e-4 * np.abs(numeric).max())
