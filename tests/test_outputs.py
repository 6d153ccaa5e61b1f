"""Outputs written whole or not at all, and never over an input (``jaxvo.host.writers.outputs``).

Every writer of jaxvo goes through :class:`OutputFile` (or :class:`OutputFolder`); each is
interrupted here mid-write (Ctrl-C, and a full disk: the handle raises after writing half
of what it was given) with an earlier file in place, which must stay as it was, with no
temporary file left. The checks before any work compare files by device and inode.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.host.writers import outputs
from jaxvo.host.writers.outputs import (
    STDOUT,
    OutputFile,
    OutputFolder,
    OutputWarning,
    abort_pending,
    check_outputs,
    output_file,
    output_folder,
    stream_target,
)


def leftovers(folder: Path) -> list[str]:
    """The temporary outputs left in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if ".jaxvo-" in p.name)


class _Cut:
    """A file handle that writes half of what it is first given, then raises ``error``."""

    def __init__(self, fh, error: BaseException):
        self._fh, self._error = fh, error

    def write(self, data):
        self._fh.write(data[: max(len(data) // 2, 1)])
        self._fh.flush()
        raise self._error

    def __getattr__(self, name):
        return getattr(self._fh, name)


@pytest.fixture(params=["ctrl-c", "full disk"])
def cut(request, monkeypatch):
    """Every OutputFile's handle cut short by Ctrl-C or by a full disk; yields the
    exception type the writer then raises."""
    error = (KeyboardInterrupt() if request.param == "ctrl-c"
             else OSError(errno.ENOSPC, "No space left on device"))
    real = outputs._open_fd
    monkeypatch.setattr(outputs, "_open_fd", lambda fd, text: _Cut(real(fd, text), error))
    return type(error)


def _evo_result():
    from jaxvo.evaluation.evo_results import ape_result
    from jaxvo.evaluation.metrics import ate
    from jaxvo.trajectory import Trajectory

    t = np.arange(5) / 30.0
    poses = np.tile(np.eye(4), (5, 1, 1))
    poses[:, 0, 3] = np.arange(5) * 0.01
    gt = Trajectory(t, poses)
    return ape_result(ate(gt, gt), ref_name="gt", est_name="est", align_line="(not aligned)")


def _writers():
    """(name, write(path)) of every file writer of jaxvo but the recording (Rerun writes its
    own file: tests/test_recording.py) and the trajectory writer of a run (Ctrl-C keeps
    its poses: tests/test_cli_run.py)."""
    from jaxvo.evaluation.evo_results import result_image, result_zip
    from jaxvo.host.frontend.camera import Intrinsics, write_camera_file
    from jaxvo.host.readers.io import write_image, write_trajectory
    from jaxvo.host.writers.mapping import PointMap, write_ply
    from jaxvo.host.writers.outputs import write_bytes
    from jaxvo.study.report import write_csv
    from jaxvo.trajectory import Trajectory

    traj = Trajectory(np.arange(3.0), np.tile(np.eye(4), (3, 1, 1)))
    cloud = PointMap(np.zeros((4, 3), np.float32), np.zeros((4, 3), np.uint8),
                     np.ones(4, np.int32))
    return [
        ("trajectory", "t.txt", lambda p: write_trajectory(p, traj)),
        ("mask or overlay", "m.png", lambda p: write_image(p, np.zeros((8, 8), np.uint8))),
        ("map", "map.ply", lambda p: write_ply(p, cloud)),
        ("study table", "results.csv", lambda p: write_csv(p, [{"a": 1}], ["a"])),
        ("camera", "camera.txt", lambda p: write_camera_file(p, Intrinsics(525, 525, 319.5,
                                                                           239.5))),
        ("evo zip", "ate.zip", lambda p: write_bytes(p, result_zip(_evo_result()))),
        ("evo plot", "ate.png", lambda p: write_bytes(p, result_image(p, _evo_result(),
                                                                      plot_mode="xy"))),
    ]


@pytest.mark.parametrize("name, file, write", _writers(), ids=[w[0] for w in _writers()])
def test_every_writer_interrupted_mid_file_leaves_the_earlier_file(tmp_path, cut, name, file,
                                                                   write):
    if name == "evo plot":
        pytest.importorskip("matplotlib")
    target = tmp_path / file
    target.write_bytes(b"an earlier output")
    with pytest.raises(cut) as got:
        write(target)
    assert target.read_bytes() == b"an earlier output", name
    assert leftovers(tmp_path) == [], name
    if cut is OSError:  # a full disk names the file (write() and close() name none)
        assert got.value.filename == str(target) and got.value.errno == errno.ENOSPC


def test_a_synthetic_sequence_folder_interrupted_is_not_there(tmp_path, cut):
    from jaxvo.synth.scenes import make_sequence, write_sequence

    with pytest.raises(cut):
        write_sequence(make_sequence("static", frames=2, seed=0), tmp_path / "seq")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_output_file_replaces_the_target_only_when_whole(tmp_path):
    target = tmp_path / "t.txt"
    target.write_text("old\n")
    with OutputFile(target, text=True) as fh:
        fh.write("new\n")
        fh.flush()
        assert target.read_text() == "old\n" and len(leftovers(tmp_path)) == 1
    assert target.read_text() == "new\n" and leftovers(tmp_path) == []


def test_a_link_is_followed_and_a_device_written_as_the_stream_it_is(tmp_path):
    real = tmp_path / "real.txt"
    real.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(real)
    with OutputFile(link, text=True) as fh:
        fh.write("new")
    assert link.is_symlink() and real.read_text() == "new"
    with OutputFile(os.devnull) as fh:  # no temporary file in /dev, no rename over it
        fh.write(b"x")
    assert not Path(os.devnull).is_file()


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_device_names_itself():
    with pytest.raises(OSError, match="No space left") as got, OutputFile("/dev/full") as fh:
        fh.write(b"x" * 100_000)
    assert got.value.filename == "/dev/full"


def test_an_abrupt_end_keeps_what_is_whole_at_every_flush(tmp_path):
    """A second Ctrl-C cannot wait for the writers: the trajectory (whole at every pose) is
    put in place as flushed, a half-written image is not."""
    traj = OutputFile(tmp_path / "t.txt", text=True, keep_on_abort=True)
    traj.write("0.0 0 0 0 0 0 0 1\n")
    traj.flush()
    image = OutputFile(tmp_path / "m.png")
    image.write(b"half a PNG")
    abort_pending()
    assert (tmp_path / "t.txt").read_text() == "0.0 0 0 0 0 0 0 1\n"
    assert not (tmp_path / "m.png").exists() and leftovers(tmp_path) == []


def test_a_folder_appears_whole_or_not_at_all(tmp_path):
    with OutputFolder(tmp_path / "seq") as folder:
        (folder.temporary / "rgb.txt").write_text("x")
        assert not (tmp_path / "seq").exists()
    assert (tmp_path / "seq" / "rgb.txt").read_text() == "x" and leftovers(tmp_path) == []
    with pytest.raises(InputError, match="not an empty folder"):
        OutputFolder(tmp_path / "seq")


def test_a_folder_a_library_makes_takes_an_empty_target_and_leaves_nothing_beside(tmp_path):
    """make_folder=False: the library makes the folder at the temporary path (rosbags'
    writer refuses one that exists), named as the target inside a hidden holder; a target
    made empty beforehand (by a script) is taken; a discard before the library made
    anything leaves nothing either."""
    target = tmp_path / "bag"
    target.mkdir()
    with OutputFolder(target, make_folder=False) as folder:
        # the target's own name (a library may name its files after the folder), hidden
        assert not folder.temporary.exists() and folder.temporary.name == "bag"
        assert folder.temporary.parent.parent == tmp_path
        folder.temporary.mkdir()  # as rosbags' Writer.open does
        (folder.temporary / "metadata.yaml").write_text("x")
    assert (target / "metadata.yaml").read_text() == "x" and leftovers(tmp_path) == []
    OutputFolder(tmp_path / "other", make_folder=False).discard()
    assert not (tmp_path / "other").exists() and leftovers(tmp_path) == []


def test_another_writer_is_said_and_a_killed_ones_leftover_removed(tmp_path):
    """Two runs into one --out: each writes it whole, the last one kept, and the second is
    told; a temporary a killed run left (its process gone) is removed."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead = tmp_path / f".t.txt.jaxvo-{int(done.stdout)}-00000000.part"
    live = tmp_path / f".t.txt.jaxvo-{os.getppid()}-00000000.part"
    dead.write_text("cut")
    live.write_text("being written")
    with pytest.warns(OutputWarning, match="another jaxvo .* is writing it now"):
        output_file(tmp_path / "t.txt", what="--out")
    assert live.exists() and not dead.exists()


def test_inputs_are_compared_by_device_and_inode(tmp_path):
    """A hard link to the ground truth is the ground truth (only symbolic links were
    caught); every file of a protected folder is protected, read this run or not."""
    seq = tmp_path / "seq"
    (seq / "rgb").mkdir(parents=True)
    gt = seq / "groundtruth.txt"
    gt.write_text("0 0 0 0 0 0 0 1\n")
    (seq / "rgb" / "3.png").write_bytes(b"a frame this run does not read")
    os.link(gt, tmp_path / "hard.txt")
    with pytest.raises(InputError, match="would overwrite the input .*groundtruth.txt"):
        check_outputs([gt], files={"--out": tmp_path / "hard.txt"})
    with pytest.raises(InputError, match="would overwrite a file of the input folder"):
        check_outputs([gt, seq / "rgb"], files={"--map": seq / "rgb" / "3.png"})
    with pytest.raises(InputError, match="holds"):
        check_outputs([gt, seq / "rgb"], folders={"--masks": seq / "rgb"})
    check_outputs([gt, seq / "rgb"], files={"--out": seq / "traj.txt"},
                  folders={"--masks": seq / "masks"})  # new names beside the inputs: fine


def test_standard_output_named_as_a_file_is_standard_output(capfd):
    """``--out /dev/stdout > f`` wrote the trajectory, then the summary over it."""
    assert stream_target("/dev/stdout", what="--out", stdout=True) == STDOUT
    assert stream_target("-", what="--out", stdout=True) == STDOUT
    for path, needle in (("/dev/stdout", "standard output, where its summary goes"),
                         ("/dev/stderr", "standard error, where its messages go"),
                         ("-", "--map writes a file, not standard output")):
        with pytest.raises(InputError, match=needle):
            stream_target(path, what="--map")


def test_a_folder_of_an_earlier_run_is_said(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "9.000000.png").write_bytes(b"")
    with pytest.warns(OutputWarning, match="holds 1 file.* this run does not write"):
        output_folder(tmp_path / "m", what="--masks", names={"0.000000.png"})


def test_a_named_pipe_nobody_reads_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="a named pipe that no process reads"):
        output_file(fifo, what="--out")


def test_a_closed_pipe_while_help_prints_ends_quietly():
    """``jaxvo run --help | head -1`` as the shell runs it: the reader gone before the help
    is written."""
    read, write = os.pipe()
    os.close(read)
    done = subprocess.run([sys.executable, "-m", "jaxvo.cli.main", "run", "--help"],
                          stdout=write, stderr=subprocess.PIPE, text=True, timeout=60,
                          check=False)
    os.close(write)
    # argparse drops its own write error (0); jaxvo's flush after it finds the pipe (141)
    assert done.returncode in (0, 141) and done.stderr == "", done.stderr[-2000:]
