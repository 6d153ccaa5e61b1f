"""Scores of one run on a sequence with ground truth: ATE, RPE and segmentation (host side).

Segmentation is scored where the method measures it: at the grid points, the moving
ground truth being the object-id mask at each cell centre of the previous image of every
frame pair (the image the labels are anchored on). A point counts as predicted moving when
the pipeline reports it moving (``StepOutput.moving``: a moving temporal identifier, thesis
section 4.1, or a moving identifier in this frame's matched measurement); unknown points
count as predicted static.
"""

from __future__ import annotations

import numpy as np

from jaxvo.evaluation.metrics import SegmentationScores, ate, rpe
from jaxvo.trajectory import Trajectory


def ids_at_grid(mask: np.ndarray, cell: int) -> np.ndarray:
    """Ground-truth ``(H, W)`` object-id mask sampled at the grid cell centres -> ``(n,)``."""
    rows, cols = mask.shape[0] // cell, mask.shape[1] // cell
    ys = (np.arange(rows) * cell + cell // 2).astype(int)
    xs = (np.arange(cols) * cell + cell // 2).astype(int)
    return mask[np.ix_(ys, xs)].ravel()


def moving_at_grid(mask: np.ndarray, cell: int) -> np.ndarray:
    """Ground-truth ``(H, W)`` object-id mask sampled at the grid cell centres -> ``(n,)`` bool."""
    return ids_at_grid(mask, cell) > 0


def trajectory_scores(gt: Trajectory, est: Trajectory) -> dict:
    """ATE (rmse) and RPE over 1 frame and over 1 second (rmse), as a flat dict.

    The ATE is taken after rigid alignment, except against a camera that never moves
    (thesis Table 5.1, "Fixed Camera"): no alignment is defined there, and the estimate,
    which starts at the true first pose, is compared as it is (``ate_aligned`` False).
    """
    gt_pos = np.asarray(gt.poses)[:, :3, 3]
    aligned = bool(np.ptp(gt_pos, axis=0).max() > 1e-6)
    a = ate(gt, est, align=aligned)
    r1 = rpe(gt, est, delta=1, delta_unit="frames")
    out = {
        "ate_rmse_m": a.stats.rmse,
        "ate_aligned": aligned,
        "ate_max_m": a.stats.max,
        "rpe_trans_m_per_frame": r1.trans.rmse,
        "rpe_rot_deg_per_frame": r1.rot.rmse,
    }
    duration = float(gt.timestamps[-1] - gt.timestamps[0]) if len(gt) > 1 else 0.0
    if duration > 1.0:
        r_s = rpe(gt, est, delta=1.0, delta_unit="seconds")
        out["rpe_trans_m_per_s"] = r_s.trans.rmse
        out["rpe_rot_deg_per_s"] = r_s.rot.rmse
    return out


def segmentation_scores(seq, moving: np.ndarray, cell: int) -> SegmentationScores:
    """Grid-level recall / precision / F-measure of ``moving`` (T, n) against ``seq``'s masks.

    ``moving[k]`` (bool, or identifiers where >= 2 means moving) labels the grid of image
    ``k`` (the previous image of pair k -> k+1).
    """
    scores = SegmentationScores()
    moving = np.asarray(moving)
    pred = moving if moving.dtype == bool else moving >= 2
    for k in range(len(pred)):
        mask = seq[k].mask
        if mask is None:
            raise ValueError(f"sequence {seq.name!r} has no ground-truth masks")
        scores.add(pred[k], moving_at_grid(mask, cell))
    return scores
