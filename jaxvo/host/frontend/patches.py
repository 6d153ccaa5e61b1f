"""The checks a tracked point passes on the host, shared by the pair tracker
(:class:`jaxvo.host.frontend.flow.GridFlowTracker`) and the keyframe tracker
(:class:`jaxvo.host.frontend.keyframes.KeyframeTracker`): LK converged inside the image, and the
patches around both ends look alike (thesis section 2.2's similarity check).

Host only: numpy and OpenCV, never traced.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np


@functools.cache
def _patch_offsets(side: int) -> tuple[np.ndarray, np.ndarray]:
    """The (side * side,) x and y offsets of a patch's pixels from its centre, made once per
    side (read-only): a pair's checks sample patches two to five times."""
    r = (side - 1) / 2.0
    o = np.arange(side, dtype=np.float32) - np.float32(r)
    oy, ox = np.meshgrid(o, o, indexing="ij")
    ox, oy = ox.ravel(), oy.ravel()
    ox.flags.writeable = oy.flags.writeable = False
    return ox, oy


def sample_patches(grey: np.ndarray, uv: np.ndarray, side: int) -> np.ndarray:
    """Bilinear ``side`` x ``side`` patches centred on ``uv`` (n, 2), one ``cv2.remap``.

    Returns:
        (n, side * side) float32 grey values (borders replicated).
    """
    if len(uv) == 0:
        return np.zeros((0, side * side), np.float32)  # cv2.remap rejects empty maps
    ox, oy = _patch_offsets(side)
    map_x = np.add(uv[:, 0:1], ox, dtype=np.float32)
    map_y = np.add(uv[:, 1:2], oy, dtype=np.float32)
    src = grey if grey.dtype == np.float32 else grey.astype(np.float32)
    return cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def patch_correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Correlation coefficient of matching rows of (n, m) patches; 0 for a flat patch."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    num = np.einsum("ij,ij->i", a, b)
    den2 = np.einsum("ij,ij->i", a, a) * np.einsum("ij,ij->i", b, b)
    # A flat patch (std < ~0.1 grey level) carries no evidence: similarity 0, never NaN.
    flat = den2 <= np.float32(1e-2) ** 2 * a.shape[1] ** 2
    return np.where(flat, 0.0, num / np.sqrt(np.where(flat, 1.0, den2))).astype(np.float32)


def similar(grey_a: np.ndarray, uv_a: np.ndarray, grey_b: np.ndarray, uv_b: np.ndarray, *,
            side: int, least: float) -> np.ndarray:
    """(m,) bool: the ``side``-pixel patches at ``uv_a`` (m, 2) in ``grey_a`` and at ``uv_b``
    in ``grey_b`` (float32 images) correlate by at least ``least``."""
    return patch_correlation(sample_patches(grey_a, uv_a, side),
                             sample_patches(grey_b, uv_b, side)) >= least


def lk_converged(found: np.ndarray, status: np.ndarray, *, width: int, height: int) -> np.ndarray:
    """(m,) bool: LK's ``status`` (m, 1) says converged and ``found`` (m, 2) is a finite
    position inside the ``width`` x ``height`` image."""
    return ((status[:, 0] == 1) & np.isfinite(found).all(axis=1)
            & (found[:, 0] >= 0) & (found[:, 1] >= 0)
            & (found[:, 0] <= width - 1) & (found[:, 1] <= height - 1))
