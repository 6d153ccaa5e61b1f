"""Tests of ``jaxvo eval``: tables, --json, and one-line errors with exit status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxvo.cli.main import main
from jaxvo.host.readers.io import write_trajectory
from jaxvo.trajectory import Trajectory
from jaxvo.transforms import pose_from_tq


@pytest.fixture
def pair(tmp_path, random_groundtruth):
    """A ground truth and an estimate offset by a rigid transform plus a known drift."""
    rng = np.random.default_rng(0)
    gt = random_groundtruth(rng, 40, 10.0)
    t = gt.timestamps
    S = pose_from_tq([1.0, 2.0, 3.0], [0.1, 0.2, 0.3, 0.9])
    est = Trajectory(t + 0.005, S @ gt.poses)
    write_trajectory(tmp_path / "gt.txt", gt)
    write_trajectory(tmp_path / "est.txt", est)
    return str(tmp_path / "gt.txt"), str(tmp_path / "est.txt")


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_ate_table(pair, capsys):
    code, out, err = run_cli(capsys, "eval", "ate", *pair)
    assert code == 0 and err == ""
    assert "SE(3) Umeyama (rigid, no scale)" in out and "matched poses 40" in out
    assert "translation [m]" in out and "rmse" in out and "nan" not in out.lower()


def test_ate_json(pair, capsys):
    code, out, _ = run_cli(capsys, "eval", "ate", *pair, "--json")
    report = json.loads(out)
    assert code == 0 and report["pairs"] == 40 and report["results"]["trans"]["unit"] == "m"
    # The estimate is the ground truth under a rigid transform: zero once aligned
    # (up to the 1e-9 printed precision of the files).
    assert report["results"]["trans"]["max"] <= 1e-8  # tol 1e-8 m
    code, out, _ = run_cli(capsys, "eval", "ate", *pair, "--json", "--no-align")
    assert json.loads(out)["results"]["trans"]["rmse"] > 1.0
    assert json.loads(out)["alignment"] == "none"


def test_rpe_json_and_table(pair, capsys):
    code, out, _ = run_cli(
        capsys, "eval", "rpe", *pair, "--delta", "0.2", "--delta-unit", "seconds", "--json"
    )
    report = json.loads(out)
    assert code == 0 and report["delta_unit"] == "seconds" and report["all_pairs"] is True
    assert report["results"]["rot"]["unit"] == "deg"
    assert report["results"]["trans"]["max"] <= 1e-8  # tol 1e-8 m: rigid offset, no drift
    assert report["results"]["rot"]["max"] <= 1e-6  # tol 1e-6 deg
    code, out, _ = run_cli(capsys, "eval", "rpe", *pair, "--delta", "5")
    assert code == 0 and "5 frames (consecutive pairs)" in out and "rotation [deg]" in out
    assert "pose pairs    7" in out


def check_one_line_error(capsys, argv, expect):
    code, out, err = run_cli(capsys, *argv)
    assert code == 2 and out == "", err
    assert err.startswith("jaxvo: error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err and "nan" not in err.lower()
    assert expect in err, err


def test_missing_file(pair, tmp_path, capsys):
    check_one_line_error(
        capsys, ["eval", "ate", pair[0], str(tmp_path / "nope.txt")], "file not found"
    )


def test_malformed_line(pair, tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n0 0 0 0 0 0 0 1\n1 0 0 0 zero 0 0 1\n")
    check_one_line_error(capsys, ["eval", "rpe", pair[0], str(bad)], f"{bad}:3:")


def test_non_unit_quaternion(pair, tmp_path, capsys):
    bad = tmp_path / "q.txt"
    bad.write_text("0 0 0 0 0 0 0 2\n")
    check_one_line_error(capsys, ["eval", "ate", str(bad), pair[1]], f"{bad}:1: quaternion")


def test_empty_trajectory(pair, tmp_path, capsys):
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing here\n")
    check_one_line_error(capsys, ["eval", "ate", pair[0], str(empty)], "empty trajectory")


def test_no_matching_timestamps_gives_both_ranges(pair, tmp_path, capsys):
    far = tmp_path / "far.txt"
    write_trajectory(far, Trajectory(np.array([500.0, 501.0]), np.stack([np.eye(4)] * 2)))
    code, _, err = run_cli(capsys, "eval", "ate", pair[0], str(far))
    assert code == 2 and err.count("\n") == 1
    assert f"{pair[0]} spans 10.000000 .. 11.300000 s" in err
    assert f"{far} spans 500.000000 .. 501.000000 s" in err


def test_degenerate_alignment(tmp_path, capsys):
    still = tmp_path / "still.txt"
    write_trajectory(still, Trajectory(np.arange(5) / 30.0, np.stack([np.eye(4)] * 5)))
    check_one_line_error(capsys, ["eval", "ate", str(still), str(still)], "same point")
    two = tmp_path / "two.txt"
    write_trajectory(two, Trajectory(np.arange(2) / 30.0, np.stack([np.eye(4)] * 2)))
    check_one_line_error(capsys, ["eval", "ate", str(two), str(two)], "at least 3")


def test_bad_options(pair, capsys):
    check_one_line_error(capsys, ["eval", "rpe", *pair, "--delta", "1.5"], "whole number")
    check_one_line_error(capsys, ["eval", "rpe", *pair, "--delta", "-1"], "positive")
    check_one_line_error(capsys, ["eval", "ate", *pair, "--max-diff", "-0.1"], "max-diff")
    check_one_line_error(capsys, ["eval", "rpe", *pair, "--delta", "100"], "no pose pairs")


def test_evo_reference_through_cli(require_data, capsys):
    ref = require_data("evo_reference")
    expected = json.loads((ref / "evo_results.json").read_text())["est_opencv_icp.txt"]
    gt, est = str(ref / "groundtruth.txt"), str(ref / "est_opencv_icp.txt")
    code, out, _ = run_cli(capsys, "eval", "ate", gt, est, "--max-diff", "0.01", "--json")
    assert code == 0
    got = json.loads(out)["results"]["trans"]
    for stat, want in expected["ate_se3_aligned_m"].items():
        assert abs(got[stat] - want) <= 5e-7 + 1e-12  # tol: evo's printed 6 decimals
    code, out, _ = run_cli(capsys, "eval", "rpe", gt, est, "--max-diff", "0.01", "--json")
    assert code == 0
    got = json.loads(out)["results"]
    for stat, want in expected["rpe_rot_1frame_deg"].items():
        assert abs(got["rot"][stat] - want) <= 5e-7 + 1e-12  # tol: evo's printed 6 decimals
