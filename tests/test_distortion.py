"""Lens distortion: the models read from every door, undone at the tracked points, and a
scene rendered through a lens that jaxvo, given the lens, sees as the pinhole scene."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from jaxvo.config import Config
from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import (
    PRESETS,
    TUM_DISTORTION,
    Distortion,
    backproject,
    camera_info_distortion,
    describe_distortion,
    distortion,
    read_camera_file,
    write_camera_file,
)
from jaxvo.host.frontend.distortion import distort, undistort
from jaxvo.host.frontend.flow import grid_flow
from jaxvo.synth.scenes import SensorOptions, make_sequence
from jaxvo.synth.sequence import _lens_maps

FR1 = TUM_DISTORTION["tum_fr1"]
K_FR1 = PRESETS["tum_fr1"]._replace(distortion=FR1)
RATIONAL = Distortion("rational_polynomial", (0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.005))
# a lens seen through librealsense's convention, with tangential terms large enough to tell
# its order of operations from OpenCV's
RS_LENS = Distortion("inverse_brown_conrady", (0.12, -0.2, 0.004, -0.003, 0.05))


def image_pixels(step: float = 9.7) -> np.ndarray:
    """(m, 2) pixels over a 640 x 480 image, its corners included."""
    u, v = np.meshgrid(np.r_[np.arange(0, 640, step), 639], np.r_[np.arange(0, 480, step), 479])
    return np.stack([u.ravel(), v.ravel()], axis=-1)


# ------------------------------------------------------------------------ the models


def test_distortion_builds_checks_and_drops_a_zero_lens():
    assert distortion("plumb_bob", [0, 0, 0, 0, 0]) is None  # pinhole: the path bit for bit
    assert distortion("Inverse Brown Conrady", [0] * 5) is None
    assert distortion("none", []) is None
    assert distortion("plumb_bob", [0.1, 0.2, 0.0, 0.0]) == Distortion("plumb_bob",
                                                                      (0.1, 0.2, 0.0, 0.0, 0.0))
    assert distortion("Brown Conrady", [0.1] * 5).model == "plumb_bob"
    assert distortion("Inverse Brown Conrady", [0.1] * 5).model == "inverse_brown_conrady"
    with pytest.raises(InputError, match=r"^cam: plumb_bob distortion takes 5 coefficients "
                                         r"\(k1 k2 p1 p2 k3\), got 6$"):
        distortion("plumb_bob", [0.1] * 6, where="cam")
    with pytest.raises(InputError, match="does not undo 'equidistant'"):
        distortion("equidistant", [0.1] * 4)
    with pytest.raises(InputError, match="finite"):
        distortion("plumb_bob", [0.1, np.nan, 0, 0, 0])


@pytest.mark.parametrize("lens", [FR1, RATIONAL], ids=["plumb_bob", "rational"])
def test_undistort_inverts_opencvs_projection(lens):
    """OpenCV's projectPoints is the reference: each pixel's ray, projected, lands on it."""
    K = PRESETS["tum_fr1"]._replace(distortion=lens)
    uv = image_pixels()
    xn = undistort(uv, K)
    rays = np.concatenate([xn, np.ones((len(xn), 1))], axis=1)
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K.matrix(),
                                np.asarray(lens.coeffs))
    assert np.abs(back.reshape(-1, 2) - uv).max() < 2e-4  # pixels
    assert np.abs(distort(xn, K) - uv).max() < 2e-4  # pixels


def realsense_project(x, y, c):
    """librealsense's rs2_project_point_to_pixel for (inverse / modified) Brown-Conrady,
    normalised coordinates in and out, written from its source."""
    r2 = x * x + y * y
    f = 1 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2
    x, y = x * f, y * f
    return (x + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x),
            y + 2 * c[3] * x * y + c[2] * (r2 + 2 * y * y))


def test_inverse_brown_conrady_is_undone_as_librealsense_projects():
    K = PRESETS["tum_fr3"]._replace(distortion=RS_LENS)
    uv = image_pixels()
    xn = undistort(uv, K)
    x, y = realsense_project(xn[:, 0], xn[:, 1], RS_LENS.coeffs)
    assert np.abs(K.fx * x + K.cx - uv[:, 0]).max() < 2e-4  # pixels
    assert np.abs(K.fy * y + K.cy - uv[:, 1]).max() < 2e-4
    # OpenCV's order of operations (tangential terms on the undistorted point) differs
    opencv = K._replace(distortion=RS_LENS._replace(model="plumb_bob"))
    assert np.abs(undistort(uv, opencv) - xn).max() > 1e-4


def test_backproject_puts_a_pixel_on_its_ray():
    rng = np.random.default_rng(0)
    z = rng.uniform(1.0, 4.0, 200)  # rays within the 640 x 480 image's view
    pts = np.stack([rng.uniform(-0.6, 0.6, 200) * z, rng.uniform(-0.45, 0.45, 200) * z, z], -1)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K_FR1.matrix(),
                              np.asarray(FR1.coeffs))
    got = backproject(uv.reshape(-1, 2), pts[:, 2], K_FR1)
    assert np.abs(got - pts).max() < 1e-5  # metres
    # no lens: the pinhole formula, bit for bit
    K = PRESETS["tum_fr1"]
    uv32 = uv.reshape(-1, 2).astype(np.float32)
    z32 = pts[:, 2].astype(np.float32)
    want = np.stack([(uv32[:, 0] - K.cx) / K.fx * z32, (uv32[:, 1] - K.cy) / K.fy * z32, z32], -1)
    assert np.array_equal(backproject(uv32, z32, K), want)


# ------------------------------------------------------------------------ the doors


def test_camera_info_distortion_reads_ros_and_librealsense_models():
    def info(model, D):
        return SimpleNamespace(distortion_model=model, d=np.asarray(D, np.float64))

    assert camera_info_distortion(info("plumb_bob", FR1.coeffs), where="t") == (FR1, None)
    assert camera_info_distortion(info("rational_polynomial", RATIONAL.coeffs),
                                  where="t") == (RATIONAL, None)
    got, note = camera_info_distortion(info("Inverse Brown Conrady", RS_LENS.coeffs), where="t")
    assert got == RS_LENS and note is None
    got, note = camera_info_distortion(info("equidistant", [0.1, 0.01, 0, 0]), where="t")
    assert got is None and "equidistant distortion" in note and "pinhole" in note
    with pytest.raises(InputError, match="^t: rational_polynomial distortion takes 8"):
        camera_info_distortion(info("rational_polynomial", FR1.coeffs), where="t")


def write(path, text: str):
    path.write_text(text)
    return path


def test_camera_txt_distortion_line(tmp_path):
    base = "fx 517.3\nfy 516.5\ncx 318.6\ncy 255.3\n"
    coeffs = " ".join(str(c) for c in FR1.coeffs)
    for line in (f"distortion {coeffs}", f"distortion: plumb_bob {coeffs}"):
        K = read_camera_file(write(tmp_path / "camera.txt", base + line + "\n"))
        assert K.distortion == FR1
    K = read_camera_file(write(tmp_path / "camera.txt",
                               base + "distortion " + " ".join(map(str, RATIONAL.coeffs))))
    assert K.distortion == RATIONAL
    assert read_camera_file(write(tmp_path / "camera.txt", base)).distortion is None
    with pytest.raises(InputError, match=r"camera.txt:5: plumb_bob distortion takes 5"):
        read_camera_file(write(tmp_path / "camera.txt", base + "distortion 0.1 0.2 0.3\n"))
    with pytest.raises(InputError, match="unknown key 'k1'.*'distortion"):
        read_camera_file(write(tmp_path / "camera.txt", base + "k1 0.26\n"))
    write_camera_file(tmp_path / "out.txt", K_FR1)  # written as it is read
    assert read_camera_file(tmp_path / "out.txt") == K_FR1


def test_opencv_calibration_yaml(tmp_path):
    """A file cv2.FileStorage itself wrote (OpenCV's sample calibration's keys), and ROS's
    camera_calibration YAML."""
    path = str(tmp_path / "calib.yaml")
    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("camera_matrix", K_FR1.matrix())
    fs.write("distortion_coefficients", np.asarray(FR1.coeffs).reshape(1, 5))
    fs.release()
    assert read_camera_file(path) == K_FR1
    ros = write(tmp_path / "ros.yml", (
        "image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        f"  data: {K_FR1.matrix().ravel().tolist()}\ndistortion_model: rational_polynomial\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: 8\n  data: {list(RATIONAL.coeffs)}\n"))
    assert read_camera_file(ros) == PRESETS["tum_fr1"]._replace(distortion=RATIONAL)
    bad = write(tmp_path / "bad.yaml", "%YAML:1.0\nfoo: 1\n")
    with pytest.raises(InputError, match="no 3x3 camera_matrix"):
        read_camera_file(bad)


def test_presets_and_summary_line():
    assert PRESETS["tum_fr1"].distortion is None  # TUM's own tools take the images as pinhole
    assert PRESETS["tum_fr1_lens"] == K_FR1
    assert PRESETS["tum_fr2_lens"].distortion.coeffs == (0.231222, -0.784899, -0.003257,
                                                         -0.000105, 0.917205)
    assert describe_distortion(PRESETS["tum_fr3"]) == ("images taken as pinhole (no "
                                                        "distortion given)")
    assert describe_distortion(K_FR1).startswith(
        "distortion: plumb_bob k1=0.262383 k2=-0.953104 p1=-0.005358 p2=0.002628 k3=1.163314")


# ------------------------------------------------------------------ a scene through a lens


def test_lens_maps_show_each_pixels_ray():
    """The synthetic lens's remap: the pinhole pixel each distorted pixel shows, projected
    through the lens by OpenCV, is that pixel."""
    K = PRESETS["ros_default"]
    map_x, map_y = _lens_maps(K, FR1, 480, 640)
    v, u = 479, 0
    pin = np.stack([map_x.ravel(), map_y.ravel()], -1).astype(np.float64)
    rays = np.concatenate([(pin - [K.cx, K.cy]) / [K.fx, K.fy], np.ones((len(pin), 1))], 1)
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K.matrix(), np.asarray(FR1.coeffs))
    grid = np.stack(np.meshgrid(np.arange(640), np.arange(480)), -1).reshape(-1, 2)
    assert np.abs(back.reshape(-1, 2) - grid).max() < 1e-3  # pixels (float32 maps)
    assert map_x[v, u] > 0  # TUM's fr1 lens shows less than the pinhole at its corners


def static_residual(seq, K) -> float:
    """Median distance, metres, between the previous points moved by the true motion and
    the current points, over the static valid points of frames 0 -> 2."""
    f0, f1 = seq[0], seq[2]
    flow = grid_flow(f0.bgr, f0.depth, f1.bgr, f1.depth, K, Config())
    T = np.linalg.inv(seq.groundtruth.poses[2]) @ seq.groundtruth.poses[0]
    uv0 = np.round(flow.uv_prev).astype(int)
    uv1 = np.clip(np.round(flow.uv_cur).astype(int), 0, [639, 479])
    static = (flow.valid & (f0.mask[uv0[:, 1], uv0[:, 0]] == 0)
              & (f1.mask[uv1[:, 1], uv1[:, 0]] == 0))
    moved = flow.pts_prev[static] @ T[:3, :3].T + T[:3, 3]
    return float(np.median(np.linalg.norm(moved - flow.pts_cur[static], axis=1)))


def test_flow_through_a_lens_matches_the_pinhole_scene_when_the_lens_is_given():
    """Without noise, the points of a scene rendered through TUM's fr1 lens agree with the
    true motion as well as the pinhole scene's do when the lens is given (measured 0.29 vs
    0.30 mm), and about four times worse when it is not (1.09 mm)."""
    opts = SensorOptions.ideal()
    plain = make_sequence("handheld_fast", frames=3, seed=0, options=opts)
    seen = make_sequence("handheld_fast", frames=3, seed=0, options=opts, lens=FR1)
    assert seen.intrinsics == plain.intrinsics._replace(distortion=FR1)
    pinhole = static_residual(plain, plain.intrinsics)
    given = static_residual(seen, seen.intrinsics)
    taken_as_pinhole = static_residual(seen, seen.intrinsics._replace(distortion=None))
    assert given < 1.3 * pinhole
    assert taken_as_pinhole > 2.5 * given


@pytest.mark.slow
def test_run_through_a_lens_is_closer_to_the_pinhole_run_with_the_lens():
    """A whole run: the ATE of the lens scene with its lens given is near the pinhole
    scene's, clearly nearer than without it (measured 0.70 / 0.74 / 1.83 mm on 40 frames)."""
    from jaxvo.evaluation.metrics import ate
    from jaxvo.odometry import run_sequence

    def ate_of(seq) -> float:
        r = run_sequence(seq, seed=0)
        return ate(seq.groundtruth, r.trajectory, align=True, max_diff=0.02).stats.rmse

    # 12 frames: the scan of test_pipeline.py's sequence (the same length, grid and Config),
    # compiled once for both
    plain = ate_of(make_sequence("handheld_slow", frames=12, seed=0))
    seen = make_sequence("handheld_slow", frames=12, seed=0, lens=FR1)
    given = ate_of(seen)
    seen.intrinsics = seen.intrinsics._replace(distortion=None)
    not_given = ate_of(seen)
    assert abs(given - plain) < 0.5 * abs(not_given - plain)


@pytest.mark.slow
def test_jaxvo_run_reads_a_folders_lens_and_says_so(tmp_path, capsys):
    """A scene written through a lens: its camera.txt carries the distortion line, and the
    run's summary names the model it applied; with --camera it is taken as pinhole, and the
    summary says that."""
    import json

    from jaxvo.cli.main import main
    from jaxvo.synth.scenes import write_sequence

    folder = tmp_path / "lens"
    write_sequence(make_sequence("handheld_fast", frames=4, seed=1, lens=FR1), folder)
    assert "distortion plumb_bob 0.262383" in (folder / "camera.txt").read_text()
    rc = main(["run", str(folder), "--out", str(tmp_path / "t.txt"), "-q", "--json"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["lens"].startswith("distortion: plumb_bob k1=0.262383")
    rc = main(["run", str(folder), "--out", str(tmp_path / "u.txt"), "-q", "--json",
               "--camera", "ros_default"])
    summary = json.loads(capsys.readouterr().out)
    assert rc == 0 and summary["lens"] == "images taken as pinhole (no distortion given)"
