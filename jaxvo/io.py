"""Reading and writing RGB-D sequences and trajectories in the TUM RGB-D formats (host side)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np


def data_root() -> Path:
    """Where the real sequences live: ``$JAXVO_DATA``, else ``../shared/data`` beside the repo."""
    env = os.environ.get("JAXVO_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent.parent / "shared" / "data"


class Frame(NamedTuple):
    """One RGB-D frame on the host."""

    index: int
    timestamp: float  # seconds
    bgr: np.ndarray  # (H, W, 3) uint8, OpenCV channel order
    depth: np.ndarray  # (H, W) float32 metres, 0 = no reading
    mask: np.ndarray | None = None  # (H, W) uint8 moving-object id, 0 = static (synthetic only)


class Trajectory(NamedTuple):
    """Timestamped camera poses, camera-to-world (``T_w_c``), float64."""

    timestamps: np.ndarray  # (N,) seconds
    poses: np.ndarray  # (N, 4, 4)

    def __len__(self) -> int:
        return len(self.timestamps)
