"""Bad input in a TUM sequence folder: its lists, timestamps, camera files and frames.

Refused at opening naming the file and line, or handled with a warning or a count in
the summary and a usable trajectory (unsorted or repeated lines, frames dropped).

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from bad_input import (
    FRAMES,
    GOOD_CAMERA,
    assert_one_line_error,
    assert_usable_trajectory,
    base,  # noqa: F401 (fixtures)
    cli,
    copy_seq,
    data_lines,
    repeat_line,
    run_json,
    swap_lines,
)

from jaxvo.host.frontend.camera import Intrinsics, read_camera_file
from jaxvo.trajectory import read_trajectory


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
