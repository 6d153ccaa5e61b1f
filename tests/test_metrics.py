"""Tests of jaxvo.evaluation.metrics against closed forms, an SVD reference and evo's own figures."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.evaluation.metrics import (
    SegmentationScores,
    align_umeyama,
    ate,
    error_stats,
    rpe,
    rpe_pairs,
)
from jaxvo.trajectory import Trajectory, read_trajectory
from jaxvo.transforms import pose_from_tq


def random_rotation(rng):
    R, _ = cv2.Rodrigues(rng.normal(size=3))
    return R


def make_pose(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def wobbly_trajectory(rng, n=50):
    t = np.arange(n) / 30.0
    q = rng.normal(size=(n, 4)) * 0.1 + [0, 0, 0, 1]
    pos = np.cumsum(rng.normal(size=(n, 3)) * 0.05, axis=0)
    return Trajectory(t, pose_from_tq(pos, q))


# --- alignment ------------------------------------------------------------------------------


def svd_reference(src, dst, with_scale):
    """Umeyama (1991) eqs. (34)-(42), written independently of jaxvo's implementation."""
    n = len(src)
    ms, md = src.mean(0), dst.mean(0)
    sigma = sum(np.outer(d - md, s - ms) for s, d in zip(src, dst)) / n
    U, D, Vt = np.linalg.svd(sigma)
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(sigma)) or 1.0])
    R = U @ S @ Vt
    var = np.mean(np.sum((src - ms) ** 2, axis=1))
    c = np.trace(np.diag(D) @ S) / var if with_scale else 1.0
    return R, md - c * R @ ms, c


@pytest.mark.parametrize("with_scale", [False, True])
def test_alignment_matches_svd_reference_on_random_data(with_scale):
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = int(rng.integers(3, 60))
        src = rng.normal(size=(n, 3))
        dst = rng.normal(size=(n, 3)) * 2 + rng.normal(size=3)  # unrelated: any SVD case
        A = align_umeyama(src, dst, scale=with_scale)
        R, t, c = svd_reference(src, dst, with_scale)
        np.testing.assert_allclose(A.rotation, R, atol=1e-9)  # tol 1e-9
        np.testing.assert_allclose(A.translation, t, atol=1e-9)  # tol 1e-9 m
        assert abs(A.scale - c) <= 1e-9  # tol 1e-9
        assert abs(np.linalg.det(A.rotation) - 1) <= 1e-12  # tol 1e-12: a rotation


def horn_rotation(src, dst):
    """Horn (1987): the rotation is the top eigenvector of a 4x4 symmetric matrix, a
    quaternion method that shares no step with the SVD route."""
    M = (src - src.mean(0)).T @ (dst - dst.mean(0))
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = M
    N = np.array(
        [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ]
    )
    w, x, y, z = np.linalg.eigh(N)[1][:, -1]
    return pose_from_tq(np.zeros(3), [x, y, z, w])[:3, :3]


def test_alignment_matches_horn_quaternion_method():
    rng = np.random.default_rng(9)
    for _ in range(20):
        src = rng.normal(size=(40, 3))
        dst = src @ random_rotation(rng).T + rng.normal(size=3) + rng.normal(size=(40, 3)) * 0.1
        R = align_umeyama(src, dst).rotation
        np.testing.assert_allclose(R, horn_rotation(src, dst), atol=1e-9)  # tol 1e-9


def test_alignment_recovers_a_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(30, 3))
    R, t = random_rotation(rng), rng.normal(size=3)
    A = align_umeyama(src, 2.5 * src @ R.T + t, scale=True)
    np.testing.assert_allclose(A.rotation, R, atol=1e-12)  # tol 1e-12
    np.testing.assert_allclose(A.translation, t, atol=1e-12)  # tol 1e-12 m
    assert abs(A.scale - 2.5) <= 1e-12  # tol 1e-12


@pytest.mark.parametrize(
    "src, match",
    [
        (np.zeros((2, 3)), "at least 3 matched poses"),
        (np.ones((10, 3)), "same point"),
    ],
)
def test_alignment_degenerate(src, match):
    dst = np.random.default_rng(2).normal(size=src.shape)
    with pytest.raises(InputError, match=match):
        align_umeyama(src, dst)


# --- ATE ------------------------------------------------------------------------------------


def test_ate_zero_after_alignment_under_any_rigid_transform():
    rng = np.random.default_rng(3)
    gt = wobbly_trajectory(rng)
    for _ in range(10):
        S = make_pose(random_rotation(rng), rng.normal(size=3) * 10)
        est = Trajectory(gt.timestamps + 0.004, S @ gt.poses)
        res = ate(gt, est)
        assert res.num_pairs == len(gt)
        assert res.stats.max <= 1e-9  # tol 1e-9 m
        unaligned = ate(gt, est, align=False)
        assert unaligned.stats.rmse > 1e-3  # the transform was not the identity


def test_ate_closed_form_offset():
    # Unaligned, a constant offset d gives every pose error |d|; aligned, it vanishes.
    rng = np.random.default_rng(4)
    gt = wobbly_trajectory(rng)
    poses = gt.poses.copy()
    poses[:, :3, 3] += [0.3, -0.4, 0.0]
    res = ate(gt, Trajectory(gt.timestamps, poses), align=False)
    np.testing.assert_allclose(res.errors, 0.5, atol=1e-12)  # tol 1e-12 m
    assert abs(res.stats.sse - 0.25 * len(gt)) <= 1e-10  # tol 1e-10 m^2
    assert ate(gt, Trajectory(gt.timestamps, poses)).stats.rmse <= 1e-9  # tol 1e-9 m


def test_ate_scale_alignment():
    rng = np.random.default_rng(5)
    gt = wobbly_trajectory(rng)
    poses = gt.poses.copy()
    poses[:, :3, 3] *= 0.5
    est = Trajectory(gt.timestamps, poses)
    assert ate(gt, est).stats.rmse > 1e-3
    res = ate(gt, est, scale=True)
    assert res.stats.rmse <= 1e-9 and abs(res.alignment.scale - 2.0) <= 1e-9  # tol 1e-9


def test_error_stats_against_numpy():
    e = np.array([3.0, 1.0, 2.0, 4.0])
    s = error_stats(e)
    assert s.rmse == pytest.approx(np.sqrt(7.5), abs=1e-15)  # tol 1e-15
    assert (s.mean, s.median, s.min, s.max, s.sse, s.count) == (2.5, 2.5, 1.0, 4.0, 30.0, 4)
    assert s.std == pytest.approx(np.sqrt(1.25), abs=1e-15)  # tol 1e-15; population std


def test_ate_no_match_and_empty():
    rng = np.random.default_rng(6)
    gt = wobbly_trajectory(rng)
    est = Trajectory(gt.timestamps + 100.0, gt.poses)
    with pytest.raises(InputError, match="gt.txt spans .* est.txt spans"):
        ate(gt, est, names=("gt.txt", "est.txt"))
    with pytest.raises(InputError, match="empty trajectory"):
        ate(gt, Trajectory(np.zeros(0), np.zeros((0, 4, 4))))


# --- RPE ------------------------------------------------------------------------------------


def test_rpe_closed_form_constant_drift():
    # Ground truth moves 0.1 m along x per frame; the estimate adds a constant error
    # increment D = (rotation a about z, translation d) to every step:
    # P_{i+1} = P_i @ G @ D. Then inv(Q_i)Q_{i+1} = G, inv(P_i)P_{i+1} = G D, and
    # E_i = inv(G) G D = D: every 1-frame error is exactly |d| metres and a radians.
    n, a, d = 40, np.radians(0.5), np.array([0.01, -0.02, 0.005])
    G = make_pose(np.eye(3), [0.1, 0, 0])
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    D = make_pose(Rz, d)
    Q, P = [np.eye(4)], [np.eye(4)]
    for _ in range(n - 1):
        Q.append(Q[-1] @ G)
        P.append(P[-1] @ G @ D)
    t = np.arange(n) / 30.0
    res = rpe(Trajectory(t, np.array(Q)), Trajectory(t, np.array(P)), delta=1)
    assert res.num_pairs == n - 1
    np.testing.assert_allclose(res.trans_errors, np.linalg.norm(d), atol=1e-12)  # tol 1e-12 m
    np.testing.assert_allclose(res.rot_errors, 0.5, atol=1e-10)  # tol 1e-10 deg
    assert res.trans_unit == "m" and res.rot_unit == "deg"

    # Over delta = k frames E = inv(G^k) (G D)^k, rotation angle k*a (all rotations about z).
    k = 5
    res = rpe(Trajectory(t, np.array(Q)), Trajectory(t, np.array(P)), delta=k)
    GD = np.linalg.matrix_power(G @ D, k)
    E = np.linalg.inv(np.linalg.matrix_power(G, k)) @ GD
    np.testing.assert_allclose(res.trans_errors, np.linalg.norm(E[:3, 3]), atol=1e-12)  # 1e-12 m
    np.testing.assert_allclose(res.rot_errors, k * 0.5, atol=1e-9)  # tol 1e-9 deg


def test_rpe_invariant_to_rigid_transform_of_estimate():
    rng = np.random.default_rng(7)
    gt = wobbly_trajectory(rng)
    est = Trajectory(gt.timestamps, gt.poses @ pose_from_tq([0.01, 0, 0], [0, 0, 0.01, 1]))
    S = make_pose(random_rotation(rng), rng.normal(size=3))
    a = rpe(gt, est, delta=3)
    b = rpe(gt, Trajectory(est.timestamps, S @ est.poses), delta=3)
    np.testing.assert_allclose(a.trans_errors, b.trans_errors, atol=1e-12)  # tol 1e-12 m
    np.testing.assert_allclose(a.rot_errors, b.rot_errors, atol=1e-9)  # tol 1e-9 deg


def test_rpe_pairs_conventions():
    t = np.arange(10) / 10.0
    # evo: consecutive pairs (0, d), (d, 2d), ...; all pairs: every (i, i + d).
    consecutive = [[0, 3], [3, 6], [6, 9]]
    assert rpe_pairs(t, 3, "frames", all_pairs=False, max_diff=0.02).tolist() == consecutive
    assert len(rpe_pairs(t, 3, "frames", all_pairs=True, max_diff=0.02)) == 10 - 3
    # seconds: the pose nearest t_i + delta, none past the end.
    sec = rpe_pairs(t, 0.31, "seconds", all_pairs=True, max_diff=0.02)
    assert sec.tolist() == [[i, i + 3] for i in range(7)]
    assert rpe_pairs(t, 0.3, "seconds", all_pairs=False, max_diff=0.02).tolist() == consecutive


def test_rpe_bad_input():
    rng = np.random.default_rng(8)
    gt = wobbly_trajectory(rng, n=5)
    with pytest.raises(InputError, match="no pose pairs 10 frames apart"):
        rpe(gt, gt, delta=10)
    with pytest.raises(InputError, match="delta must be positive"):
        rpe(gt, gt, delta=0)
    with pytest.raises(InputError, match="whole number"):
        rpe(gt, gt, delta=1.5)
    with pytest.raises(InputError, match="delta unit"):
        rpe(gt, gt, delta=1, delta_unit="metres")


# --- agreement with evo ------------------------------------------------------------------------


def evo_figures(ref_dir):
    gt = read_trajectory(ref_dir / "groundtruth.txt")
    expected = json.loads((ref_dir / "evo_results.json").read_text())
    for name, figures in expected.items():
        est = read_trajectory(ref_dir / name)
        # evo's default association tolerance is 0.01 s.
        one = rpe(gt, est, delta=1, max_diff=0.01)
        ours = {
            "ate_se3_aligned_m": ate(gt, est, max_diff=0.01).stats,
            "ate_unaligned_m": ate(gt, est, max_diff=0.01, align=False).stats,
            "rpe_trans_1frame_m": one.trans,
            "rpe_trans_30frames_m": rpe(gt, est, delta=30, max_diff=0.01).trans,
            "rpe_rot_1frame_deg": one.rot,
        }
        for key, stats in figures.items():
            for stat, value in stats.items():
                yield name, key, stat, value, getattr(ours[key], stat)


def test_agreement_with_evo(require_data):
    ref_dir = require_data("evo_reference")
    rows = list(evo_figures(ref_dir))
    assert len(rows) == 3 * 5 * 7
    for name, key, stat, want, got in rows:
        # evo prints 6 decimals: agreement to half a unit of the last digit (+ float slack).
        assert abs(got - want) <= 5e-7 + 1e-12, f"{name} {key} {stat}: {got} vs evo {want}"


# --- segmentation scores -------------------------------------------------------------------------


def test_segmentation_scores_hand_built_masks():
    gt = np.zeros((4, 5), bool)
    gt[1:3, 1:4] = True  # 6 moving pixels
    pred = np.zeros((4, 5), bool)
    pred[1:3, 2:5] = True  # 6 predicted: 4 hits, 2 false alarms, 2 misses
    s = SegmentationScores()
    s.add(pred, gt)
    assert (s.tp, s.fp, s.fn, s.tn) == (4, 2, 2, 12)
    # A second frame (grid cells, (n,)): 1 hit, 0 false alarms, 3 misses.
    s.add(np.array([1, 0, 0, 0, 0], np.uint8), np.array([1, 1, 1, 1, 0], bool))
    assert (s.tp, s.fp, s.fn, s.tn, s.frames) == (5, 2, 5, 13, 2)
    # Whole-sequence counts (thesis: "calculated in an entire video sequence").
    assert s.recall == pytest.approx(5 / 10, abs=1e-15)  # tol 1e-15
    assert s.precision == pytest.approx(5 / 7, abs=1e-15)  # tol 1e-15
    f = 2 * 0.5 * (5 / 7) / (0.5 + 5 / 7)
    assert s.f_measure == pytest.approx(f, abs=1e-15)  # tol 1e-15


def test_segmentation_scores_no_positives_rule():
    empty = np.zeros((3, 3), bool)
    full = np.ones((3, 3), bool)
    s = SegmentationScores()
    s.add(empty, empty)  # nothing moves, nothing predicted: perfect
    assert (s.recall, s.precision, s.f_measure) == (1.0, 1.0, 1.0)
    s = SegmentationScores()
    s.add(full, empty)  # false alarms only
    assert (s.recall, s.precision, s.f_measure) == (1.0, 0.0, 0.0)
    s = SegmentationScores()
    s.add(empty, full)  # misses only
    assert (s.recall, s.precision, s.f_measure) == (0.0, 1.0, 0.0)
    assert not any(np.isnan(v) for v in SegmentationScores().as_dict().values())
    with pytest.raises(InputError, match="differ in shape"):
        s.add(np.zeros(3), np.zeros(4))


# --- evo's -s / -as: the scale alone, or Sim(3) ----------------------------------------------


def test_scale_only_and_sim3_alignment():
    """evo's ``-s`` without ``-a`` corrects only the scale; ``-as`` fits Sim(3). Closed form:
    an estimate at half the ground truth's scale about the origin is undone by scale 2 alone
    (error 0 unaligned), and a rotated, shifted, half-scale one by Sim(3)."""
    rng = np.random.default_rng(3)
    n = 30
    t = np.arange(n) / 30.0
    gt = Trajectory(t, pose_from_tq(rng.normal(size=(n, 3)), rng.normal(size=(n, 4))))
    half = gt.poses.copy()
    half[:, :3, 3] *= 0.5
    est = Trajectory(t, half)
    only = ate(gt, est, align=False, scale=True)
    assert only.alignment.scale == pytest.approx(2.0, abs=1e-12)  # tol 1e-12
    np.testing.assert_allclose(only.alignment.rotation, np.eye(3), atol=0)  # exactly identity
    assert only.stats.max <= 1e-12  # tol 1e-12 m
    assert ate(gt, est, align=False).stats.rmse > 0.1  # not corrected: far off
    S = pose_from_tq([1.0, -2.0, 0.5], [0.2, -0.1, 0.3, 0.9])
    moved = Trajectory(t, S @ half)
    sim3 = ate(gt, moved, align=True, scale=True)
    assert sim3.alignment.scale == pytest.approx(2.0, abs=1e-9)  # tol 1e-9
    assert sim3.stats.max <= 1e-9  # tol 1e-9 m
    # RPE: the rigid part changes nothing, the scale undoes the halved steps
    assert rpe(gt, moved).trans.rmse > 0.1
    assert rpe(gt, moved, align=True, scale=True).trans.max <= 1e-9  # tol 1e-9 m
    assert rpe(gt, moved, scale=True).trans.max <= 1e-9  # tol 1e-9 m
