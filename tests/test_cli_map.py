"""`jaxvo map` and `jaxvo run --map` end to end on a small synthetic sequence on disk."""

import json

import pytest

from jaxvo.cli.main import main
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
