"""Scores of a run: fixed cameras compared unaligned, segmentation at the grid points."""

from typing import NamedTuple

import numpy as np

from jaxvo.evaluation.scores import segmentation_scores, trajectory_scores
from jaxvo.trajectory import Trajectory


def _traj(positions):
    poses = np.tile(np.eye(4), (len(positions), 1, 1))
    poses[:, :3, 3] = positions
    return Trajectory(np.arange(len(positions)) / 30.0, poses)


def test_fixed_camera_is_scored_without_alignment():
    gt = _traj(np.zeros((40, 3)))
    est = _traj(np.tile([0.01, 0.0, 0.0], (40, 1)))
    s = trajectory_scores(gt, est)
    assert not s["ate_aligned"]
    np.testing.assert_allclose(s["ate_rmse_m"], 0.01, atol=1e-12)  # a constant 1 cm offset
    np.testing.assert_allclose(s["rpe_trans_m_per_frame"], 0.0, atol=1e-12)
    assert "rpe_trans_m_per_s" in s  # 40 frames at 30 Hz is over a second


def test_moving_camera_is_aligned_first():
    t = np.linspace(0, 1, 40)
    gt = _traj(np.stack([t, np.sin(3 * t), t * t], -1))
    est = _traj(np.stack([t, np.sin(3 * t), t * t], -1) + [5.0, -2.0, 1.0])  # shifted copy
    s = trajectory_scores(gt, est)
    assert s["ate_aligned"] and s["ate_rmse_m"] < 1e-9


class _Frame(NamedTuple):
    mask: np.ndarray


def test_segmentation_scores_at_the_cell_centres():
    mask = np.zeros((32, 32), np.uint8)
    mask[:16, :16] = 1  # cell 0 of a 2 x 2 grid moves
    seq = [_Frame(mask), _Frame(mask)]
    pred = np.array([[True, False, False, False], [True, True, False, False]])
    s = segmentation_scores(seq, pred, 16)
    assert (s.tp, s.fp, s.fn) == (2, 1, 0)
    ids = np.array([[2, 1, 1, 0], [1, 1, 1, 1]])  # identifiers: >= 2 means moving
    s = segmentation_scores(seq, ids, 16)
    assert (s.tp, s.fp, s.fn) == (1, 0, 1)
