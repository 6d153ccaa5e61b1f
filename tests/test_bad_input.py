"""Bad and unusual input, end to end: each case a user plausibly hits, and what jaxvo answers.

Every case is answered in one of two ways (issue 19): a one-line ``jaxvo: error: ...`` that
names the file or option and what is wrong, with exit status 2 and no traceback; or it is
handled, with a warning or a count in the summary, and the result is usable (a finite
trajectory whose time goes forward, nothing computed lost). The Python API answers with a
``ValueError`` that says what is wrong.

The sequence is a small synthetic one written to disk once (6 frames of ``handheld_fast``);
each case copies its text files and links or copies its images, then breaks one thing. The
runs share one compile of the per-frame step (the same settings everywhere).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pytest

from jaxvo.cli.main import interrupt_at_safe_points, main
from jaxvo.config import Config, Params, check_config, check_params
from jaxvo.errors import InputError, check_seed
from jaxvo.evaluation.metrics import ate
from jaxvo.host.camera import Intrinsics, read_camera_file
from jaxvo.host.io import InMemorySequence, open_sequence
from jaxvo.odometry import Odometry
from jaxvo.status import Status
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


# --- options: refused before any work, naming the option ------------------------------------


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--cell", "0"], ["--cell must be at least 4 pixels, got 0"]),
        (["--cell", "3"], ["--cell must be at least 4"]),
        (["--cell", "1000"], ["--cell 1000 leaves fewer than 2 x 2 grid cells", "640x480"]),
        (["--hypotheses", "0"], ["--hypotheses must be at least 1"]),
        (["--seed", "-1"], ["--seed must be a whole number from 0 to 4294967295"]),
        (["--seed", str(2**32)], ["--seed must be", "got 4294967296"]),
        (["--max-diff", "-1"], ["--max-diff must be a number of seconds >= 0"]),
        (["--max-diff", "nan"], ["--max-diff", "nan"]),
        (["--frames", "1"], ["--frames must be at least 2"]),
        # the consecutive-frame window is gone: its option says what replaced it
        (["--window", "5"], ["--window was removed: --keyframes refines a window over"]),
    ],
)
def test_run_option_out_of_range_is_one_line_naming_it(base, tmp_path, capsys, args, needles):
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", *args)
    assert_one_line_error(res, *needles)
    assert not (tmp_path / "t.txt").exists()  # refused before anything was written


@pytest.mark.parametrize(
    "args, needles",
    [
        (["synth", "static", "{tmp}/o", "--frames", "2", "--seed", "-1"], ["--seed must be"]),
        (["synth", "static", "{tmp}/o", "--frames", "0"], ["frames must be at least 1"]),
        (["demo", "--seed", "-1", "--peers", "none"], ["--seed must be"]),
        (["demo", "--frames", "1", "--peers", "none"], ["--frames must be at least 2"]),
        (["demo", "--peers", "nope"], ["unknown peer(s) nope"]),
    ],
)
def test_synth_and_demo_options_out_of_range(tmp_path, capsys, args, needles):
    res = cli(capsys, *(a.format(tmp=tmp_path) for a in args))
    assert_one_line_error(res, *needles)


def test_check_params_names_the_field_and_its_range():
    from jaxvo.config import PARAM_SPANS

    assert set(PARAM_SPANS) == set(Params._fields)  # every field has its range
    check_params(Params())  # the defaults pass, and so does a batch of good values
    check_params(Params(confidence=np.array([0.9, 0.99]), evidence_margin=np.zeros(2)))
    with pytest.raises(InputError, match=r"^Params.evidence_margin must be in \[0, inf\), got -1$"):
        check_params(Params(evidence_margin=-1.0))
    with pytest.raises(InputError, match=r"^Params.confidence must be in \(0, 1\), got 1\.5$"):
        check_params(Params(confidence=np.array([0.9, 1.5])))
    with pytest.raises(InputError, match=r"^Params.max_age must be a finite number"):
        check_params(Params(max_age=float("inf")))
    with pytest.raises(InputError, match=r"^--conf must be a number, got 'high'$"):
        check_params(Params(confidence="high"), names={"confidence": "--conf"})


def test_check_config_and_check_seed_name_the_field():
    with pytest.raises(InputError, match="Config.num_hypotheses must be at least 1"):
        check_config(Config(num_hypotheses=0))
    with pytest.raises(InputError, match="Config.cell must be a whole number"):
        check_config(Config(cell=16.0))
    check_config(Config(cell=np.int64(16)), height=480, width=640)  # NumPy integers pass
    assert check_seed(np.uint32(7)) == 7
    with pytest.raises(InputError, match="seed must be"):
        check_seed(1.5)


# --- outputs: checked before any work, naming the option --------------------------------


@pytest.mark.parametrize("option", ["--masks", "--dynamic-masks", "--overlays"])
def test_unwritable_mask_folder(base, tmp_path, unwritable, capsys, option):
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", option, unwritable / "m")
    assert_one_line_error(res, option, "cannot write there")


def test_unwritable_trajectory(base, unwritable, capsys):
    assert_one_line_error(cli(capsys, "run", base, "--out", unwritable / "t.txt"),
                          "--out", "cannot write")


def test_unwritable_synth_and_demo_folders(unwritable, capsys):
    assert_one_line_error(cli(capsys, "synth", "static", unwritable / "o", "--frames", "2"),
                          "OUT_DIR", "cannot write there")
    assert_one_line_error(cli(capsys, "demo", "--peers", "none", "--out", unwritable / "o"),
                          "--out", "cannot write there")


def test_output_paths_that_are_the_wrong_kind(base, tmp_path, capsys):
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path), "--out", "is a folder")
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path / "no" / "t.txt"),
                          "does not exist")
    (tmp_path / "file").write_text("x")
    assert_one_line_error(
        cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--masks", tmp_path / "file"),
        "--masks", "exists and is not a folder")


def test_out_never_overwrites_the_sequences_own_files(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    before = (seq / "groundtruth.txt").read_text()
    res = cli(capsys, "run", seq, "--out", seq / "groundtruth.txt")
    assert_one_line_error(res, "would overwrite the input")
    assert (seq / "groundtruth.txt").read_text() == before


# --- input files: refused at opening, naming the file --------------------------------------


GOOD_CAMERA = "fx 525\nfy 525\ncx 319.5\ncy 239.5\n"


@pytest.mark.parametrize(
    "text, needles",
    [
        ("fx nan\nfy 525\ncx 319.5\ncy 239.5\n", ["camera.txt: fx is nan, not a finite number"]),
        ("fx 525\nfy 525\ncx inf\ncy 239.5\n", ["camera.txt: cx is inf"]),
        ("fx 525\nfy 525\ncx 3195\ncy 239.5\n",
         ["camera.txt: principal point (3195, 239.5) lies outside the 640x480 image"]),
        ("fx 1\nfy 525\ncx 319.5\ncy 239.5\n", ["camera.txt: fx 1 gives a 179.6 degree field"]),
        (GOOD_CAMERA + "depth_scale 0\n", ["camera.txt: depth_scale must be a positive number"]),
        (GOOD_CAMERA + "depth-scale 1000\n", ["camera.txt:5: unknown key 'depth-scale'"]),
        (GOOD_CAMERA + "fx 530\n", ["camera.txt:5: fx given twice"]),
        ("fx 525 pixels\n", ["camera.txt:1: expected 'key value'"]),
        ("fx 525\nfy 525\n", ["camera.txt: missing cx, cy"]),
    ],
)
def test_nonsense_camera_txt_is_refused_naming_it(base, tmp_path, capsys, text, needles):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").write_text(text)
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"), *needles)


def test_camera_txt_that_is_a_folder(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").unlink()
    (seq / "camera.txt").mkdir()
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "camera.txt: not a file")


@pytest.mark.parametrize("sep", [" ", ": ", " = ", "=", ":\t"])
def test_camera_txt_takes_key_colon_value(tmp_path, sep):
    path = tmp_path / "camera.txt"
    path.write_text(f"fx{sep}585  # pixels\nfy{sep}586\ncx{sep}320\ncy{sep}240\n"
                    f"depth_scale{sep}1000\n")
    assert read_camera_file(path) == Intrinsics(585.0, 586.0, 320.0, 240.0, 1000.0)


def test_non_finite_timestamp_names_the_line(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    assoc = seq / "associations.txt"
    assoc.write_text(assoc.read_text().replace("0.066667 rgb", "nan rgb", 1))
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "associations.txt:5: timestamp is not a finite number")


@pytest.mark.parametrize("remove, needles", [
    ("depth.txt", ["file not found:", "depth.txt"]),
    ("rgb.txt", ["not a TUM RGB-D sequence (no rgb.txt or associations.txt)"]),
])
def test_a_missing_list_file_is_named(base, tmp_path, capsys, remove, needles):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "associations.txt").unlink()
    (seq / remove).unlink()
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"), *needles)


def test_sequence_path_that_is_a_file(base, capsys):
    assert_one_line_error(cli(capsys, "run", base / "rgb.txt", "--out", base / "t.txt"),
                          "sequence folder not found")


def test_no_frame_listed(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "associations.txt").unlink()
    (seq / "rgb.txt").write_text("# nothing here\n")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "rgb.txt: no images listed")


def test_no_frame_readable(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    for png in (seq / "depth").iterdir():  # 8-bit depth: no depth scale applies
        cv2.imwrite(str(png), np.zeros((480, 640), np.uint8))
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          f"none of the {FRAMES} frames can be read")


def test_start_pose_gt_without_ground_truth(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "groundtruth.txt").unlink()
    assert_one_line_error(
        cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--start-pose", "gt"),
        "start pose gt: no ground truth of the first frame")


def test_eval_on_astronomical_coordinates(tmp_path, capsys):
    rng = np.random.default_rng(0)
    for name, size in (("gt.txt", 1.0), ("est.txt", 1e200), ("ok.txt", 1e90)):
        rows = [f"{i / 10:.6f} " + " ".join(f"{size * v:.6e}" for v in rng.normal(size=3))
                + " 0 0 0 1" for i in range(10)]
        (tmp_path / name).write_text("\n".join(rows) + "\n")
    assert_one_line_error(cli(capsys, "eval", "ate", tmp_path / "gt.txt", tmp_path / "est.txt"),
                          "est.txt: a position lies", "e+200 m from the origin")
    # large but representable: scored, finite
    res = cli(capsys, "eval", "ate", tmp_path / "gt.txt", tmp_path / "ok.txt", "--json")
    assert res.rc == 0 and np.isfinite(json.loads(res.out)["results"]["trans"]["rmse"])


# --- handled: a warning or a count in the summary, a usable trajectory ---------------------


def test_clean_run_says_where_the_first_pose_came_from(base, tmp_path, capsys):
    res = run_json(capsys, base, tmp_path / "t.txt")
    assert res.rc == 0 and res.summary["warnings"] == [] and res.summary["dropped"] == {}
    assert res.summary["start_pose"] == "ground truth at 0.000000 s"
    traj = read_trajectory(tmp_path / "t.txt")
    gt = read_trajectory(base / "groundtruth.txt")
    np.testing.assert_allclose(traj.poses[0], gt.poses[0], atol=1e-8)  # tol: file precision
    res = run_json(capsys, base, tmp_path / "i.txt", "--start-pose", "identity")
    assert res.summary["start_pose"] == "identity"
    np.testing.assert_allclose(read_trajectory(tmp_path / "i.txt").poses[0], np.eye(4),
                               atol=1e-8)  # tol: file precision


@pytest.mark.parametrize("lists", [("rgb.txt", "depth.txt"), ("associations.txt",)])
def test_unsorted_lists_are_sorted_with_a_warning(base, tmp_path, capsys, lists):
    seq = copy_seq(base, tmp_path / "seq")
    if lists[0] == "rgb.txt":
        (seq / "associations.txt").unlink()
    for name in lists:
        swap_lines(seq / name, 2, 3)
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0
    assert any("lines not in time order" in w and lists[0] in w for w in res.summary["warnings"])
    assert any(line.startswith("jaxvo: warning:") for line in res.err)
    assert_usable_trajectory(tmp_path / "t.txt", FRAMES)


@pytest.mark.parametrize("name, with_gt", [("associations.txt", True),
                                           ("associations.txt", False), ("rgb.txt", True)])
def test_a_repeated_line_is_dropped_with_a_warning(base, tmp_path, capsys, name, with_gt):
    seq = copy_seq(base, tmp_path / "seq")
    if name == "rgb.txt":
        (seq / "associations.txt").unlink()
    if not with_gt:
        (seq / "groundtruth.txt").unlink()
    repeat_line(seq / name, 2)
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0
    assert any("repeats an earlier line; line dropped" in w for w in res.summary["warnings"])
    assert_usable_trajectory(tmp_path / "t.txt", FRAMES)  # no repeated timestamp
    if not with_gt:  # the trajectory is one jaxvo eval takes
        assert cli(capsys, "eval", "ate", base / "groundtruth.txt", tmp_path / "t.txt").rc == 0


def test_frames_without_a_depth_partner_are_counted(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "associations.txt").unlink()
    lines = [f"{float(t) + 0.1:.6f} {f}" for t, f in map(str.split, data_lines(seq / "depth.txt"))]
    (seq / "depth.txt").write_text("\n".join(lines) + "\n")  # shifted by 3 frames
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0
    assert res.summary["frames_listed"] == FRAMES and res.summary["frames"] == FRAMES - 3
    assert any("rgb.txt: 3 of 6 images have no depth image within 0.02 s" in w
               for w in res.summary["warnings"])


def test_camera_preset_overrides_camera_txt_with_a_warning(base, tmp_path, capsys):
    """The folder's camera.txt says millimetre depth (depth_scale 1000, and so its images
    are); --camera tum_fr3 (5000 per metre) overrides it, as the help says, and the summary
    says so naming both depth scales; the depths, 5x too short at a 0.57 m median, are
    inside the sensors' band but nearer the typical 2 m at 1000: that is said too."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    (seq / "camera.txt").write_text(GOOD_CAMERA + "depth_scale 1000\n")
    for png in (seq / "depth").iterdir():
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED).astype(np.float64)
        cv2.imwrite(str(png), np.round(raw / 5).astype(np.uint16))
    res = run_json(capsys, seq, tmp_path / "t.txt", "--camera", "tum_fr3")
    assert res.summary["camera"] == "preset tum_fr3"
    warning, scale = res.summary["warnings"]
    assert "depth_scale 1000 is likelier" in scale
    assert "preset tum_fr3 (fx 535.4" in warning and "depth_scale 5000) overrides" in warning
    assert "camera.txt (fx 525" in warning and warning.endswith("depth_scale 1000)")
    # the same folder without --camera takes its camera.txt, and says nothing
    res = run_json(capsys, seq, tmp_path / "u.txt")
    assert res.summary["camera"].endswith("camera.txt") and res.summary["warnings"] == []


def test_an_implausible_median_depth_is_warned_about(base, tmp_path, capsys):
    """depth_scale 1000 on images in TUM's 5000 per metre: a 14 m median, which no RGB-D
    sensor of these datasets reads as typical (beyond 15 m the run is refused)."""
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").write_text(GOOD_CAMERA + "depth_scale 1000\n")
    res = run_json(capsys, seq, tmp_path / "t.txt")
    (warning,) = res.summary["warnings"]
    assert "frame 0: median depth is 14.4 m with depth_scale 1000" in warning
    assert warning.endswith("check the depth scale")


def test_black_noise_and_saturated_frames_are_dropped_and_paired_across(
        base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    pngs = sorted((seq / "rgb").iterdir())
    rng = np.random.default_rng(0)
    cv2.imwrite(str(pngs[2]), np.zeros((480, 640, 3), np.uint8))
    cv2.imwrite(str(pngs[3]), rng.integers(0, 256, (480, 640, 3)).astype(np.uint8))
    cv2.imwrite(str(pngs[4]), np.full((480, 640, 3), 255, np.uint8))
    res = run_json(capsys, seq, tmp_path / "t.txt", "--masks", tmp_path / "m")
    assert res.rc == 0
    (reason, count), = res.summary["dropped"].items()
    assert count == 3 and "too few valid flow vectors with the last good frame" in reason
    assert res.summary["skipped"] == {} and res.summary["pairs_ok"] == 2  # 0->1, 1->5
    stamps = assert_usable_trajectory(tmp_path / "t.txt", FRAMES - 3)
    gt = read_trajectory(base / "groundtruth.txt")
    np.testing.assert_allclose(stamps, gt.timestamps[[0, 1, 5]], atol=1e-6)  # tol: 6 digits
    # the pose after the gap is measured, not carried: within 2 mm of the truth (both start at
    # the true first pose). Measured: 0.15 mm; the clean run 0.45 mm; before, with the 4
    # pairs touching a bad frame carried as identity, 10 mm
    est = read_trajectory(tmp_path / "t.txt")
    assert np.linalg.norm(est.poses[-1][:3, 3] - gt.poses[5][:3, 3]) < 0.002
    # a dropped frame has no mask: masks for the images the pairs start at
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == [
        f"{gt.timestamps[k]:.6f}.png" for k in (0, 1)]


def test_an_unreadable_image_and_one_of_another_size_are_dropped(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("rgb", "depth"))
    sorted((seq / "rgb").iterdir())[2].write_bytes(b"\x89PNG not really")
    cv2.imwrite(str(sorted((seq / "depth").iterdir())[4]), np.zeros((240, 320), np.uint16))
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0
    assert sum(res.summary["dropped"].values()) == 2
    reasons = " | ".join(res.summary["dropped"])
    assert "unreadable frame (first: cannot read image:" in reasons
    assert_usable_trajectory(tmp_path / "t.txt", FRAMES - 2)


def test_no_usable_pair_is_exit_1_saying_why(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    for png in (seq / "depth").iterdir():
        cv2.imwrite(str(png), np.zeros((480, 640), np.uint16))
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 1 and res.err[-1].startswith("jaxvo: no frame pair gave a camera motion")
    assert res.summary["pairs_ok"] == 0 and "scores_not_computed" in res.summary
    assert_usable_trajectory(tmp_path / "t.txt", FRAMES)  # carried poses, no NaN


def test_masks_and_overlays_are_png_named_by_rgb_timestamp(base, tmp_path, capsys):
    res = run_json(capsys, base, tmp_path / "t.txt", "--masks", tmp_path / "m",
                   "--dynamic-masks", tmp_path / "d", "--overlays", tmp_path / "o")
    assert res.rc == 0
    rgb = [Path(f).stem for _, f in map(str.split, data_lines(base / "rgb.txt"))]
    pairs = sorted(p.stem for p in (tmp_path / "m").iterdir())
    assert pairs == rgb[:-1]  # one per pair, named by the image its labels lie on
    assert sorted(p.stem for p in (tmp_path / "d").iterdir()) == rgb  # the last one too
    overlays = sorted((tmp_path / "o").iterdir())
    assert [p.stem for p in overlays] == rgb[:-1] and overlays[0].suffix == ".png"
    assert cv2.imread(str(overlays[0])).shape == (240, 1280, 3)  # 4 half-size panels


def test_demo_creates_its_out_folder(tmp_path, capsys, monkeypatch):
    """The README's own example wrote the peers' trajectories before creating the folder."""
    out = tmp_path / "demo_out" / "nested"
    # 4 frames: the scan of examples/quickstart_synthetic.py in test_examples.py (3 pairs)
    res = cli(capsys, "demo", "--frames", "4", "--peers", "opencv_rgb", "--out", out, "--json")
    assert res.rc == 0
    names = sorted(p.name for p in out.iterdir())
    assert {"jaxvo.txt", "opencv_rgb.txt", "groundtruth.txt"} <= set(names)
    assert any(n.startswith("overlay_") and n.endswith(".png") for n in names)


# --- the command line itself -------------------------------------------------------------


def test_version_help_and_exit_statuses(capsys):
    import jaxvo

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"jaxvo {jaxvo.__version__}"
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    for status in ("0 ", "1 ", "2 ", "130 "):
        assert f"\n  {status}" in text
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for needle in ("(default 0)", "at least 1 (default 20)", "(default 16)", "examples:",
                   "jaxvo run rgbd_dataset_freiburg3_walking_xyz --out traj.txt",
                   "exit status:", "Model", "Group", "--start-pose"):
        assert needle in text, needle


def test_ctrl_c_is_taken_at_the_next_safe_point():
    with interrupt_at_safe_points() as stop:
        try:
            os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt here...
        except KeyboardInterrupt:
            pytest.fail("Ctrl-C raised KeyboardInterrupt at once, not at a safe point")
        assert stop.requested
        with pytest.raises(KeyboardInterrupt):
            stop()  # ...only where the work checks
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def _run_until_compiling(seq: Path, out: Path, env: dict) -> subprocess.Popen:
    """``jaxvo run`` in a child, returned 1 s into XLA's compile of the per-frame step (an
    interrupt 0.3-3 s in crashed 8 of 8 tries before; one at its very start did not)."""
    code = "import sys; from jaxvo.cli.main import main; sys.exit(main())"
    # a smaller step (2 hypotheses, 32-pixel cells) compiles in about 5 s here, not 8: still
    # seconds past the interrupt, which lands 1 s into the compile
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "run", str(seq), "--out", str(out), "-q",
         "--hypotheses", "2", "--cell", "32"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    for line in proc.stderr:  # JAX_LOG_COMPILES: lowered, XLA's compile is about to start
        if "MLIR module conversion jit(jit_step)" in line:
            time.sleep(1.0)
            return proc
    raise AssertionError(f"no compile seen: {proc.wait()}")


def test_ctrl_c_during_the_first_compile_exits_130_keeping_the_first_pose(base, tmp_path):
    """It segfaulted (exit -11) in 12 of 15 tries: KeyboardInterrupt abandoned XLA's compile
    and the interpreter crashed on exit. Now the run stops after the compile and frame."""
    # the compile cache off: the session's may hold the step, and this needs a compile
    env = dict(os.environ, JAX_PLATFORMS="cpu", JAX_LOG_COMPILES="1", JAXVO_COMPILE_CACHE="off")
    proc = _run_until_compiling(base, tmp_path / "t.txt", env)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "stopping after the current step" in err and "jaxvo run:" in out
    traj = read_trajectory(tmp_path / "t.txt")
    assert 1 <= len(traj) < FRAMES and np.all(np.isfinite(traj.poses))


def test_a_second_ctrl_c_stops_at_once_with_130():
    code = (
        "import os, signal, time\n"
        "from jaxvo.cli.main import interrupt_at_safe_points\n"
        "with interrupt_at_safe_points():\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    time.sleep(30)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True,
                          text=True, env=dict(os.environ, JAX_PLATFORMS="cpu"), timeout=120)
    assert proc.returncode == 130 and "stopping at once" in proc.stderr


# --- the Python API: what OpenCV and Open3D users pass ------------------------------------


def _poses(odo: Odometry, frames, depth_of) -> np.ndarray:
    for f in frames:
        odo.process(f.bgr, depth_of(f), f.timestamp)
    return odo.trajectory.poses


def test_odometry_takes_uint16_depth_with_the_depth_scale(base_seq):
    """cv2.imread(..., IMREAD_UNCHANGED) gives uint16 raw units; before, every frame came
    back 'unreadable' with an identity pose. The result equals float metres bit for bit."""
    K = base_seq.intrinsics  # depth_scale 5000 per metre
    frames = list(base_seq)[:3]
    raw = [np.round(f.depth.astype(np.float64) * K.depth_scale).astype(np.uint16) for f in frames]
    by_raw = _poses(Odometry(K), frames, lambda f: raw[f.index])
    metres = [r.astype(np.float32) / np.float32(K.depth_scale) for r in raw]
    by_metres = _poses(Odometry(K), frames, lambda f: metres[f.index])
    np.testing.assert_array_equal(by_raw, by_metres)
    assert not np.allclose(by_raw[-1], np.eye(4), atol=1e-3)  # the camera moved
    by_f64 = _poses(Odometry(K), frames, lambda f: metres[f.index].astype(np.float64))
    np.testing.assert_array_equal(by_f64, by_metres)


@pytest.mark.parametrize(
    "bgr, depth, needle",
    [
        (lambda f: f.bgr, lambda f: f.depth.astype(np.int32), "got int32"),
        (lambda f: f.bgr, lambda f: f.depth[..., None], r"depth must be an \(H, W\) image"),
        (lambda f: f.bgr.astype(np.float32) / 255, lambda f: f.depth, "uint8 BGR image"),
        (lambda f: f.bgr[..., None], lambda f: f.depth, "uint8 BGR image"),
        (lambda f: f.bgr, lambda f: f.depth[:240], "differ in size"),
        (lambda f: None, lambda f: f.depth, "got NoneType"),
    ],
)
def test_odometry_refuses_wrong_dtype_or_shape(base_seq, bgr, depth, needle):
    f = base_seq[0]
    with pytest.raises(ValueError, match=needle):
        Odometry(base_seq.intrinsics).process(bgr(f), depth(f), f.timestamp)


def test_odometry_refuses_time_going_back_and_bad_settings(base_seq):
    f0, f1 = base_seq[0], base_seq[1]
    K = base_seq.intrinsics
    odo = Odometry(K)
    odo.process(f0.bgr, f0.depth, 1.0)
    with pytest.raises(ValueError, match="does not follow the previous frame's 1.000000 s"):
        odo.process(f1.bgr, f1.depth, 1.0)
    with pytest.raises(ValueError, match="finite"):
        odo.process(f1.bgr, f1.depth, float("nan"))
    with pytest.raises(ValueError, match="fx is nan"):
        Odometry(K._replace(fx=float("nan")))
    with pytest.raises(ValueError, match="Config.cell must be at least 4"):
        Odometry(K, cfg=Config(cell=0))
    with pytest.raises(ValueError, match=r"Params.confidence must be in \(0, 1\), got 1"):
        Odometry(K, params=Params(confidence=1.0))
    with pytest.raises(ValueError, match="T_w_c0 is not a rigid transform"):
        Odometry(K, T_w_c0=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="principal point"):
        Odometry(K._replace(cx=3195.0)).process(f0.bgr, f0.depth, 0.0)


def test_odometry_starts_at_the_given_pose(base_seq):
    f0 = base_seq[0]
    T0 = np.eye(4)
    T0[:3, 3] = [1.0, -2.0, 0.5]
    odo = Odometry(base_seq.intrinsics, T_w_c0=T0)
    np.testing.assert_array_equal(odo.process(f0.bgr, f0.depth, 0.0).T_w_c, T0)


def test_a_useless_frame_costs_its_own_pose_only(base_seq):
    """Streaming: a black frame is dropped (no pose, the reason said) and the next frame
    pairs with the last good one; the trajectory over the kept frames is about as accurate
    as without the black frame, instead of carrying two pairs' motion as identity."""
    gt, K = base_seq.groundtruth, base_seq.intrinsics
    clean = Odometry(K, T_w_c0=gt.poses[0])
    odo = Odometry(K, T_w_c0=gt.poses[0])
    results = []
    for f in base_seq:
        clean.process(f.bgr, f.depth, f.timestamp)
        bgr = np.zeros_like(f.bgr) if f.index == 2 else f.bgr
        results.append(odo.process(bgr, f.depth, f.timestamp))
    assert results[2].dropped and results[2].status == Status.BAD_INPUT
    assert all(r.dropped is None for k, r in enumerate(results) if k != 2)
    assert results[3].status == Status.OK  # frame 3 paired with frame 1
    assert len(odo.trajectory) == FRAMES - 1
    e_clean = ate(gt, clean.trajectory, align=False).stats.rmse
    e_drop = ate(gt, odo.trajectory, align=False).stats.rmse
    # measured (not aligned, both from the true first pose): clean 0.29 mm, dropped 0.21 mm;
    # before, the two pairs touching the black frame carried as identity: 2.1 mm
    assert e_drop < e_clean + 0.0005, (e_drop, e_clean)  # within 0.5 mm of the clean run


# --- issue 29: no output over an input, or over another output ----------------------------


def _digest(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize("option", ["--masks", "--dynamic-masks", "--overlays"])
def test_run_never_writes_images_into_a_folder_it_reads(base, tmp_path, capsys, option):
    """Masks are named by the RGB timestamp, TUM's image name: into SEQ/rgb they replaced
    5 of 6 colour images, exit 0."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    before = _digest(seq / "rgb")
    res = cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, seq / "rgb")
    assert_one_line_error(res, option, "which this command reads", "choose another folder")
    assert _digest(seq / "rgb") == before and not (tmp_path / "t.txt").exists()
    # the sequence's own folder holds its lists: refused too
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, seq),
                          option, "rgb.txt")


def test_run_out_is_never_an_input_image(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    first = min((seq / "rgb").iterdir())
    before = first.read_bytes()
    assert_one_line_error(cli(capsys, "run", seq, "--out", first),
                          "--out", "would overwrite the input", first.name)
    assert first.read_bytes() == before
    # through a link to the same folder: the same file
    (tmp_path / "link").symlink_to(seq / "rgb", target_is_directory=True)
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "link" / first.name),
                          "would overwrite the input")


def test_run_outputs_never_share_a_folder(base, tmp_path, capsys):
    x = tmp_path / "x"
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--masks", x,
              "--dynamic-masks", x, "--overlays", x)
    assert_one_line_error(res, "--dynamic-masks and --masks are the same folder")
    assert not x.exists()  # refused before any folder was made
    res = cli(capsys, "run", base, "--out", x / "t.txt", "--masks", x)
    assert_one_line_error(res, "--out", "lies in the folder of --masks")


def test_synth_never_writes_into_a_folder_with_files(base, tmp_path, capsys):
    """It overwrote rgb.txt, depth.txt, groundtruth.txt and camera.txt of an existing
    sequence and left the old images beside the new lists."""
    seq = copy_seq(base, tmp_path / "seq")
    before = _digest(seq)
    res = cli(capsys, "synth", "handheld_fast", seq, "--frames", "2")
    assert_one_line_error(res, "OUT_DIR", "is not empty")
    assert _digest(seq) == before
    res = cli(capsys, "synth", "handheld_fast", seq, "--composite", seq, "--frames", "2")
    assert_one_line_error(res, "OUT_DIR", "which this command reads")
    assert _digest(seq) == before
    (tmp_path / "empty").mkdir()  # an empty folder is a new one
    assert cli(capsys, "synth", "static", tmp_path / "empty", "--frames", "2").rc == 0
    assert (tmp_path / "empty" / "rgb.txt").is_file()


def test_demo_outputs_are_distinct_files(tmp_path, capsys):
    res = cli(capsys, "demo", "--frames", "3", "--peers", "opencv_rgb,opencv_rgb",
              "--out", tmp_path / "d")
    assert_one_line_error(res, "the opencv_rgb trajectory (#4) and the opencv_rgb trajectory "
                          "(#3) are the same file")
    assert not (tmp_path / "d").exists()


def test_study_results_never_go_over_the_spec_or_a_sequence(base, tmp_path, capsys):
    spec = tmp_path / "spec.json"  # what a study writes as its record in --out
    spec.write_text(json.dumps({"sequences": [{"path": str(base), "frames": 3}]}))
    before = spec.read_bytes()
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path, "-q"),
                          "--out", "spec.json, which this command reads")
    assert spec.read_bytes() == before
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "--flow-cache",
                              base, "-q"), "--flow-cache", "which this command reads")
    assert not (tmp_path / "r").exists()


def test_check_outputs_refuses_one_file_twice(tmp_path):
    from jaxvo.host.io import check_outputs

    with pytest.raises(InputError, match="b and a are the same file"):
        check_outputs((), files={"a": tmp_path / "t.txt", "b": tmp_path / "." / "t.txt"})
    check_outputs([tmp_path / "in.txt"], files={"a": tmp_path / "t.txt"},
                  folders={"m": tmp_path / "m"})  # apart: fine


# --- issue 29: depth scale, intrinsics and the files cameras write -------------------------


def _rewrite_depth(seq: Path, write) -> None:
    """Every depth image of ``seq`` replaced by ``write(png_path, metres) -> new path``, and
    associations.txt pointing at the new files."""
    K = read_camera_file(seq / "camera.txt")
    names = {}
    for png in sorted((seq / "depth").iterdir()):
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        new = write(png, raw.astype(np.float32) / np.float32(K.depth_scale))
        if new != png:
            png.unlink()
        names[f"depth/{png.name}"] = f"depth/{new.name}"
    assoc = seq / "associations.txt"
    assoc.write_text(re.sub(r"\S+", lambda m: names.get(m[0], m[0]), assoc.read_text()))


def _save_depth(png: Path, metres: np.ndarray, suffix: str) -> Path:
    """``metres`` written beside ``png`` as float depth: ``.npy`` or a float TIFF."""
    new = png.with_suffix(suffix)
    if suffix == ".npy":
        np.save(new, metres)
    else:
        assert cv2.imwrite(str(new), metres)
    return new


def _write(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image)
    return path


def test_millimetre_depth_at_5000_per_metre_is_warned_and_depth_scale_fixes_it(
        base, tmp_path, capsys):
    """Millimetres read at TUM's 5000 per metre: a median of 0.57 m, inside the old 0.3-8 m
    band, so nothing was said and the trajectory came out 5 times too short."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    _rewrite_depth(seq, lambda p, m: _write(p, np.round(m * 1000).astype(np.uint16)))
    res = run_json(capsys, seq, tmp_path / "t.txt")
    (warning,) = res.summary["warnings"]
    assert "median depth is 0.575 m with depth_scale 5000 (2.87 m at 1000" in warning
    assert "depth_scale 1000 is likelier (--depth-scale)" in warning
    res = run_json(capsys, seq, tmp_path / "u.txt", "--depth-scale", "1000")
    assert res.summary["warnings"] == [] and "depth_scale 1000 given" in res.summary["camera"]
    assert res.summary["ate_rmse_m"] < 0.002  # measured 0.45 mm at the right scale
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "v.txt",
                              "--depth-scale", "0"), "--depth-scale must be a positive number")


@pytest.mark.parametrize("suffix", [".tiff", ".npy"])
def test_float_depth_in_tiff_and_npy_is_read_as_metres(base, tmp_path, capsys, suffix):
    """The same depths as float32 metres give the same trajectory, bit for bit."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))

    _rewrite_depth(seq, lambda png, metres: _save_depth(png, metres, suffix))
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0 and res.summary["warnings"] == [] and res.summary["dropped"] == {}
    run_json(capsys, base, tmp_path / "png.txt")
    np.testing.assert_array_equal(read_trajectory(tmp_path / "t.txt").poses,
                                  read_trajectory(tmp_path / "png.txt").poses)


def test_depth_that_is_8_bit_or_of_another_size_names_the_file_and_cause(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    pngs = sorted((seq / "depth").iterdir())
    for png in pngs:
        cv2.imwrite(str(png), np.zeros((240, 320), np.uint16))
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          f"none of the {FRAMES} frames can be read (first: ", pngs[0].name,
                          "depth 320x240 does not match colour 640x480")
    for png in pngs:
        cv2.imwrite(str(png), np.zeros((480, 640), np.uint8))
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          f"{pngs[0].name} is 8-bit; depth must be 16-bit raw units or float")


def test_images_resized_without_their_camera_are_refused(base, tmp_path, capsys):
    """320x240 images beside the 640x480 camera.txt put the principal point at the image
    corner: it ran, 100 times worse, without a word."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb", "depth", "mask"))
    for sub, interp in (("rgb", cv2.INTER_AREA), ("depth", cv2.INTER_NEAREST),
                        ("mask", cv2.INTER_NEAREST)):
        for png in (seq / sub).iterdir():
            img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(png), cv2.resize(img, (320, 240), interpolation=interp))
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "principal point (319.5, 239.5) is far from the centre of the "
                          "320x240 image", "about 640x480")
    # the camera scaled to the images: runs
    res = run_json(capsys, seq, tmp_path / "t.txt", "--intrinsics", "262.5,262.5,159.75,119.75")
    assert res.rc == 0 and res.summary["camera"] == "given"


@pytest.mark.parametrize("value", ["525,525,319.5", "525,525,a,239.5", "525,525,319.5,239.5,1"])
def test_intrinsics_option_takes_four_numbers(base, tmp_path, capsys, value):
    assert_one_line_error(cli(capsys, "run", base, "--out", tmp_path / "t.txt", "--intrinsics",
                              value), "--intrinsics must be four numbers fx,fy,cx,cy")


def test_eth3d_calibration_txt_is_read(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").unlink()
    (seq / "calibration.txt").write_text("525 525 319.5 239.5\n")
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0 and res.summary["camera"].endswith("calibration.txt")
    (seq / "calibration.txt").write_text("525 525 319.5\n")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "calibration.txt: expected one line 'fx fy cx cy'")


def test_negative_fy_is_a_camera_whose_y_axis_points_up(base, tmp_path, capsys):
    """ICL-NUIM's TUM-style camera has fy -480: its image rows run against the camera's y.
    The sequence's images flipped upside down with fy negated back-project to the same
    points, so the trajectory is the original's; read with fy positive it is its mirror
    image (the ATE, after a rigid alignment, hides it; the positions do not)."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb", "depth"))
    for sub in ("rgb", "depth"):
        for png in (seq / sub).iterdir():
            cv2.imwrite(str(png), cv2.flip(cv2.imread(str(png), cv2.IMREAD_UNCHANGED), 0))
    K = read_camera_file(base / "camera.txt")
    assert K.cy == (480 - 1) / 2  # flipping keeps it: only fy changes sign
    (seq / "camera.txt").write_text(f"fx {K.fx}\nfy {-K.fy}\ncx {K.cx}\ncy {K.cy}\n")
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0 and res.summary["warnings"] == []
    run_json(capsys, base, tmp_path / "o.txt")
    orig = read_trajectory(tmp_path / "o.txt").poses[:, :3, 3]

    def gap(path: Path) -> float:  # metres, largest position difference to the original
        return float(np.abs(read_trajectory(path).poses[:, :3, 3] - orig).max())

    assert gap(tmp_path / "t.txt") < 0.001  # measured 0.02 mm
    (seq / "camera.txt").write_text(f"fx {K.fx}\nfy {K.fy}\ncx {K.cx}\ncy {K.cy}\n")
    run_json(capsys, seq, tmp_path / "m.txt")
    assert gap(tmp_path / "m.txt") > 0.01  # the mirror image: measured 44 mm


def test_odometry_refuses_float_depth_in_millimetres_or_raw_units(base_seq):
    f = base_seq[0]
    K = base_seq.intrinsics
    for depth, what in ((f.depth * 1000, "millimetres"), (f.depth * K.depth_scale, "raw")):
        with pytest.raises(ValueError, match="median of the float depth is .* the depth scale "
                                             "looks wrong"):
            Odometry(K).process(f.bgr, depth, f.timestamp)
    mm = np.round(f.depth * 1000).astype(np.uint16)  # millimetres at 5000 per metre
    odo = Odometry(K)
    from jaxvo.host.io import DepthScaleWarning

    with pytest.warns(DepthScaleWarning, match="depth_scale 1000 is likelier"):
        odo.process(f.bgr, mm, f.timestamp)
    assert len(odo.warnings) == 1


# --- issue 29: what users pass the Python API ---------------------------------------------


def test_odometry_takes_a_tuple_a_dict_a_camera_matrix_or_a_preset(base_seq):
    K = Intrinsics(525.0, 525.0, 319.5, 239.5, 5000.0)
    for given in ((525, 525, 319.5, 239.5), [525, 525, 319.5, 239.5, 5000],
                  {"fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5}, K.matrix(), np.asarray(K[:4]),
                  "ros_default"):
        assert Odometry(given).intrinsics == K, given
    for bad, needle in (((525, 525), "got shape"), ({"fx": 525, "f": 1}, "got keys"),
                        (object(), "got object"), (np.ones((3, 3)), "a camera matrix is"),
                        ("tum_fr9", "unknown camera preset")):
        with pytest.raises(ValueError, match=needle):
            Odometry(bad)


def test_run_sequence_takes_a_folder_and_says_what_it_expects(base, base_seq):
    from jaxvo.odometry import _as_sequence, run_sequence

    seq = _as_sequence(str(base))
    assert len(seq) == FRAMES and seq.intrinsics == base_seq.intrinsics
    assert _as_sequence(base_seq) is base_seq
    with pytest.raises(ValueError, match="for frames in a list, feed them to jaxvo.Odometry"):
        run_sequence(list(base_seq))
    with pytest.raises(InputError, match="sequence folder not found"):
        run_sequence(str(base / "missing"))


# --- issue 29: memory a run cannot have is refused up front -------------------------------


@pytest.mark.parametrize("args, needle", [
    (["--hypotheses", "100000"], "--hypotheses 100000"),
])
def test_run_that_cannot_fit_in_memory_is_refused_before_compiling(
        base, tmp_path, capsys, args, needle):
    """These compiled for 16-24 s, then died with an out-of-memory traceback (8.4 TB)."""
    t0 = time.perf_counter()
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", *args)
    assert_one_line_error(res, needle, "needs about", "of memory; this machine has",
                          "available")
    assert time.perf_counter() - t0 < 10  # seconds: nothing compiled (the step takes 16+)
    assert not (tmp_path / "t.txt").exists()


def test_synth_and_demo_of_a_billion_frames_are_refused(tmp_path, capsys):
    res = cli(capsys, "synth", "static", tmp_path / "o", "--frames", "1000000000")
    assert_one_line_error(res, "jaxvo synth --frames 1000000000 needs about 861 GB of memory")
    assert not (tmp_path / "o").exists()
    res = cli(capsys, "demo", "--frames", "10000000", "--peers", "none")
    assert_one_line_error(res, "jaxvo demo --frames 10000000 needs about", "TB of memory")


@pytest.mark.parametrize("extra, needle", [
    ("[fixed]\nnum_hypotheses = 100000\n", "num_hypotheses 100000"),
])
def test_study_that_cannot_fit_in_memory_is_refused(tmp_path, capsys, extra, needle):
    spec = tmp_path / "s.toml"
    spec.write_text("[[sequences]]\nscene = 'static'\nframes = 3\n" + extra)
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          needle, "needs about", "available")
    assert not (tmp_path / "r").exists()
    spec.write_text("[[sequences]]\nscene = 'static'\nframes = 1000000000\n")
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          "(1000000000 frames)", "TB of memory")


def test_python_api_refuses_memory_it_cannot_have(base_seq):
    from jaxvo.odometry import run_sequence

    f = base_seq[0]
    with pytest.raises(ValueError, match="Odometry with num_hypotheses 100000, cell "
                                         "16 needs about .* GB of memory"):
        Odometry(base_seq.intrinsics, cfg=Config(num_hypotheses=100000)).process(f.bgr, f.depth,
                                                                               0.0)
    with pytest.raises(InputError, match=f"run_sequence of {FRAMES} frames with num_hypotheses "
                                         "100000, cell 16 needs about"):
        run_sequence(base_seq, cfg=Config(num_hypotheses=100000))


def test_check_memory_gives_both_numbers():
    from jaxvo.host.memory import check_memory, run_bytes

    need = run_bytes(Config(), height=480, width=640)
    check_memory(need, what="x", available=2 * need)
    with pytest.raises(InputError, match=r"^x needs about 1.2 GB of memory; this machine has "
                                         r"1 GB available$"):
        check_memory(1.2e9, what="x", available=1e9)
    # the estimate grows with what the settings hold: hypotheses squared, keyframes squared
    assert run_bytes(Config(num_hypotheses=2000), height=480, width=640) > need + 40e6
    kf = run_bytes(Config(keyframes=True), height=480, width=640)
    assert need < kf < need + 10e6  # the default window of 4 keyframes costs little
    assert run_bytes(Config(keyframes=True, keyframe_window=10000), height=480,
                     width=640) > 1e13


def test_a_run_over_a_whole_sequence_counts_the_flow_it_holds_keyframes_included():
    """run_sequence and a study hold every pair's flow at once, with keyframes also its
    keyframe flow (80 bytes a grid point at the default window against the grid flow's
    53): run_bytes grows per frame by what sequence_flows really holds."""
    from jaxvo.host.flow import sequence_flows
    from jaxvo.host.memory import run_bytes

    seq = make_sequence("handheld_fast", frames=4, seed=0)
    per_frame = {}
    for keyframes in (False, True):
        cfg = Config(keyframes=keyframes)
        held = sequence_flows(seq, cfg)
        pairs = len(held.flows.valid)
        fields = [*held.flows, *(held.keyframes or ())]
        nbytes = sum(np.asarray(a).nbytes for a in fields)
        grow = (run_bytes(cfg, height=480, width=640, frames=1000)
                - run_bytes(cfg, height=480, width=640)) / 1000
        per_frame[keyframes] = grow
        outputs = 23.0 * 1200  # the stacked step outputs a frame, counted beside the flow
        assert grow - outputs == pytest.approx(nbytes / pairs, rel=1e-6)
    assert per_frame[True] - per_frame[False] > 60 * 1200  # the keyframe flow, counted


# --- issue 29: a study's folder whose depth cannot be read ---------------------------------


def test_study_folder_with_jpeg_depth_is_one_line_naming_the_file(base, tmp_path, capsys):
    """It raised IndexError after reading every frame."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    _rewrite_depth(seq, lambda p, m: _write(p.with_suffix(".jpg"),
                                            np.clip(m * 50, 0, 255).astype(np.uint8)))
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"sequences": [{"path": str(seq)}]}))
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          "none of the 6 frames can be read", ".jpg is 8-bit")
    assert not (tmp_path / "r").exists()


def test_eval_outputs_never_go_over_its_trajectories_or_each_other(base, tmp_path, capsys):
    gt = tmp_path / "gt.txt"
    shutil.copy(base / "groundtruth.txt", gt)
    before = gt.read_bytes()
    for option in ("--save_results", "--plot"):
        res = cli(capsys, "eval", "ate", gt, gt, option, gt)
        assert_one_line_error(res, option, "would overwrite the input")
        assert gt.read_bytes() == before
    res = cli(capsys, "eval", "ate", gt, gt, "--save_results", tmp_path / "r", "--plot",
              tmp_path / "r")
    assert_one_line_error(res, "--plot and --save_results are the same file")
    assert not (tmp_path / "r").exists()


# --- issue 37: the doors added since (eval options, depth values and scales, API types) ---


@pytest.mark.parametrize("args, needles", [
    (["rpe", "--delta", "inf"], ["--delta must be a positive number of frames, got inf"]),
    (["rpe", "--delta", "nan"], ["--delta must be a positive number of frames, got nan"]),
    (["rpe", "--delta", "inf", "--delta_unit", "s"], ["positive number of seconds, got inf"]),
    (["rpe", "--delta", "0", "-u", "seconds"], ["positive number of seconds, got 0"]),
    (["ate", "--max-diff", "nan"], ["--max-diff must be a number of seconds >= 0, got nan"]),
    (["ate", "--t_max_diff", "inf"], ["--max-diff", "got inf"]),
    (["rpe", "--delta_unit", "m"], ["--delta_unit 'm'", "not offered"]),
])
def test_eval_options_out_of_range_are_one_line_before_any_work(base, tmp_path, capsys, args,
                                                                 needles):
    """--delta inf raised OverflowError, --delta nan ValueError; both now say the option,
    and before the files are read (a missing estimate is not what is named)."""
    gt = base / "groundtruth.txt"
    res = cli(capsys, "eval", args[0], gt, tmp_path / "missing.txt", *args[1:])
    assert_one_line_error(res, *needles)


@pytest.mark.parametrize("plot, needle", [
    ("out.xyz", "its extension .xyz names no image format matplotlib writes"),
    ("out", "no extension names no image format"),
    ("out.png.docx", ".docx names no image format"),
])
def test_eval_plot_format_is_checked_before_any_work(base, tmp_path, capsys, plot, needle):
    pytest.importorskip("matplotlib", reason="--plot needs matplotlib (jaxvo[plot])")
    gt = base / "groundtruth.txt"
    res = cli(capsys, "eval", "ate", gt, tmp_path / "missing.txt", "--plot", tmp_path / plot)
    assert_one_line_error(res, needle, ".png", ".pdf", ".svg")
    assert list(tmp_path.iterdir()) == []
    res = cli(capsys, "eval", "ate", gt, gt, "--plot", tmp_path / "ok.JPG", "--json")
    assert res.rc == 0 and (tmp_path / "ok.JPG").read_bytes()[:2] == b"\xff\xd8", res.err


def test_eval_ate_help_says_what_scale_does_with_and_without_the_alignment(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "ate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "with the alignment Sim(3), as evo's -as; with --no-align the scale alone" in text


@pytest.mark.parametrize("scale, needle", [
    ("1e-300", ("puts every 16-bit depth reading (1 to 65535 units: 1e+300 to 6.55e+304 m) "
                "beyond 15 m")),
    ("1e300", "nearer than 0.1 m"),
    ("1e6", "nearer than 0.1 m"),
    ("0.01", "beyond 15 m"),
    ("-5000", "--depth-scale must be a positive number of raw units per metre, got -5000"),
])
def test_a_depth_scale_no_sensor_has_is_named_before_any_work(base, tmp_path, capsys, scale,
                                                               needle):
    """1e-300 and 1e300 gave numpy overflow warnings, then every pair blamed on too few
    valid flow vectors."""
    res = run_json(capsys, base, tmp_path / "t.txt", "--depth-scale", scale)
    assert_one_line_error(res, "--depth-scale", needle)
    assert not (tmp_path / "t.txt").exists()


def test_a_camera_txt_depth_scale_no_sensor_has_is_named(base, tmp_path, capsys):
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").write_text(GOOD_CAMERA + "depth_scale 1e9\n")
    assert_one_line_error(run_json(capsys, seq, tmp_path / "t.txt"),
                          "camera.txt: depth_scale 1e+09 raw units per metre", "nearer than 0.1 m")


@pytest.mark.parametrize("suffix", [".tiff", ".npy"])
def test_infinite_float_depth_is_no_reading(base, tmp_path, capsys, suffix):
    """+inf in float depth (a sensor's 'too far') is no reading: the pixels read inf are
    left out, and a first frame that is all inf is named as the cause, with no numpy
    warning."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    rng = np.random.default_rng(0)

    def write(png: Path, metres: np.ndarray) -> Path:
        metres = metres.copy()
        metres[rng.random(metres.shape) < 0.05] = np.inf
        return _save_depth(png, metres, suffix)

    _rewrite_depth(seq, write)
    frame = open_sequence(seq)[0]
    assert np.isfinite(frame.depth).all() and (frame.depth == 0).mean() >= 0.05
    res = run_json(capsys, seq, tmp_path / "t.txt")
    assert res.rc == 0 and res.summary["warnings"] == [], res
    assert not any("RuntimeWarning" in line or "overflow" in line for line in res.err), res.err
    assert_usable_trajectory(tmp_path / "t.txt", FRAMES)

    first = min((seq / "depth").iterdir())
    all_inf = np.full(frame.depth.shape, np.inf, np.float32)
    np.save(first, all_inf) if suffix == ".npy" else cv2.imwrite(str(first), all_inf)
    res = run_json(capsys, seq, tmp_path / "u.txt")
    assert res.summary is not None, res
    assert any("frame 0: no depth reading (every value is 0, negative, NaN or infinite)" in w
               for w in res.summary["warnings"]), res.summary["warnings"]


def test_odometry_takes_infinite_and_float64_depth_as_no_reading(base_seq):
    """Float64 depth beyond float32 and +inf are no reading, with no overflow warning."""
    import warnings

    f = base_seq[0]
    depth = f.depth.astype(np.float64)
    depth[:10] = np.inf
    depth[10:20] = 1e300
    odo = Odometry(base_seq.intrinsics)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = odo.process(f.bgr, depth, f.timestamp)
    assert r.dropped is None and odo.warnings == []


def test_eth3d_calibration_with_a_fifth_number_is_not_guessed(base, tmp_path, capsys):
    """A fifth number was taken as the depth scale without a word."""
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").unlink()
    (seq / "calibration.txt").write_text("525 525 319.5 239.5 1000\n")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt"),
                          "calibration.txt: ETH3D's calibration is 4 numbers 'fx fy cx cy', "
                          "got 5 (525 525 319.5 239.5 1000)", "--depth-scale")
    res = run_json(capsys, seq, tmp_path / "t.txt", "--intrinsics", "525,525,319.5,239.5")
    assert res.rc == 0, res  # the camera given: the folder's calibration is not read


def test_odometry_takes_the_times_numpy_and_ros_users_hold(base_seq):
    """np.datetime64 was taken as seconds and came out as nanoseconds written as seconds."""
    from types import SimpleNamespace

    from jaxvo.odometry import timestamp_seconds

    t_ns = 1305031102175304000
    for t in (np.datetime64(t_ns, "ns"), np.datetime64(t_ns // 1000, "us"), t_ns,
              np.int64(t_ns), SimpleNamespace(sec=1305031102, nanosec=175304000),
              SimpleNamespace(secs=1305031102, nsecs=175304000)):
        assert abs(timestamp_seconds(t) - 1305031102.175304) < 1e-6, t  # tol 1 us
    assert timestamp_seconds(np.timedelta64(1500, "ms")) == pytest.approx(1.5, abs=1e-12)
    assert timestamp_seconds(12) == 12.0 and timestamp_seconds(np.float32(0.5)) == 0.5
    for bad, needle in ((1305031102175, "neither seconds nor nanoseconds"),
                        ("1.0", "got str"), (True, "got bool"), (None, "got NoneType"),
                        (np.datetime64("NaT"), "NaT"), (float("inf"), "finite")):
        with pytest.raises(ValueError, match=needle):
            timestamp_seconds(bad)
    odo = Odometry(base_seq.intrinsics)
    for k in range(2):
        f = base_seq[k]
        odo.process(f.bgr, f.depth, np.datetime64(t_ns + k * 33_000_000, "ns"))
    np.testing.assert_allclose(odo.trajectory.timestamps, [1305031102.175304, 1305031102.208304],
                               atol=1e-6)  # tol 1 us


@pytest.mark.parametrize("count", ["0", "1000"])
def test_study_cpu_devices_beyond_the_cores_is_one_line(tmp_path, capsys, count):
    """1000 CPU devices compiled a 3-frame study past 5 minutes at 8.8 GB."""
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"sequences": [{"path": str(tmp_path / "missing")}]}))
    cores = len(os.sched_getaffinity(0))
    res = cli(capsys, "study", spec, "--out", tmp_path / "r", "--cpu-devices", count)
    assert_one_line_error(res, f"--cpu-devices must be 1 to {cores} (this machine's cores",
                          f"got {count}")


def test_out_dash_writes_the_trajectory_to_standard_output(base, tmp_path, capsys):
    """--out - wrote a file named '-'; now the trajectory goes to stdout (as command-line
    tools do) and the summary to stderr."""
    res = cli(capsys, "run", base, "--out", "-", "-q", "--json")
    assert res.rc == 0, res.err
    assert not Path("-").exists()
    piped = tmp_path / "piped.txt"
    piped.write_text(res.out)
    summary = json.loads("\n".join(res.err))
    assert summary["trajectory"] == "-" and summary["poses_written"] == FRAMES
    assert "ate_rmse_m" in summary  # scored from the poses written
    assert cli(capsys, "run", base, "--out", tmp_path / "file.txt", "-q").rc == 0
    np.testing.assert_array_equal(read_trajectory(piped).poses,
                                  read_trajectory(tmp_path / "file.txt").poses)
    text = cli(capsys, "run", base, "--out", "-", "-q")
    assert text.rc == 0 and "poses -> standard output" in "\n".join(text.err)
    assert text.out.startswith("# jaxvo run") and "ATE" not in text.out


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_full_disk_names_the_file(base, tmp_path, capfd):
    """'No space left on device' named no file; libpng added 'libpng error: Write Error'."""
    rc = main(["run", str(base), "--out", "/dev/full", "-q"])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and err == ["jaxvo: error: /dev/full: No space left on device"], err
    masks = tmp_path / "masks"
    masks.mkdir()
    for t in read_trajectory(base / "groundtruth.txt").timestamps:
        (masks / f"{t:.6f}.png").symlink_to("/dev/full")  # every mask lands on a full disk
    rc = main(["run", str(base), "--out", str(tmp_path / "t.txt"), "--masks", str(masks), "-q"])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1, err
    assert re.fullmatch(r"jaxvo: error: .*/masks/\d+\.\d{6}\.png: No space left on device",
                        err[0]), err


def test_one_line_answers_about_options_and_files_come_before_jax_loads(base, tmp_path):
    """`jaxvo run /missing` took 0.75-0.95 s: JAX (0.37 s of imports) loaded first, for the
    compile cache. Each command's checks now run before (bench: median 0.20 s against
    0.89 s before, 7 runs each on a loaded 2-core machine)."""
    full = tmp_path / "full"
    full.mkdir()
    (full / "x").write_text("")
    cases = [
        ["run", str(tmp_path / "missing"), "--out", str(tmp_path / "t.txt")],
        ["run", str(base), "--out", str(tmp_path / "t.txt"), "--depth-scale", "1e-300"],
        ["run", str(base), "--out", str(base / "rgb.txt")],
        ["study", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "s")],
        ["synth", "static", str(full), "--frames", "3"],
        ["demo", "--frames", "1"],
    ]
    code = ("import json, sys\nfrom jaxvo.cli.main import main\n"
            f"codes = [main(argv) for argv in {cases!r}]\n"
            "print(json.dumps([codes, sorted(m for m in ('jax', 'jaxlib') if m in sys.modules)]))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    codes, loaded = json.loads(done.stdout.splitlines()[-1])
    assert codes == [2] * len(cases) and loaded == [], (codes, loaded, done.stderr)
    lines = done.stderr.splitlines()
    assert len(lines) == len(cases) and all(ln.startswith("jaxvo: error: ") for ln in lines)


# --- recordings and maps (issue 35) ----------------------------------------------------------


def test_rerun_save_onto_an_input_or_into_an_unwritable_folder(base, tmp_path, unwritable,
                                                              capsys):
    seq = copy_seq(base, tmp_path / "seq")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--rerun-save",
                              seq / "rgb.txt"), "--rerun-save", "would overwrite the input")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--rerun-save",
                              unwritable / "run.rrd"), "--rerun-save", "cannot write")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", "--map",
                              seq / "rgb.txt"), "--map", "would overwrite the input")
    assert not (tmp_path / "t.txt").exists()  # refused before any work


def test_map_with_a_trajectory_of_another_sequence(base, tmp_path, capsys):
    lines = [f"{1000.0 + i / 30:.6f} 0 0 0 0 0 0 1" for i in range(FRAMES)]
    (tmp_path / "other.txt").write_text("\n".join(lines) + "\n")
    res = cli(capsys, "map", base, "--traj", tmp_path / "other.txt", "--out", tmp_path / "m.ply")
    assert_one_line_error(res, "--traj", "another sequence")
    assert not (tmp_path / "m.ply").exists()


def test_map_options_and_outputs_are_checked_first(base, tmp_path, unwritable, capsys):
    traj = tmp_path / "t.txt"
    traj.write_text("0.0 0 0 0 0 0 0 1\n")
    for args, needles in ((("--voxel", "0"), ("--voxel",)), (("--vote-share", "2"),
                                                             ("--vote-share",)),
                          (("--grow", "-1"), ("--grow",)),
                          (("--dynamic-masks", tmp_path / "none"), ("--dynamic-masks",))):
        assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out",
                                  tmp_path / "m.ply", *args), *needles)
    assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out",
                              unwritable / "m.ply"), "--out", "cannot write")
    assert_one_line_error(cli(capsys, "map", base, "--traj", traj, "--out", traj),
                          "--out", "would overwrite the input")


# --- nothing lost at the new doors (issue 46) ------------------------------------------------


def test_no_file_of_the_sequence_can_be_an_output(base, tmp_path, capsys):
    """Only the frames a run read were protected: --frames 2 --out SEQ/rgb/<3rd image> filled
    an image with the trajectory, --map SEQ/rgb/<image>.ply its picture; a hard link to the
    ground truth was written through."""
    seq = copy_seq(base, tmp_path / "seq", images=("rgb",))
    shutil.copy(seq / "rgb" / min(os.listdir(seq / "rgb")), seq / "rgb" / "unlisted.png")
    images = sorted((seq / "rgb").iterdir())
    before = {p: p.read_bytes() for p in images}
    assert_one_line_error(cli(capsys, "run", seq, "--frames", 2, "--out", images[2]),
                          "--out", "would overwrite the input")
    assert_one_line_error(cli(capsys, "run", seq, "--out", seq / "rgb" / "unlisted.png"),
                          "--out", "would overwrite a file of the input folder")
    assert_one_line_error(cli(capsys, "run", seq, "--frames", 2, "--out", tmp_path / "t.txt",
                              "--map", images[3].with_suffix(".ply")),
                          "--map's map picture", "would overwrite the input")
    os.link(seq / "groundtruth.txt", tmp_path / "hard.txt")
    assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "hard.txt"),
                          "would overwrite the input", "groundtruth.txt")
    for option in ("--rerun-save", "--map"):  # wrote files named '-'
        assert_one_line_error(cli(capsys, "run", seq, "--out", tmp_path / "t.txt", option, "-"),
                              f"{option} -: {option} writes a file, not standard output")
    assert {p: p.read_bytes() for p in images} == before and not Path("-").exists()
    assert not (tmp_path / "t.txt").exists()


def test_out_dev_stdout_is_standard_output_written_once(base, capfd):
    """``--out /dev/stdout > f``: the summary, printed to the same file after the
    trajectory, overwrote it."""
    rc = main(["run", str(base), "--out", "/dev/stdout", "-q"])
    cap = capfd.readouterr()
    assert rc == 0 and cap.out.startswith("# jaxvo run") and "jaxvo run:" not in cap.out
    assert len(read_trajectory_text(cap.out)) == FRAMES
    assert "poses -> standard output" in cap.err


def read_trajectory_text(text: str):
    return read_trajectory("-", text=text)


def test_a_closed_or_broken_standard_output(base, capsys, monkeypatch):
    """``--out - >&-`` raised AttributeError: 'NoneType' object has no attribute 'write';
    ``--out - | head`` ended 'jaxvo: error: -: Broken pipe', exit 2."""
    import errno

    from jaxvo.host import outputs

    monkeypatch.setattr(outputs, "STDOUT_CLOSED", False)
    monkeypatch.setattr(sys, "stdout", None)
    rc = main(["run", str(base), "--out", "-", "-q"])
    assert rc == 2 and "--out -: standard output is closed" in capsys.readouterr().err

    class ReaderGone:
        def write(self, text):
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")

        flush = write

    monkeypatch.setattr(outputs, "STDOUT_CLOSED", False)
    monkeypatch.setattr(sys, "stdout", ReaderGone())
    rc = main(["run", str(base), "--out", "-", "-q"])
    assert rc == 141 and capsys.readouterr().err == ""  # quiet, as other tools end


def test_ctrl_c_while_jax_starts_is_not_lost(base, tmp_path):
    """Ctrl-C 2 s after start: 'Exception ignored in: <function _xla_gc_callback>', the
    interrupt lost and the run ended with exit 0."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from jaxvo.cli.main import main; sys.exit(main())",
         "run", str(base), "--out", str(tmp_path / "t.txt"), "-q"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, JAX_PLATFORMS="cpu"))
    maps = Path(f"/proc/{proc.pid}/maps")
    end = time.monotonic() + 60
    while time.monotonic() < end and proc.poll() is None:  # until jaxlib is being loaded
        with contextlib.suppress(OSError):
            if "jaxlib" in maps.read_text():
                break
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert "Exception ignored" not in err and "Traceback" not in err, err[-2000:]
    if (tmp_path / "t.txt").exists():  # the signal came after JAX loaded: whole, and short
        assert len(read_trajectory(tmp_path / "t.txt")) <= 1


@pytest.mark.parametrize("suffix", [".tiff", ".npy"])
def test_depth_scale_on_float_depth_is_refused(base, tmp_path, capsys, suffix):
    """Float depth is metres: --depth-scale was ignored without a word."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    _rewrite_depth(seq, lambda png, metres: _save_depth(png, metres, suffix))
    res = run_json(capsys, seq, tmp_path / "t.txt", "--depth-scale", "1000")
    assert_one_line_error(res, "depth is float metres", "--depth-scale is for 16-bit depth")


def test_config_names_the_replacement_and_checks_every_value():
    """Config(window=5): TypeError 'unexpected keyword argument'; keyframe_overlap = nan and
    keyframe_stride = 1000 ran, taking no keyframe or one point a keyframe."""
    with pytest.raises(TypeError, match="keyframes=True.* refines a window over the latest"):
        Config(window=5)
    with pytest.raises(TypeError, match="did you mean cell"):
        Config(cel=8)
    for cfg, needle in ((Config(keyframe_overlap=float("nan")), ("keyframe_overlap must be a "
                         r"number in \[0, 1\], got nan")),
                        (Config(keyframes=True, keyframe_stride=1000),
                         "keyframe_stride 1000 keeps 1 of the 30x40 grid's points"),
                        (Config(fb_max=-1.0), r"fb_max must be a number in \(0, inf\)"),
                        (Config(lk_levels=-1), "lk_levels must be at least 0"),
                        (Config(keyframes="no"), "keyframes must be True or False"),
                        (Config(depth_min=5.0, depth_max=1.0), "depth_max 1.0 must be beyond")):
        with pytest.raises(InputError, match=needle):
            check_config(cfg, height=480, width=640)
    check_config(Config(keyframes=True), height=480, width=640)  # the defaults pass
    with pytest.raises(InputError, match="the grid itself is too coarse"):
        check_config(Config(keyframes=True, cell=200), height=480, width=640)


def test_a_date_past_2262_is_not_wrapped():
    """np.datetime64 went through nanoseconds, which hold dates up to 2262: 2300 came back
    as about 1830 and was taken."""
    from jaxvo.odometry import timestamp_seconds

    want = (np.datetime64("2300-01-01", "D") - np.datetime64("1970-01-01", "D")).astype(int)
    for t in (np.datetime64("2300-01-01", "D"), np.datetime64("2300-01-01T00:00:00", "s")):
        assert timestamp_seconds(t) == pytest.approx(float(want) * 86400.0, abs=1e-3)  # 1 ms
    with pytest.raises(ValueError, match="beyond any recording"):
        timestamp_seconds(np.datetime64("9999-01-01", "D"))
