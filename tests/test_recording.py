"""The Rerun recording of a run (`jaxvo.host.recording`), read back with Rerun's own reader.

A few synthetic frames are run with ``jaxvo run --rerun-save``; the ``.rrd`` is read with
``rerun.chunk.RrdReader`` (rerun-sdk's reader, not our code): every entity is there, the
camera has one pose per frame, on the ``frame`` and ``time`` timelines, and the poses are
the trajectory file's. The tests that need rerun-sdk (the ``viz`` extra, also in ``test``)
skip, saying so, where it is absent; the one-line error for a missing extra runs always.
"""

from __future__ import annotations

import sys
from collections import defaultdict

import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.host.io import read_trajectory
from jaxvo.synth.scenes import make_sequence, write_sequence

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
    from jaxvo.host.recording import RerunLogger
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
    from jaxvo.host.recording import RerunLogger

    with pytest.raises(InputError, match=r"jaxvo\[viz\]"):
        RerunLogger(save=tmp_path / "x.rrd")
    rc = main(["run", str(seq_dir), "--out", str(tmp_path / "t.txt"), "--rerun-save",
               str(tmp_path / "x.rrd"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "pip install 'jaxvo[viz]'" in err[0], err
    assert not (tmp_path / "t.txt").exists()  # refused before any work
