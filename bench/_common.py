"""Helpers shared by the benchmarks: the machine description and in-memory sequences."""

from __future__ import annotations

import os
import platform
import resource
from pathlib import Path

import numpy as np

from jaxvo.io import Trajectory


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (the platform's processor string elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> list[float] | None:
    """1, 5 and 15 minute load averages (None where the OS does not report them)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def peak_rss_mib() -> float:
    """The process's peak resident set size so far (``ru_maxrss``, KiB on Linux), MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def machine() -> dict:
    """Platform, CPU, cores, library versions and JAX device of this run."""
    import cv2
    import jax

    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "jax": jax.__version__,
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "opencv": cv2.__version__,
        "numpy": np.__version__,
        "load_average_start": load_average(),
    }


class CachedSequence:
    """The first ``frames`` frames of a sequence, read (or rendered) once and kept in memory.

    jaxvo and every peer then read the same frames, and rendering a synthetic frame (about
    0.1 s) is paid once instead of once per method.
    """

    def __init__(self, seq, frames: int | None = None):
        n = len(seq) if frames is None else min(len(seq), int(frames))
        self.name = seq.name
        self.intrinsics = seq.intrinsics
        self.height, self.width = seq.height, seq.width
        self.timestamps = np.asarray(seq.timestamps[:n], np.float64)
        self._frames = [seq[i] for i in range(n)]
        gt = getattr(seq, "groundtruth", None)
        if gt is not None and len(gt) == len(seq):  # one pose per frame: keep the same ones
            gt = Trajectory(np.asarray(gt.timestamps[:n]), np.asarray(gt.poses[:n]))
        self.groundtruth = gt  # otherwise associated by timestamp, as the metrics do
        self.has_masks = self._frames[0].mask is not None

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int):
        return self._frames[index]

    def __iter__(self):
        return iter(self._frames)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return float(self.timestamps[-1] - self.timestamps[0]) if len(self) > 1 else 0.0
