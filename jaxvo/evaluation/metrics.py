"""Evaluation: trajectory errors (ATE, RPE) and motion-segmentation scores, float64 numpy.

Conventions follow the TUM RGB-D benchmark (Sturm et al., IROS 2012) and evo 1.38
(github.com/MichaelGrupp/evo), so that figures can be compared with published ones:

* trajectories are associated by nearest timestamp, one-to-one, within ``max_diff``;
* the ground truth ``Q`` is the reference, the estimate ``P`` is aligned onto it;
* ATE is the translation of ``inv(Q_i) S P_i`` (thesis eqs. 5.6-5.8) after a rigid (by
  default no scale) Umeyama alignment ``S`` of the positions;
* RPE is the translation / rotation angle of ``inv(inv(Q_i) Q_j) inv(P_i) P_j`` (thesis
  eqs. 5.4, 5.5); with a delta in frames the pairs are evo's consecutive ones
  ``(0, d), (d, 2d), ...`` (``all_pairs=True``: every ``(i, i + d)``, the thesis's
  ``m = n - delta``); with a delta in seconds they are TUM ``evaluate_rpe.py``'s: every
  ``i`` with the pose nearest ``t_i + delta``;
* statistics: rmse, mean, median, std (population), min, max, sse, as evo reports them.

Nothing here imports JAX or OpenCV: ``jaxvo eval`` stays quick to start.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.trajectory import Trajectory, associate
from jaxvo.transforms import relative_pose, rotation_angle

# Positions that spread less than this (metres, RMS about their centroid) carry no
# orientation: a rotation fitted to them would be arbitrary.
_MIN_SPREAD_M = 1e-9
# Positions further out than this (metres) are refused: no trajectory reaches them, and
# their squares (1e200) stay far from where float64 overflows (1.8e308, from |x| ~ 1.3e154),
# which made the alignment's SVD fail to converge on coordinates near 1e200.
_MAX_COORD_M = 1e100


class Stats(NamedTuple):
    """Summary of per-pose (or per-pair) errors, in the unit of the errors."""

    rmse: float
    mean: float
    median: float
    std: float  # population standard deviation, as numpy's and evo's default
    min: float
    max: float
    sse: float  # sum of squared errors
    count: int

    def as_dict(self) -> dict[str, float | int]:
        return self._asdict()


def error_stats(errors: np.ndarray) -> Stats:
    """Statistics of a non-empty error vector ``(n,)`` (thesis eq. 5.4 / 5.6 give the rmse)."""
    e = np.asarray(errors, np.float64)
    if e.size == 0:
        raise InputError("no errors to summarise (no pose pairs)")
    sse = float(np.sum(e * e))
    return Stats(
        rmse=float(np.sqrt(sse / e.size)),
        mean=float(np.mean(e)),
        median=float(np.median(e)),
        std=float(np.std(e)),
        min=float(np.min(e)),
        max=float(np.max(e)),
        sse=sse,
        count=int(e.size),
    )


# --- alignment -------------------------------------------------------------------------


class Alignment(NamedTuple):
    """A similarity ``x -> scale * rotation @ x + translation`` (``S`` of thesis eq. 5.7)."""

    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,) metres
    scale: float  # 1.0 for a rigid alignment

    def matrix(self) -> np.ndarray:
        """The 4x4 matrix ``[[s R, t], [0, 1]]``."""
        S = np.eye(4)
        S[:3, :3] = self.scale * self.rotation
        S[:3, 3] = self.translation
        return S

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """Map points ``(n, 3)``."""
        return self.scale * np.asarray(points, np.float64) @ self.rotation.T + self.translation

    def apply_poses(self, poses: np.ndarray) -> np.ndarray:
        """``S @ P`` for poses ``(n, 4, 4)``; with a scale the rotation part stays a rotation
        (the scale moves positions only), as evo's ``align(correct_scale=True)``."""
        out = np.array(poses, np.float64)
        out[:, :3, 3] = self.apply_points(out[:, :3, 3])
        out[:, :3, :3] = self.rotation @ out[:, :3, :3]
        return out


def align_umeyama(src: np.ndarray, dst: np.ndarray, *, scale: bool = False) -> Alignment:
    """Least-squares similarity taking positions ``src`` onto ``dst`` (Umeyama 1991).

    Minimises ``sum_i |dst_i - (s R src_i + t)|^2`` over rotations ``R`` (det +1),
    translations ``t`` and, when ``scale`` is set, ``s > 0``: the ``S`` of thesis eq. (5.8),
    ``S P_i ~ Q_i``, restricted to positions as in the TUM benchmark and evo.

    Args:
      src: (n, 3) estimated positions, metres.
      dst: (n, 3) reference positions, metres.
      scale: also fit a scale (for monocular estimates); otherwise ``s = 1``.
    Returns:
      the :class:`Alignment`.
    Raises:
      InputError: fewer than 3 positions, or either set all at one point.
    """
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(f"need two (n, 3) position sets, got {src.shape} and {dst.shape}")
    n = len(src)
    if n < 3:
        raise InputError(f"alignment needs at least 3 matched poses, got {n}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float(np.sum(xs * xs)) / n
    for name, x in (("estimated", xs), ("reference", xd)):
        if np.sqrt(np.sum(x * x) / n) < _MIN_SPREAD_M:
            raise InputError(
                f"cannot align: all {n} {name} positions are the same point "
                "(use --no-align, or a trajectory that moves)"
            )
    cov = xd.T @ xs / n
    U, D, Vt = np.linalg.svd(cov)
    # Umeyama's sign correction: the nearest proper rotation, never a reflection.
    W = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        W[2, 2] = -1.0
    R = U @ W @ Vt
    s = float(np.trace(np.diag(D) @ W) / var_s) if scale else 1.0
    t = mu_d - s * R @ mu_s
    return Alignment(R, t, s)


# --- trajectory errors ------------------------------------------------------------------


class Matched(NamedTuple):
    """The poses of two trajectories associated by timestamp, one-to-one, in time order."""

    gt_timestamps: np.ndarray  # (n,) seconds
    est_timestamps: np.ndarray  # (n,) seconds
    gt_poses: np.ndarray  # (n, 4, 4) T_w_c, float64
    est_poses: np.ndarray  # (n, 4, 4) T_w_c as given (not aligned), float64


class AteResult(NamedTuple):
    """Absolute trajectory error (thesis eqs. 5.6-5.8), metres."""

    errors: np.ndarray  # (n,) |trans(F_i)| per matched pose, metres
    timestamps: np.ndarray  # (n,) the ground truth's stamps of the matched poses, seconds
    stats: Stats  # metres
    alignment: Alignment | None  # S, or None when not aligned
    max_diff: float  # association tolerance used, seconds
    unit: str = "m"
    matched: Matched | None = None  # the associated poses the errors were taken on

    @property
    def num_pairs(self) -> int:
        return len(self.errors)


class RpeResult(NamedTuple):
    """Relative pose error (thesis eqs. 5.4, 5.5) over pose pairs ``delta`` apart."""

    trans_errors: np.ndarray  # (m,) |trans(E_i)|, metres
    rot_errors: np.ndarray  # (m,) rotation angle of E_i, degrees
    pairs: np.ndarray  # (m, 2) indices (i, j) into the matched poses
    timestamps: np.ndarray  # (m, 2) ground-truth stamps of each pair, seconds
    trans: Stats  # metres
    rot: Stats  # degrees
    delta: float
    delta_unit: str  # "frames" or "seconds"
    all_pairs: bool
    max_diff: float  # association tolerance used, seconds
    trans_unit: str = "m"
    rot_unit: str = "deg"
    alignment: Alignment | None = None  # S applied to the estimate first (see rpe's scale)
    matched: Matched | None = None  # the associated poses the pairs index

    @property
    def num_pairs(self) -> int:
        return len(self.pairs)


def match_poses(
    gt: Trajectory, est: Trajectory, max_diff: float, names: tuple[str, str]
) -> Matched:
    """Associate ``est`` with ``gt`` by nearest timestamp within ``max_diff`` seconds
    (:func:`jaxvo.trajectory.associate`), after checking that neither is empty or implausibly far out.

    Args:
      gt: ground-truth trajectory.
      est: estimated trajectory.
      max_diff: largest time difference of an associated pair, seconds.
      names: names of the two trajectories in error messages.
    Returns:
      :class:`Matched`.
    """
    for traj, name in zip((gt, est), names):
        if len(traj) == 0:
            raise InputError(f"{name}: empty trajectory")
        far = float(np.max(np.abs(np.asarray(traj.poses, np.float64)[:, :3, 3])))
        if not far <= _MAX_COORD_M:  # also NaN
            raise InputError(
                f"{name}: a position lies {far:.3g} m from the origin; beyond "
                f"{_MAX_COORD_M:g} m no trajectory is plausible (and float64 overflows)"
            )
    ig, ie = associate(gt.timestamps, est.timestamps, max_diff, names=names)
    return Matched(
        np.asarray(gt.timestamps, np.float64)[ig],
        np.asarray(est.timestamps, np.float64)[ie],
        np.asarray(gt.poses, np.float64)[ig],
        np.asarray(est.poses, np.float64)[ie],
    )


def fit_alignment(m: Matched, *, align: bool, scale: bool) -> Alignment | None:
    """The ``S`` evo's ``-a`` / ``-s`` / ``-as`` apply to the estimate, from the matched
    positions: ``align`` a rigid Umeyama fit (SE(3)); ``align`` and ``scale`` Sim(3);
    ``scale`` alone only the Sim(3) fit's scale (rotation identity, no translation: evo's
    "scale corrected"); neither ``None``.

    Args:
      m: the associated poses.
      align: fit a rotation and translation.
      scale: fit a scale.
    Returns:
      the :class:`Alignment`, or ``None``.
    """
    if not (align or scale):
        return None
    S = align_umeyama(m.est_poses[:, :3, 3], m.gt_poses[:, :3, 3], scale=scale)
    return S if align else Alignment(np.eye(3), np.zeros(3), S.scale)


def ate(
    gt: Trajectory,
    est: Trajectory,
    *,
    max_diff: float = 0.02,
    align: bool = True,
    scale: bool = False,
    names: tuple[str, str] = ("ground truth", "estimate"),
) -> AteResult:
    """Absolute trajectory error of ``est`` against ``gt``, thesis eqs. (5.6)-(5.8).

    ``F_i = inv(Q_i) S P_i`` (eq. 5.7) with ``S`` from :func:`align_umeyama` on the matched
    positions (eq. 5.8), or the identity when ``align`` is false; the error of pose ``i`` is
    ``|trans(F_i)| = |S p_i - q_i|`` (the rotation of ``Q_i`` does not change the norm) and
    the ATE of eq. (5.6) is ``stats.rmse``.

    Args:
      gt: ground-truth trajectory ``Q`` (``T_w_c``).
      est: estimated trajectory ``P`` (``T_w_c``).
      max_diff: largest time difference of an associated pair, seconds.
      align: fit ``S`` (rigid); otherwise compare in the given frames.
      scale: let ``S`` scale too: Sim(3) with ``align``, the scale alone without it (evo's
        ``-s``, see :func:`fit_alignment`).
      names: names of the two trajectories in error messages (e.g. the file paths).
    Returns:
      :class:`AteResult`, metres.
    """
    m = match_poses(gt, est, max_diff, names)
    S = fit_alignment(m, align=align, scale=scale)
    p = S.apply_points(m.est_poses[:, :3, 3]) if S is not None else m.est_poses[:, :3, 3]
    errors = np.linalg.norm(p - m.gt_poses[:, :3, 3], axis=-1)  # |trans(F_i)|, eqs. 5.6, 5.7
    return AteResult(errors, m.gt_timestamps, error_stats(errors), S, float(max_diff),
                     matched=m)


def rpe_pairs(
    timestamps: np.ndarray, delta: float, delta_unit: str, *, all_pairs: bool, max_diff: float
) -> np.ndarray:
    """Index pairs ``(i, j)`` of matched poses ``delta`` apart (see the module docstring).

    Args:
      timestamps: (n,) sorted stamps of the matched poses, seconds.
      delta: frames (a positive integer) or seconds (positive).
      delta_unit: ``"frames"`` or ``"seconds"``.
      all_pairs: every start pose rather than consecutive, non-overlapping pairs.
      max_diff: with seconds, how far past the last pose ``t_i + delta`` may fall.
    Returns:
      (m, 2) int array, possibly empty.
    """
    n = len(timestamps)
    if delta_unit == "frames":
        d = int(delta)
        starts = np.arange(0, n - d) if all_pairs else np.arange(0, n, d)[:-1]
        starts = starts[starts + d < n]
        return np.stack([starts, starts + d], axis=-1).astype(np.int64).reshape(-1, 2)
    if delta_unit != "seconds":
        raise InputError(f"delta unit must be 'frames' or 'seconds', got {delta_unit!r}")

    def partner(i: int) -> int | None:
        target = timestamps[i] + delta
        if target > timestamps[-1] + max_diff:
            return None
        k = int(np.searchsorted(timestamps, target))
        cands = [c for c in (k - 1, k) if 0 <= c < n]
        j = min(cands, key=lambda c: abs(timestamps[c] - target))
        return j if j > i else None

    pairs = []
    if all_pairs:
        for i in range(n):
            j = partner(i)
            if j is not None:
                pairs.append((i, j))
    else:
        i = 0
        while (j := partner(i)) is not None:
            pairs.append((i, j))
            i = j
    return np.asarray(pairs, np.int64).reshape(-1, 2)


def rpe(
    gt: Trajectory,
    est: Trajectory,
    *,
    delta: float = 1,
    delta_unit: str = "frames",
    max_diff: float = 0.02,
    all_pairs: bool | None = None,
    align: bool = False,
    scale: bool = False,
    names: tuple[str, str] = ("ground truth", "estimate"),
) -> RpeResult:
    """Relative pose error of ``est`` against ``gt``, thesis eqs. (5.4), (5.5).

    ``E_i = inv(inv(Q_i) Q_j) (inv(P_i) P_j)`` (eq. 5.5) for each pair ``(i, j)``; the
    translational error is ``|trans(E_i)|`` metres (its rmse is eq. 5.4), the rotational
    error the angle of ``rot(E_i)`` in degrees. No alignment is needed: ``E_i`` does not
    change under a rigid transform of either trajectory; ``align`` / ``scale`` apply evo's
    ``-a`` / ``-s`` first (:func:`fit_alignment`), of which only the scale changes ``E_i``
    (the translational errors of an estimate off in scale, e.g. monocular).

    Args:
      gt: ground-truth trajectory ``Q``.
      est: estimated trajectory ``P``.
      delta: pair spacing: a positive integer with ``"frames"``, positive with ``"seconds"``.
      delta_unit: ``"frames"`` (counted along the matched poses) or ``"seconds"``.
      max_diff: largest time difference of an associated pair, seconds.
      all_pairs: every start pose (thesis eq. 5.4, ``m = n - delta``) or consecutive
        non-overlapping pairs; ``None`` follows the reference tool of each unit: evo's
        consecutive pairs for frames, TUM ``evaluate_rpe.py``'s all pairs for seconds.
      align: align the estimate onto the ground truth first (rigid Umeyama).
      scale: correct the estimate's scale first (Sim(3) Umeyama's scale).
      names: names of the two trajectories in error messages.
    Returns:
      :class:`RpeResult`.
    """
    if delta_unit not in ("frames", "seconds"):
        raise InputError(f"delta unit must be 'frames' or 'seconds', got {delta_unit!r}")
    if not np.isfinite(delta) or delta <= 0:
        raise InputError(f"delta must be positive, got {delta}")
    if delta_unit == "frames" and float(delta) != int(delta):
        raise InputError(f"a delta in frames must be a whole number, got {delta}")
    if all_pairs is None:
        all_pairs = delta_unit == "seconds"
    m = match_poses(gt, est, max_diff, names)
    S = fit_alignment(m, align=align, scale=scale)
    stamps, Q = m.gt_timestamps, m.gt_poses
    P = S.apply_poses(m.est_poses) if S is not None else m.est_poses
    pairs = rpe_pairs(stamps, delta, delta_unit, all_pairs=all_pairs, max_diff=max_diff)
    if len(pairs) == 0:
        span = stamps[-1] - stamps[0]
        raise InputError(
            f"no pose pairs {delta:g} {delta_unit} apart: {len(stamps)} matched poses "
            f"spanning {span:.3f} s"
        )
    i, j = pairs[:, 0], pairs[:, 1]
    E = relative_pose(relative_pose(Q[i], Q[j]), relative_pose(P[i], P[j]))  # eq. (5.5)
    trans = np.linalg.norm(E[:, :3, 3], axis=-1)
    rot = np.degrees(rotation_angle(E[:, :3, :3]))
    return RpeResult(
        trans_errors=trans,
        rot_errors=rot,
        pairs=pairs,
        timestamps=stamps[pairs],
        trans=error_stats(trans),
        rot=error_stats(rot),
        delta=float(delta) if delta_unit == "seconds" else int(delta),
        delta_unit=delta_unit,
        all_pairs=bool(all_pairs),
        max_diff=float(max_diff),
        alignment=S,
        matched=m,
    )


# --- motion segmentation ----------------------------------------------------------------


class SegmentationScores:
    """Recall, precision and F-measure of moving-object masks over a whole sequence.

    Thesis eqs. (5.1)-(5.3), "calculated in an entire video sequence": the counts
    ``TP, FP, FN, TN`` are summed over every frame added, then the scores are taken once.
    Moving is the positive class.

    Rule when a denominator is zero (a figure is never NaN): a score whose denominator
    counts nothing is 1.0, because nothing was missed (recall, no moving ground truth) or
    nothing was falsely reported (precision, no moving prediction); the F-measure is 0.0
    when recall + precision is 0. So a sequence with no motion that is predicted with no
    motion scores 1 / 1 / 1, and any miss or false alarm against an empty side scores F 0.
    """

    def __init__(self) -> None:
        self.tp = 0
        self.fp = 0
        self.fn = 0
        self.tn = 0
        self.frames = 0

    def add(self, pred_moving: np.ndarray, gt_moving: np.ndarray) -> None:
        """Count one frame: ``pred_moving`` and ``gt_moving`` of equal shape, e.g. (H, W) or
        (n,) grid cells; non-zero (or True) means moving."""
        pred = np.asarray(pred_moving) != 0
        gt = np.asarray(gt_moving) != 0
        if pred.shape != gt.shape:
            raise InputError(
                f"prediction and ground-truth masks differ in shape: {pred.shape} vs {gt.shape}"
            )
        self.tp += int(np.count_nonzero(pred & gt))
        self.fp += int(np.count_nonzero(pred & ~gt))
        self.fn += int(np.count_nonzero(~pred & gt))
        self.tn += int(np.count_nonzero(~pred & ~gt))
        self.frames += 1

    @property
    def recall(self) -> float:
        """TP / (TP + FN), thesis eq. (5.1); 1.0 with no moving ground truth."""
        den = self.tp + self.fn
        return self.tp / den if den else 1.0

    @property
    def precision(self) -> float:
        """TP / (TP + FP), thesis eq. (5.2); 1.0 with no moving prediction."""
        den = self.tp + self.fp
        return self.tp / den if den else 1.0

    @property
    def f_measure(self) -> float:
        """Harmonic mean of recall and precision, thesis eq. (5.3); 0.0 when both are 0."""
        r, p = self.recall, self.precision
        return 2.0 * r * p / (r + p) if r + p > 0 else 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "recall": self.recall,
            "precision": self.precision,
            "f_measure": self.f_measure,
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "tn": self.tn,
            "frames": self.frames,
        }
