"""`jaxvo map` and `jaxvo run --map` end to end on a small synthetic sequence on disk."""

import json

import cv2
import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.synth.scenes import make_sequence, write_sequence


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A sequence, and jaxvo run over it with --dynamic-masks and --map."""
    d = tmp_path_factory.mktemp("map")
    write_sequence(make_sequence("fixed_camera_1", frames=6, seed=3), d / "seq")
    rc = main(["run", str(d / "seq"), "--out", str(d / "traj.txt"), "--dynamic-masks",
               str(d / "dyn"), "--map", str(d / "run_map.ply"), "-q", "--json"])
    assert rc == 0
    return d


def _ply_points(path) -> int:
    head = path.read_bytes().split(b"end_header\n", 1)[0].decode()
    return int(next(line.split()[2] for line in head.splitlines()
                    if line.startswith("element vertex")))


def test_map_writes_both_maps_and_the_picture_as_run_does(run_dir, capsys):
    capsys.readouterr()
    d = run_dir
    rc = main(["map", str(d / "seq"), "--traj", str(d / "traj.txt"), "--dynamic-masks",
               str(d / "dyn"), "--out", str(d / "m.ply"), "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["frames_fused"] == 6 and summary["frames_without_mask"] == 0
    assert _ply_points(d / "m.ply") == summary["map_points"] > 0
    assert _ply_points(d / "m_all.ply") == summary["map_all_points"] > summary["map_points"]
    assert (d / "m.png").stat().st_size > 0
    # the run's in-memory masks are the ones it wrote: the same maps, byte for byte
    assert (d / "m.ply").read_bytes() == (d / "run_map.ply").read_bytes()
    assert (d / "m_all.ply").read_bytes() == (d / "run_map_all.ply").read_bytes()


def test_map_without_masks_writes_the_full_map_only(run_dir, capsys):
    capsys.readouterr()
    d = run_dir
    assert main(["map", str(d / "seq"), "--traj", str(d / "traj.txt"), "--out",
                 str(d / "plain.ply")]) == 0
    assert "plain.ply" in capsys.readouterr().out
    assert not (d / "plain_all.ply").exists()
    assert (d / "plain.ply").read_bytes() == (d / "run_map_all.ply").read_bytes()
    assert (d / "plain.png").is_file()


# --- what a user trips on (issue 46) ---------------------------------------------------------


def _map(capsys, d, *args):
    """``jaxvo map`` over the run's sequence: (exit status, stdout, stderr lines)."""
    capsys.readouterr()
    rc = main(["map", str(d / "seq"), *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, [ln for ln in cap.err.splitlines() if ln.strip()]


def _one_line(rc, err, *needles):
    assert rc == 2 and len(err) == 1 and err[0].startswith("jaxvo: error: "), err
    for needle in needles:
        assert needle in err[0], (needle, err[0])


def test_map_reads_the_depth_as_the_run_did(run_dir, capsys):
    """jaxvo run --depth-scale 1000, then jaxvo map: the map was 5x too small. The run's
    trajectory names its camera; the map reads the depth that way, as the option would."""
    from jaxvo.run import RUN_TAG

    d = run_dir
    text = (d / "traj.txt").read_text()
    assert RUN_TAG + "{" in text and '"depth_scale": 5000.0' in text
    (d / "t1000.txt").write_text(text.replace('"depth_scale": 5000.0', '"depth_scale": 1000.0'))
    far = ("--max-depth", "20")  # the depth read at 1000 per metre is 5 times as far
    rc, out, err = _map(capsys, d, "--traj", d / "t1000.txt", "--out", d / "h.ply", "--json",
                        *far)
    assert rc == 0 and err == [], err
    assert json.loads(out)["camera"].startswith("as jaxvo run read it")
    rc, _, _ = _map(capsys, d, "--traj", d / "traj.txt", "--out", d / "o.ply",
                    "--depth-scale", "1000", *far)
    assert rc == 0 and (d / "h.ply").read_bytes() == (d / "o.ply").read_bytes()
    # an option that differs from the run's is said
    rc, out, err = _map(capsys, d, "--traj", d / "t1000.txt", "--out", d / "w.ply",
                        "--depth-scale", "5000", *far)
    assert rc == 0 and len(err) == 1 and "differs from the one jaxvo run read" in err[0], err


def test_a_run_of_another_sequence_is_refused_and_a_foreign_motion_warned(run_dir, capsys,
                                                                           tmp_path):
    """Both sequences timed index / 30 from 0: the timestamps matched, and a map came out
    with no word."""
    from jaxvo.host.readers.io import open_sequence, write_trajectory
    from jaxvo.run import run_header
    from jaxvo.trajectory import Trajectory

    d = run_dir
    other = open_sequence(d / "seq")
    other.name, other.frames_listed = "walking_xyz", 827
    poses = np.tile(np.eye(4), (6, 1, 1))
    stamps = np.asarray(other.timestamps, np.float64)
    write_trajectory(tmp_path / "o.txt", Trajectory(stamps, poses),
                     comment=run_header("walking_xyz", other))
    rc, _, err = _map(capsys, d, "--traj", tmp_path / "o.txt", "--out", tmp_path / "m.ply")
    _one_line(rc, err, "jaxvo run wrote it over the sequence 'walking_xyz'")
    assert not (tmp_path / "m.ply").exists()
    # another tool's trajectory moving 0.3 m a frame over a camera that stands still
    poses[:, 0, 3] = 0.3 * np.arange(6)
    write_trajectory(tmp_path / "f.txt", Trajectory(stamps, poses))
    rc, _, err = _map(capsys, d, "--traj", tmp_path / "f.txt", "--out", tmp_path / "f.ply")
    assert rc == 0 and len(err) == 1 and "fits the depth worse than no motion" in err[0], err
    # a ground truth at 3x the frame rate: two poses on one frame
    fast = Trajectory(np.arange(16) / 90.0, np.tile(np.eye(4), (16, 1, 1)))
    write_trajectory(tmp_path / "g.txt", fast)
    rc, _, err = _map(capsys, d, "--traj", tmp_path / "g.txt", "--out", tmp_path / "g.ply",
                      "--max-diff", "0.02")
    _one_line(rc, err, "fall on a frame another pose already has")


def test_masks_grow_and_outputs_that_no_map_can_use(run_dir, capsys, tmp_path):
    d = run_dir
    small = tmp_path / "small"
    small.mkdir()
    for f in (d / "dyn").iterdir():  # 320x240 masks for 640x480 frames: IndexError
        cv2.imwrite(str(small / f.name), cv2.resize(cv2.imread(str(f)), (320, 240)))
    rc, _, err = _map(capsys, d, "--traj", d / "traj.txt", "--dynamic-masks", small, "--out",
                      tmp_path / "m.ply")
    _one_line(rc, err, "the mask is 320x240, the frames 640x480")
    rc, _, err = _map(capsys, d, "--traj", d / "traj.txt", "--dynamic-masks", d / "dyn",
                      "--out", tmp_path / "m.ply", "--grow", "100000")  # 37 GiB before
    _one_line(rc, err, "--grow 100000 is wider than the 640x480 frames")
    for option, value, needle in (("--out", "-", "--out writes a file, not standard output"),
                                  ("--rerun-save", "-", "--rerun-save writes a file"),
                                  ("--voxel", "0", "--voxel must be a number of metres above")):
        args = ["--traj", d / "traj.txt", "--out", tmp_path / "m.ply", option, value]
        _one_line(*_map(capsys, d, *args)[::2], needle)
    assert not (d / "-").exists() and not list(tmp_path.glob("m*"))


def test_the_summary_says_what_was_left_out_and_the_camera_warning(run_dir, capsys, tmp_path):
    d = run_dir
    rc, out, err = _map(capsys, d, "--traj", d / "traj.txt", "--out", tmp_path / "p.ply",
                        "--camera", "tum_fr1")
    assert rc == 0 and "(nothing left out: no --dynamic-masks), from 6 frames" in out, out
    assert "dynamic pixels left out" not in out
    # --camera over camera.txt is said, as jaxvo run says it; and that it is not the run's
    assert len(err) == 2 and "overrides" in err[0] and "camera.txt" in err[0], err
    assert "differs from the one jaxvo run read" in err[1]


def test_fuse_maps_refuses_settings_no_map_can_use(run_dir):
    from jaxvo.host.readers.io import open_sequence
    from jaxvo.host.writers.mapping import fuse_maps

    seq = open_sequence(run_dir / "seq")
    poses = [(0, np.eye(4))]
    for kwargs, needle in (({"voxel": 0}, "voxel must be"), ({"grow": 10**5}, "grow 100000"),
                           ({"vote_share": float("nan")}, "vote_share must be"),
                           ({"stride": 0}, "stride must be 1 or more")):
        with pytest.raises(InputError, match=needle):
            fuse_maps(seq, poses, None, **kwargs)


def test_the_sequences_images_as_masks_and_a_map_with_no_point(run_dir, capsys, tmp_path):
    d = run_dir
    rc, _, err = _map(capsys, d, "--traj", d / "traj.txt", "--dynamic-masks", d / "seq" / "rgb",
                      "--out", tmp_path / "m.ply")
    _one_line(rc, err, "holds the sequence's own images, not dynamic masks")
    rc, _, err = _map(capsys, d, "--traj", d / "traj.txt", "--out", tmp_path / "m.ply",
                      "--max-depth", "0.01")
    _one_line(rc, err, "has a depth reading within --max-depth 0.01 m: no map written")
    assert not list(tmp_path.iterdir())


def test_a_folder_without_a_camera_is_told_an_option_map_takes(run_dir, capsys, tmp_path):
    """It advised --intrinsics, which jaxvo map did not take."""
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(run_dir / "seq", seq)
    (seq / "camera.txt").unlink()
    traj = tmp_path / "t.txt"
    traj.write_text("".join(ln for ln in (run_dir / "traj.txt").read_text().splitlines(True)
                            if not ln.startswith("# jaxvo-run")))  # another tool's: no camera
    capsys.readouterr()
    rc = main(["map", str(seq), "--traj", str(traj), "--out", str(tmp_path / "m.ply")])
    err = capsys.readouterr().err
    assert rc == 2 and "--intrinsics fx,fy,cx,cy" in err, err
    assert main(["map", str(seq), "--traj", str(traj), "--out", str(tmp_path / "m.ply"),
                 "--intrinsics", "525,525,319.5,239.5"]) == 0
