"""`jaxvo run` and `jaxvo demo` end to end on small synthetic sequences written to disk."""

import json

import cv2
import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.synth.scenes import make_sequence, write_sequence
from jaxvo.trajectory import read_trajectory


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "handheld"
    write_sequence(make_sequence("handheld_fast", frames=8, seed=1), out)
    return out


def test_run_writes_every_pose_masks_and_a_summary(seq_dir, tmp_path, capsys):
    traj = tmp_path / "traj.txt"
    dyn = tmp_path / "dyn"
    rc = main(["run", str(seq_dir), "--out", str(traj), "--dynamic-masks", str(dyn), "-q",
               "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0
    est = read_trajectory(traj)
    assert len(est) == 8 and summary["poses_written"] == 8
    assert np.all(np.isfinite(est.poses))
    # the folder has ground truth: the summary scores the run (metres, not NaN); measured
    # 0.087 mm on this sequence (2-core CPU), bounded at about 3x that
    assert 0.0 <= summary["ate_rmse_m"] < 0.0003
    # the background keeps identifier 1 throughout (the summary counts re-acquisitions)
    assert summary["background_reacquired"] == 0
    pngs = sorted(dyn.glob("*.png"))
    assert pngs and set(np.unique(cv2.imread(str(pngs[0]), cv2.IMREAD_UNCHANGED))) <= {0, 255}


@pytest.mark.slow
def test_run_with_keyframes_writes_every_pose_and_counts_the_keyframes(seq_dir, tmp_path,
                                                                       capsys):
    """`--keyframes`: the keyframe window runs end to end through the command; the summary
    counts the keyframes and the run is as precise as without (measured 0.09 mm)."""
    traj = tmp_path / "traj.txt"
    rc = main(["run", str(seq_dir), "--out", str(traj), "--keyframes", "-q", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and len(read_trajectory(traj)) == 8
    assert summary["keyframes"] >= 1
    assert 0.0 <= summary["ate_rmse_m"] < 0.0003


def test_a_fixed_camera_is_scored_without_alignment(tmp_path, capsys):
    """A camera that never moves defines no alignment: the summary scores the poses as they
    are (from the true first pose) instead of advising an option jaxvo run does not have."""
    folder = tmp_path / "fixed"
    write_sequence(make_sequence("fixed_camera_1", frames=6, seed=1), folder)
    rc = main(["run", str(folder), "--out", str(tmp_path / "t.txt"), "-q", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and "scores_not_computed" not in summary
    assert summary["ate_aligned"] is False
    assert 0.0 <= summary["ate_rmse_m"] < 0.001  # metres: the camera stays put


def test_run_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["run", str(tmp_path / "missing"), "--out", str(tmp_path / "t.txt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxvo: error:")


def test_one_frame_sequence_is_refused(tmp_path, capsys):
    one = tmp_path / "one"
    write_sequence(make_sequence("static", frames=1, seed=0), one)
    assert main(["run", str(one), "--out", str(tmp_path / "t.txt")]) == 2
    assert "at least 2" in capsys.readouterr().err


def test_wrong_depth_scale_is_reported(seq_dir, tmp_path, capsys):
    bad = tmp_path / "bad"
    bad.mkdir()
    for f in seq_dir.iterdir():
        if f.is_dir():
            (bad / f.name).symlink_to(f, target_is_directory=True)
        elif f.name == "camera.txt":
            (bad / f.name).write_text(f.read_text().replace("depth_scale 5000", "depth_scale 5"))
        else:
            (bad / f.name).write_text(f.read_text())
    assert main(["run", str(bad), "--out", str(tmp_path / "t.txt")]) == 2
    assert "depth scale looks wrong" in capsys.readouterr().err


def test_each_check_runs_once_a_run(seq_dir, tmp_path, capsys, monkeypatch):
    """The settings, the memory they need and the first frame's depth are checked once a
    run, before JAX loads (jaxvo.run.prepare_run, record_run); the odometry is told so
    and checks none of them again (each ran twice or three times)."""
    import jaxvo.config
    import jaxvo.host.readers.io
    import jaxvo.host.services.memory
    import jaxvo.odometry
    import jaxvo.run

    calls = {"check_config": 0, "check_memory": 0, "check_depth_scale": 0}

    def counted(name, real):
        def call(*args, **kwargs):
            calls[name] += 1
            return real(*args, **kwargs)
        return call

    # each check wherever it is imported from (the functions themselves, taken first)
    for name, home, users in (
            ("check_config", jaxvo.config, (jaxvo.config, jaxvo.run, jaxvo.odometry)),
            ("check_memory", jaxvo.host.services.memory, (jaxvo.host.services.memory, jaxvo.odometry)),
            ("check_depth_scale", jaxvo.host.readers.io, (jaxvo.host.readers.io, jaxvo.odometry))):
        check = counted(name, getattr(home, name))
        for module in users:
            monkeypatch.setattr(module, name, check)
    rc = main(["run", str(seq_dir), "--out", str(tmp_path / "t.txt"), "-q", "--json",
               "--frames", "3"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["poses_written"] == 3
    assert calls == {"check_config": 1, "check_memory": 1, "check_depth_scale": 1}


def test_demo_unknown_scenario_lists_the_valid_ones(capsys):
    assert main(["demo", "--scenario", "nope"]) == 2
    assert "fixed_camera_1" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [[], pytest.param(["--keyframes"], marks=pytest.mark.slow)])
def test_all_invalid_depth_skips_every_pair_with_its_reason(seq_dir, tmp_path, capsys, extra):
    blank = tmp_path / "blank"
    blank.mkdir()
    for f in seq_dir.iterdir():
        if f.name == "depth":
            (blank / "depth").mkdir()
            for png in f.iterdir():
                cv2.imwrite(str(blank / "depth" / png.name), np.zeros((480, 640), np.uint16))
        elif f.is_dir():
            (blank / f.name).symlink_to(f, target_is_directory=True)
        else:
            (blank / f.name).write_text(f.read_text())
    rc = main(["run", str(blank), "--out", str(tmp_path / "t.txt"), "-q", "--json", *extra])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 1  # ran, but no frame pair could be used
    assert summary["poses_written"] == 8  # every pose still written (carried)
    assert list(summary["skipped"]) == ["too few valid flow vectors (textureless, blurred or no depth)"]
    assert "scores_not_computed" in summary  # no NaN figure


def test_interrupted_run_keeps_every_pose_computed(seq_dir, tmp_path, capsys, monkeypatch):
    """Ctrl-C during the 6th frame: the five frames given to the (pipelined) odometry all
    reach the trajectory file, the one still in flight included; exit code 130."""
    from jaxvo.odometry import Odometry

    real_submit = Odometry.submit
    calls = {"n": 0}

    def submit(self, *a, **kw):
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt
        return real_submit(self, *a, **kw)

    monkeypatch.setattr(Odometry, "submit", submit)
    traj = tmp_path / "traj.txt"
    masks = tmp_path / "masks"
    (tmp_path / "map.ply").write_bytes(b"an earlier map")
    rc = main(["run", str(seq_dir), "--out", str(traj), "--masks", str(masks), "-q", "--json",
               "--map", str(tmp_path / "map.ply")])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 130 and summary["interrupted"]
    est = read_trajectory(traj)
    assert len(est) == 5 and summary["poses_written"] == 5
    assert len(list(masks.glob("*.png"))) == 4  # one label mask per frame pair
    # it said "frames 8 processed" for 5 poses, and nothing of the map it did not write
    assert summary["frames"] == 8 and summary["frames_processed"] == 6
    assert summary["map_not_written"] == ("the run was interrupted (an earlier "
                                          f"{tmp_path / 'map.ply'} is as it was)")
    assert (tmp_path / "map.ply").read_bytes() == b"an earlier map"


def test_an_image_that_cannot_be_written_mid_run_is_one_line_and_exit_2(
        seq_dir, tmp_path, capsys, monkeypatch):
    """Masks are written on a background thread: a write that fails there (a full disk)
    still ends the run with one line naming the file. The run stops at the next frame, as
    after Ctrl-C: the trajectory (on a disk that may be healthy) keeps the poses computed,
    where it was discarded with the masks, and the folder keeps the masks written whole
    before the failure."""
    import jaxvo.host.writers.outputs

    real_write = jaxvo.host.writers.outputs.write_image
    calls = {"n": 0}

    def write_image(path, image):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(28, "No space left on device", str(path))
        real_write(path, image)

    monkeypatch.setattr(jaxvo.host.writers.outputs, "write_image", write_image)
    traj = tmp_path / "traj.txt"
    traj.write_text("# an earlier run\n")
    rc = main(["run", str(seq_dir), "--out", str(traj), "--masks", str(tmp_path / "m"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith("jaxvo: error: ") and "No space left on device" in err[0]
    assert ".png" in err[0]
    # the run stops at the next frame after the failure, or at the end; no mask after the
    # failed one is written, and nothing is left half-written beside them
    assert 2 <= len(read_trajectory(traj)) <= 8  # the poses up to the failed mask's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m", "traj.txt"]
    assert len(list((tmp_path / "m").glob("*.png"))) == 2
    assert not list((tmp_path / "m").glob(".*"))


_COMPILING = {"on": False, "events": []}


def _note_compile(event: str, duration: float, **kwargs) -> None:
    if _COMPILING["on"] and event in ("/jax/core/compile/jaxpr_trace_duration",
                                      "/jax/core/compile/backend_compile_duration"):
        _COMPILING["events"].append(event)


def test_the_demos_timed_scan_compiles_nothing(capsys, monkeypatch):
    """The demo's 'second, already compiled run of the scan' was called with other argument
    types than run_sequence's and compiled again (1.71 s against 0.26 s), so its ms/frame
    was the compile's, not the steady state's."""
    import jax

    from jaxvo.cli import demo

    jax.monitoring.register_event_duration_secs_listener(_note_compile)  # cannot be removed
    timed = demo._timed_scan
    seconds = []

    def watched(*args, **kwargs):
        _COMPILING["on"] = True
        try:
            seconds.append(timed(*args, **kwargs))
            return seconds[-1]
        finally:
            _COMPILING["on"] = False

    monkeypatch.setattr(demo, "_timed_scan", watched)
    # 4 frames: the scan of examples/quickstart_synthetic.py in test_examples.py (3 pairs)
    assert main(["demo", "--frames", "4", "--peers", "none", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["methods"]["jaxvo"]
    assert len(seconds) == 1 and _COMPILING["events"] == []  # no trace, no compile
    assert row["ms_per_frame"] > 0


def test_sigterm_to_a_background_job_of_a_script_keeps_what_was_finished(seq_dir, tmp_path):
    """A shell without job control (a script's ``jaxvo run ... &``) starts the job with
    SIGINT ignored; jaxvo then took no signal at all, and the script's ``kill`` (SIGTERM)
    left no trajectory and no bag, only hidden temporary files. SIGTERM is taken on its
    own: the run stops after the current frame, exit 143, the trajectory and the bag whole
    with the frames computed, nothing beside them."""
    import signal
    import subprocess
    import sys

    AnyReader = pytest.importorskip("rosbags.highlevel").AnyReader
    from test_recording import _looped, _wait_for_a_pose

    from jaxvo.host.writers.bagout import ODOMETRY_TOPIC

    long = _looped(seq_dir, tmp_path / "long", 80)  # long enough to be signalled mid-run
    out = tmp_path / "out"
    out.mkdir()
    jaxvo = [sys.executable, "-c", "import sys; from jaxvo.cli.main import main; "
             "sys.exit(main())", "run", str(long), "--out", str(out / "t.txt"),
             "--out-bag", str(out / "bag"), "-q"]
    # SIGINT ignored, then jaxvo in the same process (as `sh -c '... &'` starts it); no
    # preexec_fn, which forks this multithreaded (JAX) process
    proc = subprocess.Popen(
        [sys.executable, "-c", "import os, signal, sys; signal.signal(signal.SIGINT, "
         "signal.SIG_IGN); os.execv(sys.executable, sys.argv[1:])", *jaxvo],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_a_pose(out, proc)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-2000:]
    assert "Traceback" not in err, err[-2000:]
    poses = len(read_trajectory(out / "t.txt"))
    assert 1 <= poses < 80
    with AnyReader([out / "bag"]) as reader:
        odometry = [c for c in reader.connections if c.topic == ODOMETRY_TOPIC]
        assert len(list(reader.messages(connections=odometry))) == poses
    assert sorted(p.name for p in out.iterdir()) == ["bag", "t.txt"]
