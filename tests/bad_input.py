"""What the bad-input tests share (tests/test_bad_input_*.py, one file a door): the small
synthetic sequence written once a module, a copy of it to break, the command run in-process,
and the checks of a one-line error and of a usable trajectory.

Every case is answered in one of two ways: a one-line ``jaxvo: error: ...`` that names the
file or option and what is wrong, with exit status 2 and no traceback; or it is handled,
with a warning or a count in the summary, and the result is usable (a finite trajectory
whose time goes forward, nothing computed lost). The Python API answers with a
``ValueError`` that says what is wrong.

The sequence is a small synthetic one written to disk once a module (6 frames of
``handheld_fast``); each case copies its text files and links or copies its images, then
breaks one thing. The runs of a process share one compile of the per-frame step (the same
settings everywhere).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.host.readers.io import InMemorySequence, open_sequence
from jaxvo.synth.scenes import make_sequence, write_sequence
from jaxvo.trajectory import read_trajectory

FRAMES = 6


class Result(NamedTuple):
    rc: int
    out: str
    err: list[str]  # stderr lines
    summary: dict | None  # the --json summary of `jaxvo run`, if one was printed


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("base") / "seq"
    write_sequence(make_sequence("handheld_fast", frames=FRAMES, seed=1), out)
    return out


@pytest.fixture(scope="module")
def base_seq(base):
    """The base sequence read once into memory (frames, intrinsics, ground truth)."""
    return InMemorySequence(open_sequence(base))


def copy_seq(base: Path, dst: Path, *, images: tuple[str, ...] = ()) -> Path:
    """The sequence's text files copied to ``dst``; the image folders in ``images`` copied
    too (to be changed), the others linked."""
    dst.mkdir(parents=True)
    for f in base.iterdir():
        if f.is_dir() and f.name in images:
            shutil.copytree(f, dst / f.name)
        elif f.is_dir():
            (dst / f.name).symlink_to(f, target_is_directory=True)
        else:
            shutil.copy(f, dst / f.name)
    return dst


def data_lines(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line and not line.startswith("#")]


def swap_lines(path: Path, i: int, j: int) -> None:
    lines = path.read_text().splitlines()
    data = [k for k, line in enumerate(lines) if line and not line.startswith("#")]
    lines[data[i]], lines[data[j]] = lines[data[j]], lines[data[i]]
    path.write_text("\n".join(lines) + "\n")


def repeat_line(path: Path, i: int) -> None:
    lines = path.read_text().splitlines()
    data = [k for k, line in enumerate(lines) if line and not line.startswith("#")]
    lines.insert(data[i] + 1, lines[data[i]])
    path.write_text("\n".join(lines) + "\n")


def cli(capsys, *args) -> Result:
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    summary = None
    if "--json" in args and cap.out.lstrip().startswith("{"):
        summary = json.loads(cap.out)
    return Result(rc, cap.out, [line for line in cap.err.splitlines() if line.strip()], summary)


def run_json(capsys, seq: Path, out: Path, *extra) -> Result:
    return cli(capsys, "run", seq, "--out", out, "-q", "--json", *extra)


def assert_one_line_error(res: Result, *needles: str) -> None:
    """Exit 2, one line ``jaxvo: error: ...`` holding every needle, no traceback."""
    assert res.rc == 2, res
    assert len(res.err) == 1 and res.err[0].startswith("jaxvo: error: "), res.err
    for needle in needles:
        assert needle in res.err[0], (needle, res.err[0])


def assert_usable_trajectory(path: Path, n: int) -> np.ndarray:
    """``n`` finite poses whose timestamps strictly increase (read_trajectory also refuses a
    repeated one); returns the timestamps."""
    traj = read_trajectory(path)
    assert len(traj) == n
    assert np.all(np.isfinite(traj.poses))
    assert np.all(np.diff(traj.timestamps) > 0)
    return traj.timestamps


@pytest.fixture
def unwritable(tmp_path) -> Path:
    """A folder this process cannot write into: a read-only temporary folder, or for root
    (who writes anywhere on a normal file system) sysfs, which refuses new files to all."""
    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        yield ro
        ro.chmod(0o700)
        return
    if not Path("/sys/kernel").is_dir():
        pytest.skip("running as root without /sys: no folder refuses writes")
    yield Path("/sys/kernel")


GOOD_CAMERA = "fx 525\nfy 525\ncx 319.5\ncy 239.5\n"
