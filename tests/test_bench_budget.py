"""The error budget's length figures (``bench/bench_budget.py``, issue 43): a path made too
short, uniformly or across the view only, reads as such."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def budget():
    return bench_module("bench_budget")


def _rot(axis, angle):
    return cv2.Rodrigues(np.asarray(axis, float) * angle)[0]


def _truth(n=80, seed=0):
    """A hand-held-like path: a turning camera that moves mostly sideways."""
    rng = np.random.default_rng(seed)
    Q = np.tile(np.eye(4), (n, 1, 1))
    for i in range(1, n):
        step = np.eye(4)
        step[:3, :3] = _rot(rng.normal(size=3), 0.01)
        step[:3, 3] = [0.01, 0.002 * rng.normal(), 0.003 * rng.normal()]
        Q[i] = Q[i - 1] @ step
    return Q


def _scaled(Q, factors):
    """``Q``'s steps with their translations scaled per camera axis."""
    P = Q.copy()
    for i in range(1, len(Q)):
        step = np.linalg.inv(Q[i - 1]) @ Q[i]
        step[:3, 3] *= factors
        P[i] = P[i - 1] @ step
    return P


def test_a_uniformly_short_path_is_all_scale(budget):
    Q = _truth()
    P = _scaled(Q, np.array([0.9, 0.9, 0.9]))
    L = budget.length_budget(P, Q)
    assert L["sim3_scale"] == pytest.approx(1 / 0.9, rel=1e-3)
    assert L["ate_sim3_mm"] < 0.05 * L["ate_se3_mm"]
    for k in (1, 10):
        assert [L["axis_slope"][k][a] for a in "xyz"] == pytest.approx([0.9] * 3, rel=1e-3)


def test_a_path_short_across_the_view_only(budget):
    Q = _truth(seed=1)
    P = _scaled(Q, np.array([0.9, 1.0, 1.0]))
    slope = budget.length_budget(P, Q)["axis_slope"][1]
    assert slope["x"] == pytest.approx(0.9, rel=1e-3)
    assert slope["y"] == pytest.approx(1.0, rel=1e-3)
    assert slope["z"] == pytest.approx(1.0, rel=1e-3)


def test_the_truth_is_its_own_length(budget):
    Q = _truth(seed=2)
    L = budget.length_budget(Q, Q)
    assert L["ate_se3_mm"] < 1e-6 and L["sim3_scale"] == pytest.approx(1.0)
