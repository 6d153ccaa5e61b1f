"""Rotations and rigid poses in float64 numpy (quaternions in TUM order ``qx qy qz qw``).

The traced step has its own pose helpers in :mod:`jaxvo.core.geometry`; this module serves
trajectory files, bags and the evaluation, where float64 and exact conventions matter more
than tracing. Numpy only, so that scoring a run loads nothing of the host.
"""

from __future__ import annotations

import numpy as np


def quat_to_rotation(q: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` as ``qx qy qz qw`` -> rotation matrices ``(..., 3, 3)``.

    The quaternion is normalised first, so a value rounded in a text file still gives an
    orthonormal matrix (to float64 rounding).
    """
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def rotation_to_quat(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> unit quaternions ``(..., 4)`` ``qx qy qz qw``, qw >= 0.

    Shepperd's method: each matrix uses the branch with the largest pivot, so no branch
    divides by a small number; the sign is fixed to ``qw >= 0`` so the result is unique
    (up to the two-sided ambiguity at exactly 180 degrees).
    """
    R = np.asarray(R, np.float64)
    shape = R.shape[:-2]
    M = R.reshape(-1, 3, 3)
    out = np.empty((M.shape[0], 4), np.float64)
    for k, m in enumerate(M):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        pivot = int(np.argmax([tr, m[0, 0], m[1, 1], m[2, 2]]))
        if pivot == 0:
            s = 2.0 * np.sqrt(max(1.0 + tr, 0.0))
            q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
        elif pivot == 1:
            s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
            q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
        elif pivot == 2:
            s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
            q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
        else:
            s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
            q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
        q = np.asarray(q)
        q /= np.linalg.norm(q)
        out[k] = -q if q[3] < 0 else q
    return out.reshape(*shape, 4)


def pose_from_tq(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Translations ``(..., 3)`` metres and quaternions ``(..., 4)`` -> poses ``(..., 4, 4)``."""
    t = np.asarray(t, np.float64)
    R = quat_to_rotation(q)
    T = np.zeros(t.shape[:-1] + (4, 4), np.float64)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid poses ``(..., 4, 4)``, using ``R^T`` rather than a general inverse."""
    T = np.asarray(T, np.float64)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def relative_pose(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """``inv(T_a) @ T_b`` for poses ``(..., 4, 4)``: ``T_b`` seen from ``T_a``."""
    return invert_pose(T_a) @ np.asarray(T_b, np.float64)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices ``(..., 3, 3)`` in radians, in ``[0, pi]``.

    ``atan2(|sin|, cos)`` from the skew and trace parts: unlike ``arccos`` of the trace it
    stays accurate for the tiny angles of frame-to-frame errors.
    """
    R = np.asarray(R, np.float64)
    skew = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]],
        axis=-1,
    )
    sin = 0.5 * np.linalg.norm(skew, axis=-1)
    cos = 0.5 * (R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2] - 1.0)
    return np.arctan2(sin, cos)
