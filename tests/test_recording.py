"""The Rerun recording of a run (`jaxvo.host.writers.recording`), read back with Rerun's own reader.

A few synthetic frames are run with ``jaxvo run --rerun-save``; the ``.rrd`` is read with
``rerun.chunk.RrdReader`` (rerun-sdk's reader, not our code): every entity is there, the
camera has one pose per frame, on the ``frame`` and ``time`` timelines, and the poses are
the trajectory file's. The tests that need rerun-sdk (the ``viz`` extra, also in ``test``)
skip, saying so, where it is absent; the one-line error for a missing extra runs always.
"""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from conftest import python_code

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.synth.scenes import make_sequence, write_sequence
from jaxvo.trajectory import read_trajectory

FRAMES = 5


def _rerun():
    return pytest.importorskip("rerun", reason="rerun-sdk (pip install 'jaxvo[viz]') is not "
                               "installed")


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "seq"
    write_sequence(make_sequence("handheld_fast", frames=FRAMES, seed=2), out)
    return out


def read_back(path):
    """``{entity: [pyarrow record batches]}`` of the recording's chunks, and the static
    entities, with Rerun's reader."""
    from rerun.chunk import RrdReader

    chunks, static = defaultdict(list), set()
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
        else:
            chunks[chunk.entity_path].append(chunk.to_record_batch().to_pydict())
    return chunks, static


def column(batches, name):
    return [v for b in batches for v in b[name]]


def test_recording_holds_every_entity_one_pose_per_frame_and_the_files_poses(
        seq_dir, tmp_path, capsys):
    _rerun()
    traj, rrd = tmp_path / "traj.txt", tmp_path / "run.rrd"
    assert main(["run", str(seq_dir), "--out", str(traj), "--rerun-save", str(rrd), "-q"]) == 0
    capsys.readouterr()
    chunks, static = read_back(rrd)
    for entity in ("/world/camera", "/world/camera/image/rgb", "/world/camera/image/depth",
                   "/world/camera/image/ids", "/world/points", "/world/trajectory",
                   "/stats"):
        assert entity in chunks, (entity, sorted(chunks))
    assert {"/world/camera/image", "/world/groundtruth", "/world", "/stats"} <= static
    # one row of the four numbers per frame pair: points used and moving cells in % of the
    # grid, ms per frame, skipped pairs so far
    stats = np.array(column(chunks["/stats"], "Scalars:scalars"), np.float64)
    assert stats.shape == (FRAMES - 1, 4)
    assert np.all((stats[:, :2] >= 0) & (stats[:, :2] <= 100)) and np.all(stats[:, 2] > 0)
    cam = chunks["/world/camera"]
    frames = column(cam, "frame")
    assert sorted(frames) == list(range(FRAMES))
    # one pair's labels per pair, on the image the pair starts at (frames 0 .. FRAMES - 2)
    assert sorted(column(chunks["/world/camera/image/ids"], "frame")) == list(range(FRAMES - 1))
    est = read_trajectory(traj)
    order = np.argsort(frames)
    t = np.array([v.value for v in column(cam, "time")], np.float64)[order] * 1e-9
    np.testing.assert_allclose(t, est.timestamps, atol=1e-6)  # ns timeline, s in the file
    trans = np.array([v[0] for v in column(cam, "Transform3D:translation")])[order]
    rot = np.array([v[0] for v in column(cam, "Transform3D:mat3x3")])[order]
    # the file writes 6 decimals of metres and of the quaternion; rerun keeps float32;
    # mat3x3 is stored column-major
    np.testing.assert_allclose(trans, est.poses[:, :3, 3], atol=2e-6)
    np.testing.assert_allclose(rot.reshape(-1, 3, 3).transpose(0, 2, 1), est.poses[:, :3, :3],
                               atol=1e-5)


def test_odometry_logs_through_an_attached_logger(tmp_path):
    _rerun()
    from jaxvo.host.writers.recording import RerunLogger
    from jaxvo.odometry import Odometry

    seq = make_sequence("handheld_fast", frames=3, seed=0)
    logger = RerunLogger(save=tmp_path / "odo.rrd")
    odo = Odometry(seq.intrinsics, logger=logger)
    for f in seq:
        odo.process(f.bgr, f.depth, f.timestamp)
    logger.close()
    chunks, _ = read_back(tmp_path / "odo.rrd")
    trans = np.array([v[0] for v in column(chunks["/world/camera"], "Transform3D:translation")])
    np.testing.assert_allclose(trans, np.asarray(odo.trajectory.poses)[:, :3, 3], atol=1e-6)


def test_a_missing_rerun_is_one_line_naming_the_extra(seq_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    from jaxvo.host.writers.recording import RerunLogger

    with pytest.raises(InputError, match=r"jaxvo\[viz\]"):
        RerunLogger(save=tmp_path / "x.rrd")
    rc = main(["run", str(seq_dir), "--out", str(tmp_path / "t.txt"), "--rerun-save",
               str(tmp_path / "x.rrd"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "pip install 'jaxvo[viz]'" in err[0], err
    assert not (tmp_path / "t.txt").exists()  # refused before any work


# --- nothing lost (issue 46) -----------------------------------------------------------------


_FAKE_RUN = """
import sys
from types import SimpleNamespace
import numpy as np
from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.host.writers.recording import RerunLogger

def frames(logger, n):
    logger.setup(Intrinsics(525.0, 525.0, 31.5, 23.5), 16)
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.01 * i
        r = SimpleNamespace(index=i, timestamp=i / 30, T_w_c=T, dropped=None, output=None)
        logger.log_frame(r, np.zeros((48, 64, 3), np.uint8), np.full((48, 64), 2.0, np.float32))
"""


def _camera_poses(path) -> int:
    chunks, _ = read_back(path)
    return len(column(chunks["/world/camera"], "frame"))


def test_a_logger_never_closed_keeps_every_pose(tmp_path):
    """docs/cli.md showed RerunLogger without close(): the recording held 5 of 6 poses."""
    _rerun()
    code = _FAKE_RUN + f"frames(RerunLogger(save={str(tmp_path / 'r.rrd')!r}), 6)\n"
    done = python_code(code)
    assert done.returncode == 0, done.stderr[-2000:]
    assert _camera_poses(tmp_path / "r.rrd") == 6
    assert [p.name for p in tmp_path.iterdir()] == ["r.rrd"]  # no temporary left


def test_the_with_form_writes_whole_or_leaves_the_earlier_file(tmp_path):
    _rerun()
    from jaxvo.host.writers.recording import RerunLogger

    namespace = {}
    exec(_FAKE_RUN, namespace)  # noqa: S102 (the helper above, shared with the child)
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"an earlier recording")
    with pytest.raises(ValueError, match="the run failed"), RerunLogger(save=rrd) as logger:
        namespace["frames"](logger, 3)
        raise ValueError("the run failed")
    assert rrd.read_bytes() == b"an earlier recording"
    with RerunLogger(save=rrd) as logger:  # Ctrl-C keeps what was recorded, whole
        namespace["frames"](logger, 3)
    assert _camera_poses(rrd) == 3 and sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd"]
    with pytest.warns(RuntimeWarning, match="frames after close"):
        namespace["frames"](logger, 1)  # RuntimeError: BackgroundWriter.submit after close


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_or_a_missing_folder_is_one_line_naming_the_file(tmp_path):
    """A full disk raised Rerun's 'File-writer thread shut down prematurely'; a missing
    folder Rerun's own RuntimeError."""
    _rerun()
    from jaxvo.host.writers.recording import RerunLogger

    with pytest.raises(OSError, match="No space left on device") as got:
        RerunLogger(save="/dev/full")
    assert got.value.filename == "/dev/full"
    with pytest.raises(InputError, match="save= .*/nonexistent/x.rrd: folder .* does not exist"):
        RerunLogger(save=tmp_path / "nonexistent" / "x.rrd")


def test_a_tmpfs_that_fills_mid_recording_names_the_file(tmp_path):
    """A disk that fills while Rerun writes (a 64 KiB tmpfs in a user namespace, where the
    kernel allows one): one OSError naming the file, the earlier recording kept."""
    _rerun()
    mount = tmp_path / "small"
    mount.mkdir()
    code = _FAKE_RUN + (
        "import errno, os\n"
        f"path = {str(mount / 'r.rrd')!r}\n"
        "open(path, 'wb').write(b'earlier')\n"
        "try:\n"
        "    with RerunLogger(save=path) as logger:\n"
        "        frames(logger, 40)\n"
        "except OSError as exc:\n"
        "    print(exc.errno == errno.ENOSPC, exc.filename == path, open(path, 'rb').read(),\n"
        "          sorted(os.listdir(os.path.dirname(path))))\n")
    script = tmp_path / "fill.py"
    script.write_text(code)
    shell = (f"mount -t tmpfs -o size=64k tmpfs {mount} && {sys.executable} {script}")
    done = subprocess.run(["unshare", "-rm", "sh", "-c", shell], capture_output=True,
                          text=True, timeout=120, check=False)
    if done.returncode != 0 and "mount" in done.stderr + done.stdout:
        pytest.skip(f"no tmpfs in a user namespace here: {done.stderr.strip()[:200]}")
    assert done.stdout.strip() == "True True b'earlier' ['r.rrd']", done.stderr[-2000:]


def test_a_recording_that_fails_mid_run_keeps_the_trajectory(seq_dir, tmp_path, capsys,
                                                             monkeypatch):
    """A recording that fails during the frames (its disk full) discarded the trajectory,
    on a disk that may be healthy, with it. Now the run stops at the next frame as after
    Ctrl-C: one line naming the recording, exit 2, the trajectory with the poses computed,
    the earlier recording as it was."""
    _rerun()
    from jaxvo.host.writers import recording

    traj, rrd = tmp_path / "t.txt", tmp_path / "r.rrd"
    rrd.write_bytes(b"an earlier recording")
    real = recording.RerunLogger._log_frame
    calls = {"n": 0}

    def log_frame(self, *args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError(28, "No space left on device", str(rrd))
        real(self, *args)

    monkeypatch.setattr(recording.RerunLogger, "_log_frame", log_frame)
    code = main(["run", str(seq_dir), "--out", str(traj), "--rerun-save", str(rrd), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and err == f"jaxvo: error: {rrd}: No space left on device\n", err
    assert 2 <= len(read_trajectory(traj)) <= FRAMES
    assert rrd.read_bytes() == b"an earlier recording"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.rrd", "t.txt"]


def test_a_disk_that_fills_at_the_end_of_the_recording_is_said_and_the_process_ends(
        tmp_path):
    """A disk that fills late in a recording (a 1200 KiB tmpfs in a user namespace, where
    the kernel allows one, under 5 frames of 1.9 MB) left Rerun's file writer stuck: close()
    raised the OSError naming the file, but the process then waited for ever, in
    RecordingStream.__del__ when the error was let go (``jaxvo run --rerun-save`` never
    printed it), and in Rerun's flush at exit. Now the error is said and the process ends."""
    import os

    _rerun()
    mount = tmp_path / "small"
    mount.mkdir()
    code = (
        "import sys\n"
        "from types import SimpleNamespace\n"
        "import numpy as np\n"
        "from jaxvo.host.frontend.camera import Intrinsics\n"
        "from jaxvo.host.writers.recording import RerunLogger\n"
        f"path = {str(mount / 'r.rrd')!r}\n"
        "rng = np.random.default_rng(0)\n"
        "def run():\n"
        "    with RerunLogger(save=path) as logger:\n"
        "        logger.setup(Intrinsics(525.0, 525.0, 319.5, 239.5), 16)\n"
        "        for i in range(5):\n"
        "            r = SimpleNamespace(index=i, timestamp=i / 30, T_w_c=np.eye(4),\n"
        "                                dropped=None, output=None)\n"
        "            logger.log_frame(r, rng.integers(0, 255, (480, 640, 3), np.uint8),\n"
        "                             rng.uniform(0.5, 4.0, (480, 640)).astype(np.float32))\n"
        "try:\n"
        "    run()\n"
        "except OSError as exc:\n"
        "    print(exc.errno, exc.filename == path, flush=True)\n"
        "print('ended', flush=True)\n")
    script = tmp_path / "fill.py"
    script.write_text(code)
    shell = f"mount -t tmpfs -o size=1200k tmpfs {mount} && exec {sys.executable} {script}"
    proc = subprocess.Popen(["unshare", "-rm", "sh", "-c", shell], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "RUST_LOG": "off"})
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"the process never ended (Rerun's file writer stuck): {out!r}")
    if proc.returncode != 0 and "mount" in err:
        pytest.skip(f"no tmpfs in a user namespace here: {err.strip()[:200]}")
    assert proc.returncode == 0 and out == "28 True\nended\n", (out, err[-2000:])


def test_loggers_that_are_no_loggers_and_a_viewer_that_cannot_start(tmp_path, monkeypatch):
    _rerun()
    from jaxvo.host.writers import recording
    from jaxvo.odometry import Odometry

    for bad in ("run.rrd", object()):  # AttributeError: ... no attribute 'setup'
        with pytest.raises(ValueError, match="logger must have setup"):
            Odometry((525.0, 525.0, 319.5, 239.5), logger=bad)
    monkeypatch.setenv("PATH", str(tmp_path))  # no viewer executable to find
    with pytest.raises(InputError, match="--rerun: the Rerun viewer cannot start"):
        recording.RerunLogger(spawn=True)
    # a viewer that starts but never listens (no display to open): 11 s of gRPC, then a
    # RuntimeError at the end of the run
    monkeypatch.setattr(recording, "VIEWER_WAIT", 0.5)
    monkeypatch.setattr(recording, "_VIEWER_PORT", _free_port())
    monkeypatch.setattr("rerun.RecordingStream.spawn", lambda self, **kw: None)
    with pytest.raises(InputError, match="did not start listening on port"):
        recording.RerunLogger(spawn=True)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sigterm_and_a_second_ctrl_c_leave_whole_files(seq_dir, tmp_path):
    """SIGTERM left a .rrd that `rerun rrd verify` rejects; two Ctrl-C an atexit traceback.
    Now SIGTERM stops the run at the next frame (exit 143) with the trajectory and the
    recording whole; after a second Ctrl-C (exit 130, at once) the trajectory is whole and
    the recording the earlier one, and nothing else is printed."""
    _rerun()
    long = _looped(seq_dir, tmp_path / "long", 60)  # long enough to be signalled mid-run
    for signals, status in (((signal.SIGTERM,), 143), ((signal.SIGINT, signal.SIGINT), 130)):
        out = tmp_path / str(status)
        out.mkdir()
        (out / "r.rrd").write_bytes(b"an earlier recording")
        proc = subprocess.Popen(
            [sys.executable, "-c", ("import sys; from jaxvo.cli.main import main; "
             "sys.exit(main())"), "run", str(long), "--out", str(out / "t.txt"),
             "--rerun-save", str(out / "r.rrd"), "-q"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_for_a_pose(out, proc)
        for sig in signals:
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == status, err[-2000:]
        assert "Traceback" not in err and "Exception ignored" not in err, err[-2000:]
        traj = read_trajectory(out / "t.txt")  # whole: every line a pose
        assert 1 <= len(traj) < 60
        if status == 143:
            assert _camera_poses(out / "r.rrd") >= len(traj) - 1
        else:
            assert (out / "r.rrd").read_bytes() == b"an earlier recording" or (
                _camera_poses(out / "r.rrd") >= 1)
        assert sorted(p.name for p in out.iterdir()) == ["r.rrd", "t.txt"]


def _looped(seq: Path, out: Path, frames: int) -> Path:
    """A sequence of ``frames`` frames at 30 Hz going round ``seq``'s images (no new image
    rendered or written: the lists name the same files again)."""
    rows = [ln.split() for ln in (seq / "associations.txt").read_text().splitlines()
            if ln and not ln.startswith("#")]
    out.mkdir()
    (out / "camera.txt").write_text((seq / "camera.txt").read_text())
    (out / "associations.txt").write_text("".join(
        f"{k / 30:.6f} {seq / rows[k % len(rows)][1]} {k / 30:.6f} "
        f"{seq / rows[k % len(rows)][3]}\n" for k in range(frames)))
    return out


def _wait_for_a_pose(folder: Path, proc, timeout: float = 120.0) -> None:
    """Until the run's temporary trajectory beside ``folder/t.txt`` holds a pose."""
    import time

    end = time.monotonic() + timeout
    while time.monotonic() < end and proc.poll() is None:
        for part in folder.glob(".t.txt.jaxvo-*"):
            with contextlib.suppress(OSError):
                if any(not ln.startswith("#") for ln in part.read_text().splitlines()):
                    return
        time.sleep(0.05)
    raise AssertionError(f"no pose written: {proc.poll()}")
