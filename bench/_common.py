"""Helpers shared by the benchmarks: the machine description and in-memory sequences."""

from __future__ import annotations

import os
import platform
import resource
import time
from pathlib import Path

import numpy as np

from jaxvo.host.readers.io import InMemorySequence, data_root

# The real sequences the benchmarks read from the data root (``$JAXVO_DATA``), when present.
SEVEN_SCENES = "7scenes_static_0000_0299"
TUM_WALKING = "tum_fr3_walking_halfsphere_50"
REAL_SEQUENCES = (TUM_WALKING, SEVEN_SCENES)


def with_groundtruth(seq: InMemorySequence, truth: Path, max_diff: float = 0.02) -> InMemorySequence:
    """``seq`` with the ground truth of its frames taken from the trajectory file ``truth``
    (for each frame the pose nearest in time, within ``max_diff`` seconds; frames without
    one are left out of it, as evo's association leaves them out), when the file is
    there: TUM's motion capture, kept apart from the clip's folder (the data root's
    ``ground_truth/``), which starts 0.12 s after the clip's first frame."""
    from jaxvo.trajectory import Trajectory, pose_at, read_trajectory

    if not truth.is_file():
        return seq
    gt = read_trajectory(truth)
    t = np.asarray(seq.timestamps, np.float64)
    poses = [pose_at(gt, float(x), max_diff=max_diff) for x in t]
    keep = [i for i, p in enumerate(poses) if p is not None]
    if keep:
        seq.groundtruth = Trajectory(t[keep], np.stack([poses[i] for i in keep]))
    return seq


def groundtruth(data: dict):
    """A cached case's ground truth (``gt_poses`` at ``gt_times``, or at every frame's
    timestamp), or None."""
    from jaxvo.trajectory import Trajectory

    if "gt_poses" not in data:
        return None
    return Trajectory(data.get("gt_times", data["timestamps"]), data["gt_poses"])


def first_pose(data: dict) -> np.ndarray:
    """Where a run over a cached case starts: the ground truth's pose of the first frame,
    where it has one (the trajectories then share a frame without alignment), else the
    identity."""
    times = data.get("gt_times", data["timestamps"])
    if "gt_poses" in data and abs(float(times[0]) - float(data["timestamps"][0])) < 1e-6:
        return data["gt_poses"][0]
    return np.eye(4)


def tum_walking_truth() -> Path:
    """TUM's ground truth of the walking clip under the data root."""
    return data_root() / "ground_truth" / f"{TUM_WALKING}.txt"


def real_present(names=REAL_SEQUENCES) -> list[str]:
    """Those of ``names`` found as TUM-layout folders under the data root."""
    return [n for n in names if (data_root() / n / "associations.txt").is_file()]


def data_name(path: str | Path) -> str:
    """How a report names a data path: relative to the data root when under it (a
    sequence's folder name), else its own name; never the machine's absolute path."""
    path = Path(path)
    try:
        return path.resolve().relative_to(data_root().resolve()).as_posix()
    except ValueError:
        return path.name


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


def machine_line() -> str:
    """:func:`machine` as one line for the benchmarks' printed headers."""
    m = machine()
    return (f"{m['platform']}; {m['cpu_model']}; {m['cores']} cores; python {m['python']}; "
            f"numpy {m['numpy']}; jax {m['jax']} ({', '.join(m['jax_devices'])}); "
            f"opencv {m['opencv']}; load average {m['load_average_start']}")


# The in-memory copy of a sequence moved into the package (jaxvo.host.readers.io.InMemorySequence).
CachedSequence = InMemorySequence


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A Markdown table of ``header`` and ``rows`` of cells already formatted."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def log(msg: str) -> None:
    """A progress line on standard output, with the time of day."""
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)
