"""What every RGB-D sequence reader shares (host side): the :class:`Frame`, index and size
checks, timestamp association, and the camera a caller gave or a sequence's name points to.

TUM folders (:mod:`jaxvo.host.io`), ROS bags (:mod:`jaxvo.host.rosbag`) and synthetic scenes
import it; it imports none of them, so no reader imports another.
"""

from __future__ import annotations

import re
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.camera import Intrinsics, preset


class Frame(NamedTuple):
    """One RGB-D frame on the host."""

    index: int
    timestamp: float  # seconds
    bgr: np.ndarray  # (H, W, 3) uint8, OpenCV channel order
    depth: np.ndarray  # (H, W) float32 metres, 0 = no reading
    mask: np.ndarray | None = None  # (H, W) uint8 moving-object id, 0 = static (synthetic only)


def frame_index(index: int, n: int) -> int:
    """``index`` into a sequence of ``n`` frames as 0 .. n-1 (negative counts from the end).

    Raises:
      IndexError: out of range.
    """
    if not -n <= index < n:
        raise IndexError(f"frame {index} out of range for {n} frames")
    return int(index) % n


def check_frame_size(where: str, image: np.ndarray, height: int, width: int) -> None:
    """Raise :class:`InputError` when ``image`` (H, W, ...) is not the sequence's size."""
    if image.shape[:2] != (height, width):
        raise InputError(f"{where}: image is {image.shape[1]}x{image.shape[0]}, the sequence "
                         f"is {width}x{height}")


def given_camera(camera) -> tuple[Intrinsics, str] | None:
    """The intrinsics a caller gave (an :class:`Intrinsics`, or a preset name) and where they
    came from, in words; None when ``camera`` is None."""
    if isinstance(camera, Intrinsics):
        return camera, "given"
    if camera is None:
        return None
    try:
        return preset(camera), f"preset {camera}"
    except ValueError as exc:
        raise InputError(str(exc)) from None


def associate(
    t_a: np.ndarray,
    t_b: np.ndarray,
    max_diff: float,
    *,
    names: tuple[str, str] = ("first", "second"),
) -> tuple[np.ndarray, np.ndarray]:
    """Pair timestamps of two lists by nearest time, one-to-one (TUM ``associate.py``).

    Every pair of stamps closer than ``max_diff`` is a candidate; candidates are taken in
    order of increasing time difference, skipping any whose stamp is already used. Where
    the stamps of each list are further apart than ``2 * max_diff`` this is the same as
    evo's nearest-neighbour association.

    Args:
      t_a: (N,) seconds.
      t_b: (M,) seconds.
      max_diff: largest accepted time difference, seconds.
      names: what to call the two lists in the error message (e.g. the file names).
    Returns:
      ``(idx_a, idx_b)``, int arrays of equal length, sorted by ``t_a``.
    Raises:
      InputError: no pair matches; the message gives both time ranges.
    """
    t_a = np.asarray(t_a, np.float64)
    t_b = np.asarray(t_b, np.float64)
    if max_diff < 0:
        raise InputError(f"max time difference must be >= 0 s, got {max_diff}")
    order_b = np.argsort(t_b, kind="stable")
    sb = t_b[order_b]
    lo = np.searchsorted(sb, t_a - max_diff, side="left")
    hi = np.searchsorted(sb, t_a + max_diff, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(len(t_a)), counts)
    starts = np.repeat(lo - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts)
    ib = order_b[np.arange(len(ia)) + starts] if len(ia) else np.zeros(0, np.int64)
    diff = np.abs(t_a[ia] - t_b[ib])
    keep = diff <= max_diff
    ia, ib, diff = ia[keep], ib[keep], diff[keep]
    used_a = np.zeros(len(t_a), bool)
    used_b = np.zeros(len(t_b), bool)
    pairs = []
    for k in np.lexsort((ib, ia, diff)):
        a, b = ia[k], ib[k]
        if not used_a[a] and not used_b[b]:
            used_a[a] = used_b[b] = True
            pairs.append((a, b))
    if not pairs:
        raise InputError(
            f"no timestamps match within {max_diff:g} s: {names[0]} spans "
            f"{_time_range(t_a)}, {names[1]} spans {_time_range(t_b)}"
        )
    pairs.sort()
    out = np.asarray(pairs, np.int64)
    return out[:, 0], out[:, 1]


def _time_range(t: np.ndarray) -> str:
    if len(t) == 0:
        return "nothing (0 stamps)"
    return f"{t.min():.6f} .. {t.max():.6f} s ({len(t)} stamps)"


def preset_from_name(name: str) -> str | None:
    """The calibration a folder's name points to, as the benchmarks name their downloads:
    TUM RGB-D (``rgbd_dataset_freiburg3_walking_xyz``, or short ``fr3_walking_xyz``) and
    Bonn RGB-D Dynamic (``rgbd_bonn_balloon``); ``None`` if the name names neither."""
    low = name.lower()
    if re.search(r"(?:^|[^a-z0-9])bonn(?:[^a-z0-9]|$)", low):
        return "bonn"
    m = re.search(r"freiburg([123])|(?:^|[^a-z0-9])fr([123])(?:[^0-9]|$)", low)
    return None if m is None else f"tum_fr{m.group(1) or m.group(2)}"


def describe(K: Intrinsics) -> str:
    """The intrinsics in one line, for messages."""
    return f"fx {K.fx:g} fy {K.fy:g} cx {K.cx:g} cy {K.cy:g} depth_scale {K.depth_scale:g}"
