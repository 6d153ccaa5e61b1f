"""Trajectories: timestamped camera poses, TUM trajectory files and association by time.

Both sides read them: the host writes a run's poses and reads a sequence's ground truth
(:mod:`jaxvo.host.readers.io`), the evaluation scores one trajectory against another
(:mod:`jaxvo.evaluation.metrics`). Numpy only, and nothing of the host: the lines of a
TUM file are made here (:func:`tum_header`, :func:`tum_lines`) and written by the host's
two writers, :func:`jaxvo.host.readers.io.write_trajectory` and
:class:`jaxvo.host.readers.io.TrajectoryWriter`, whole or not at all.

A frame's time as users hold it (seconds, nanoseconds, ``np.datetime64``, a ROS stamp) is
read here too (:func:`timestamp_seconds`).

TUM format: one line a pose, ``timestamp tx ty tz qx qy qz qw`` (seconds, metres, the
camera-to-world rotation's quaternion, scalar last); ``#`` starts a comment.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.transforms import pose_from_tq, rotation_to_quat


class Trajectory(NamedTuple):
    """Timestamped camera poses, camera-to-world (``T_w_c``), float64."""

    timestamps: np.ndarray  # (N,) seconds
    poses: np.ndarray  # (N, 4, 4)

    def __len__(self) -> int:
        return len(self.timestamps)


# Printed precision of write_trajectory: timestamps to the microsecond (as TUM files), metres
# and quaternion components to 1e-9 (well below any sensor's accuracy).
POSE_LINE = " ".join(["%.6f"] + ["%.9f"] * 7)  # timestamp tx ty tz qx qy qz qw
HEADER = "# timestamp tx ty tz qx qy qz qw"
# A quaternion whose norm is further than this from 1 is not a rotation that was merely
# rounded when printed: the file is wrong, and guessing would hide it.
QUAT_NORM_TOL = 1e-3


def read_text(path: Path) -> str:
    """A text file's contents; ``-`` reads standard input, and a pipe (``/dev/stdin``, a
    FIFO) is read as a file is."""
    import sys

    if str(path) == "-":  # standard input, as for other tools that read a file
        if sys.stdin is None or sys.stdin.isatty():
            raise InputError("-: standard input is a terminal or closed, not a trajectory "
                             "piped in (jaxvo run --out - | jaxvo eval ate gt.txt -)")
        return sys.stdin.read()
    if not path.exists():
        raise InputError(f"file not found: {path}")
    if path.is_dir():
        raise InputError(f"not a file: {path}")
    try:
        return path.read_text()
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None


def data_lines(path: Path, text: str | None = None) -> list[tuple[int, list[str]]]:
    """Non-empty, non-comment lines of a text file (or of ``text``, named ``path``), split
    on whitespace or commas."""
    out = []
    for lineno, raw in enumerate((read_text(path) if text is None else text).splitlines(),
                                 start=1):
        line = raw.split("#", 1)[0].replace(",", " ").strip()
        if line:
            out.append((lineno, line.split()))
    return out


def read_trajectory(path: str | Path, *, text: str | None = None) -> Trajectory:
    """Read a TUM trajectory file ``timestamp tx ty tz qx qy qz qw`` (``#`` comments);
    ``-`` reads it from standard input, ``text`` is the file's text (named ``path``).

    Poses are sorted by time. Raises :class:`InputError` (``file:line: ...``) for a line
    that is not eight numbers, a non-finite value, a quaternion whose norm is not 1 within
    :data:`QUAT_NORM_TOL`, a repeated timestamp, or a file with no poses.

    Args:
      path: the file.
    Returns:
      a :class:`Trajectory`, timestamps (N,) seconds, poses (N, 4, 4) ``T_w_c`` metres.
    """
    path = Path(path)
    rows, linenos = [], []
    for lineno, parts in data_lines(path, text):
        if len(parts) != 8:
            raise InputError(
                f"{path}:{lineno}: expected 8 values 'timestamp tx ty tz qx qy qz qw', "
                f"got {len(parts)}"
            )
        try:
            values = [float(p) for p in parts]
        except ValueError:
            bad = next(p for p in parts if not is_number(p))
            raise InputError(f"{path}:{lineno}: {bad!r} is not a number") from None
        if not all(np.isfinite(values)):
            raise InputError(f"{path}:{lineno}: non-finite value")
        norm = float(np.linalg.norm(values[4:]))
        if abs(norm - 1.0) > QUAT_NORM_TOL:
            raise InputError(
                f"{path}:{lineno}: quaternion qx qy qz qw has norm {norm:.6g}, not 1 "
                f"(tolerance {QUAT_NORM_TOL:g})"
            )
        rows.append(values)
        linenos.append(lineno)
    if not rows:
        raise InputError(f"{path}: empty trajectory (no pose lines)")
    data = np.asarray(rows, np.float64)
    order = np.argsort(data[:, 0], kind="stable")
    data = data[order]
    dup = np.flatnonzero(np.diff(data[:, 0]) == 0)
    if dup.size:
        lineno = linenos[order[dup[0] + 1]]
        raise InputError(f"{path}:{lineno}: repeated timestamp {data[dup[0], 0]:.6f}")
    return Trajectory(data[:, 0].copy(), pose_from_tq(data[:, 1:4], data[:, 4:8]))


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def tum_header(comment: str = "") -> str:
    """The first lines of a TUM trajectory file: ``comment``'s lines after ``# ``, then the
    column names; each line ends in a newline."""
    return "".join(f"# {line}\n" for line in comment.splitlines()) + HEADER + "\n"


def tum_lines(timestamps: np.ndarray, poses: np.ndarray) -> str:
    """Poses as TUM trajectory lines, each ending in a newline: timestamps ``%.6f`` s,
    translation and quaternion ``%.9f``.

    Reading them back gives timestamps within 5e-7 s, translations within 5e-10 m and
    rotations within about 1e-9 of the given ones (the printed precision).

    Args:
      timestamps: (N,) seconds.
      poses: (N, 4, 4) ``T_w_c``.
    """
    poses = np.asarray(poses, np.float64)
    stamps = np.asarray(timestamps, np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or stamps.shape != (len(poses),):
        raise ValueError(
            f"trajectory needs (N,) timestamps and (N, 4, 4) poses, got {stamps.shape} "
            f"and {poses.shape}"
        )
    q = rotation_to_quat(poses[:, :3, :3])
    return "".join(POSE_LINE % (t, *T[:3, 3], *qi) + "\n" for t, T, qi in zip(stamps, poses, q))


def pose_at(traj: Trajectory, t: float, *, max_diff: float = 0.02) -> np.ndarray | None:
    """The pose of ``traj`` nearest in time to ``t``, or None when none lies within ``max_diff``.

    Args:
      traj: timestamps (N,) seconds, poses (N, 4, 4).
      t: seconds.
      max_diff: largest time difference, seconds.
    Returns:
      (4, 4) float64, or None.
    """
    stamps = np.asarray(traj.timestamps, np.float64)
    if len(stamps) == 0:
        return None
    k = int(np.argmin(np.abs(stamps - t)))
    if abs(stamps[k] - t) > max_diff:
        return None
    return np.asarray(traj.poses[k], np.float64)


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


# A number of seconds at or above this is no time (3170 years); at or above NS_FROM it is
# nanoseconds, as ROS stamps and np.datetime64 count them (1e17 ns: 1973); between the two
# (milli- or microseconds) it is refused rather than guessed.
_MAX_SECONDS = 1e11
_NS_FROM = 1e17


def timestamp_seconds(timestamp) -> float:
    """Seconds from what users hold for a frame's time.

    Args:
      timestamp: a float or int of seconds; an int (or float) of nanoseconds, from 1e17 on
        (ROS's ``header.stamp`` as one number: ``1305031102175304000``); an
        ``np.datetime64`` (any unit; since the epoch) or ``np.timedelta64``; an object with
        ``sec`` and ``nanosec`` (ROS 2, rosbags) or ``secs`` and ``nsecs`` (ROS 1).
    Returns:
      seconds, float64.
    Raises:
      ValueError: anything else, a value that is not finite, or a number in between (1e11
        to 1e17: milli- or microseconds?), saying what is accepted.
    """
    accepted = ("timestamp must be seconds (a float), nanoseconds (an int from 1e17 on, as "
                "ROS stamps), an np.datetime64 or a ROS Time")
    if isinstance(timestamp, np.datetime64 | np.timedelta64):
        if np.isnat(timestamp):
            raise ValueError(f"{accepted}; got NaT")
        seconds = _datetime_seconds(timestamp)
        if abs(seconds) >= _MAX_SECONDS:
            raise ValueError(f"timestamp {timestamp} is {seconds:.3g} s from 1970, beyond any "
                             f"recording; {accepted}")
        return seconds
    for sec, nsec in (("sec", "nanosec"), ("secs", "nsecs")):
        if hasattr(timestamp, sec) and hasattr(timestamp, nsec):
            return int(getattr(timestamp, sec)) + int(getattr(timestamp, nsec)) * 1e-9
    if isinstance(timestamp, bool | str | bytes) or not isinstance(
            timestamp, int | float | np.integer | np.floating):
        raise ValueError(f"{accepted}; got {type(timestamp).__name__} {timestamp!r}")  # noqa: TRY004 (the API says ValueError for any bad input)
    if not np.isfinite(timestamp):
        raise ValueError(f"timestamp must be a finite number of seconds, got {timestamp}")
    if abs(timestamp) >= _NS_FROM:
        return int(timestamp) * 1e-9 if isinstance(timestamp, int | np.integer) else (
            float(timestamp) * 1e-9)
    if abs(timestamp) >= _MAX_SECONDS:
        raise ValueError(f"timestamp {timestamp} is neither seconds nor nanoseconds (milli- or "
                         f"microseconds?); {accepted}")
    return float(timestamp)


# seconds in one tick of each linear unit of np.datetime64 / np.timedelta64
_TICK_SECONDS = {"W": 604800.0, "D": 86400.0, "h": 3600.0, "m": 60.0, "s": 1.0, "ms": 1e-3,
                 "us": 1e-6, "ns": 1e-9, "ps": 1e-12, "fs": 1e-15, "as": 1e-18}


def _datetime_seconds(timestamp) -> float:
    """Seconds since the epoch of an ``np.datetime64`` (or in an ``np.timedelta64``), in its
    own unit: going through nanoseconds wrapped a date past 2262 to about 1830."""
    unit, count = np.datetime_data(timestamp.dtype)
    if unit in ("Y", "M"):  # years and months are not of one length: as days
        if isinstance(timestamp, np.timedelta64):
            raise ValueError(f"a time of {timestamp} has no fixed length in seconds")
        timestamp, unit, count = timestamp.astype("datetime64[D]"), "D", 1
    if unit not in _TICK_SECONDS:
        raise ValueError(f"timestamp {timestamp!r} has no unit of time")
    ticks = int(timestamp.astype(np.int64)) * count
    ns = ticks * round(_TICK_SECONDS[unit] * 1e9) if _TICK_SECONDS[unit] >= 1e-9 else None
    if ns is not None and abs(ns) < 2**63:  # as before for every date NumPy holds in ns
        return ns * 1e-9
    return ticks * _TICK_SECONDS[unit]
