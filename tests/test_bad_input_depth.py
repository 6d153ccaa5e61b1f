"""Bad input in depth: depth images and depth scales (files, --depth-scale, camera.txt).

8-bit, float, infinite or millimetre depth and scales no sensor has: read as metres,
warned about, or refused naming the file and the cause.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import json
import re
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
    run_json,
)

from jaxvo.host.frontend.camera import read_camera_file
from jaxvo.host.readers.io import open_sequence
from jaxvo.trajectory import read_trajectory


def test_an_implausible_median_depth_is_warned_about(base, tmp_path, capsys):
    """depth_scale 1000 on images in TUM's 5000 per metre: a 14 m median, which no RGB-D
    sensor of these datasets reads as typical (beyond 15 m the run is refused)."""
    seq = copy_seq(base, tmp_path / "seq")
    (seq / "camera.txt").write_text(GOOD_CAMERA + "depth_scale 1000\n")
    res = run_json(capsys, seq, tmp_path / "t.txt")
    (warning,) = res.summary["warnings"]
    assert "frame 0: median depth is 14.4 m with depth_scale 1000" in warning
    assert warning.endswith("check the depth scale")


def rewrite_depth(seq: Path, write) -> None:
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


def save_depth(png: Path, metres: np.ndarray, suffix: str) -> Path:
    """``metres`` written beside ``png`` as float depth: ``.npy`` or a float TIFF."""
    new = png.with_suffix(suffix)
    if suffix == ".npy":
        np.save(new, metres)
    else:
        assert cv2.imwrite(str(new), metres)
    return new


def write_image_file(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image)
    return path


def test_millimetre_depth_at_5000_per_metre_is_warned_and_depth_scale_fixes_it(
        base, tmp_path, capsys):
    """Millimetres read at TUM's 5000 per metre: a median of 0.57 m, inside the old 0.3-8 m
    band, so nothing was said and the trajectory came out 5 times too short."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    rewrite_depth(seq, lambda p, m: write_image_file(p, np.round(m * 1000).astype(np.uint16)))
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

    rewrite_depth(seq, lambda png, metres: save_depth(png, metres, suffix))
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


def test_study_folder_with_jpeg_depth_is_one_line_naming_the_file(base, tmp_path, capsys):
    """It raised IndexError after reading every frame."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    rewrite_depth(seq, lambda p, m: write_image_file(p.with_suffix(".jpg"),
                                            np.clip(m * 50, 0, 255).astype(np.uint8)))
    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"sequences": [{"path": str(seq)}]}))
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          "none of the 6 frames can be read", ".jpg is 8-bit")
    assert not (tmp_path / "r").exists()


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
        return save_depth(png, metres, suffix)

    rewrite_depth(seq, write)
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


@pytest.mark.parametrize("suffix", [".tiff", ".npy"])
def test_depth_scale_on_float_depth_is_refused(base, tmp_path, capsys, suffix):
    """Float depth is metres: --depth-scale was ignored without a word."""
    seq = copy_seq(base, tmp_path / "seq", images=("depth",))
    rewrite_depth(seq, lambda png, metres: save_depth(png, metres, suffix))
    res = run_json(capsys, seq, tmp_path / "t.txt", "--depth-scale", "1000")
    assert_one_line_error(res, "depth is float metres", "--depth-scale is for 16-bit depth")
