"""What every RGB-D sequence reader shares (host side): the :class:`Frame`, index and size
checks, and the camera a caller gave or a sequence's name points to (timestamps are
associated by :func:`jaxvo.trajectory.associate`).

TUM folders (:mod:`jaxvo.host.readers.io`), ROS bags (:mod:`jaxvo.host.readers.rosbag`) and synthetic scenes
import it; it imports none of them, so no reader imports another.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import PRESETS, Intrinsics, preset, read_camera_file


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
    """The intrinsics a caller gave (an :class:`Intrinsics`, a preset name, or a camera file:
    a ``camera.txt`` or an OpenCV calibration YAML, :func:`~jaxvo.host.frontend.camera.read_camera_file`)
    and where they came from, in words; None when ``camera`` is None."""
    if isinstance(camera, Intrinsics):
        return camera, "given"
    if camera is None:
        return None
    if str(camera) not in PRESETS and Path(camera).is_file():  # a camera.txt, an OpenCV YAML
        return read_camera_file(camera), str(camera)
    try:
        return preset(camera), f"preset {camera}"
    except ValueError as exc:
        raise InputError(str(exc)) from None


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
