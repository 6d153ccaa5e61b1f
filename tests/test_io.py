"""Tests of jaxvo.host.readers.io and jaxvo.transforms: trajectory files, association, TUM sequences."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import PRESETS, Intrinsics, write_camera_file
from jaxvo.host.readers.io import (
    Frame,
    InMemorySequence,
    TrajectoryWriter,
    TumSequence,
    open_sequence,
    preset_from_name,
    write_trajectory,
)
from jaxvo.trajectory import Trajectory, associate, read_trajectory, tum_header, tum_lines
from jaxvo.transforms import (
    invert_pose,
    pose_from_tq,
    quat_to_rotation,
    rotation_angle,
    rotation_to_quat,
)


def random_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def random_trajectory(rng, n=20, t0=1341846434.710184):
    t = t0 + np.arange(n) / 30.0 + rng.uniform(0, 1e-3, n)
    return Trajectory(t, pose_from_tq(rng.normal(size=(n, 3)), random_quats(rng, n)))


# --- transforms -------------------------------------------------------------------------


def test_quat_to_rotation_matches_axis_angle():
    # Independent reference: OpenCV's Rodrigues formula for a rotation of angle a about u.
    rng = np.random.default_rng(0)
    for _ in range(20):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        a = rng.uniform(0, np.pi)
        q = np.concatenate([u * np.sin(a / 2), [np.cos(a / 2)]])
        R_ref, _ = cv2.Rodrigues(u * a)
        np.testing.assert_allclose(quat_to_rotation(q), R_ref, atol=1e-12)  # tol 1e-12
        np.testing.assert_allclose(rotation_angle(R_ref), a, atol=1e-12)  # tol 1e-12 rad


def test_rotation_quat_round_trip_all_branches():
    rng = np.random.default_rng(1)
    q = random_quats(rng, 500)
    # Near 180 degrees about each axis: the branches of Shepperd's method with small qw.
    q = np.concatenate([q, [[1, 0, 0, 1e-3], [0, 1, 0, 1e-3], [0, 0, 1, 1e-3]]])
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q_back = rotation_to_quat(quat_to_rotation(q))
    q_canon = np.where(q[:, 3:] < 0, -q, q)
    np.testing.assert_allclose(q_back, q_canon, atol=1e-12)  # tol 1e-12


def test_rotation_angle_small_angles_accurate():
    # arccos of the trace loses ~1e-8 rad here; the atan2 form must not.
    for a in (1e-9, 1e-7, 1e-5):
        R, _ = cv2.Rodrigues(np.array([0.0, a, 0.0]))
        assert abs(rotation_angle(R) - a) <= 1e-15 + 1e-9 * a  # tol relative 1e-9


def test_invert_pose():
    rng = np.random.default_rng(2)
    T = pose_from_tq(rng.normal(size=(5, 3)), random_quats(rng, 5))
    np.testing.assert_allclose(invert_pose(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


# --- trajectory files -------------------------------------------------------------------


def test_trajectory_round_trip_to_printed_precision(tmp_path):
    rng = np.random.default_rng(3)
    traj = random_trajectory(rng)
    path = tmp_path / "traj.txt"
    write_trajectory(path, traj, comment="test\nsecond line")
    back = read_trajectory(path)
    # Printed precision: %.6f seconds, %.9f metres and quaternion components.
    np.testing.assert_allclose(back.timestamps, traj.timestamps, rtol=0, atol=5e-7 + 1e-9)
    np.testing.assert_allclose(back.poses[:, :3, 3], traj.poses[:, :3, 3], rtol=0, atol=5e-10)
    np.testing.assert_allclose(back.poses[:, :3, :3], traj.poses[:, :3, :3], rtol=0, atol=4e-9)
    # Writing what was read gives the same timestamps and translations, character for character.
    path2 = tmp_path / "traj2.txt"
    write_trajectory(path2, back, comment="test\nsecond line")
    cols = [[ln.split()[:4] for ln in p.read_text().splitlines()] for p in (path, path2)]
    assert cols[0] == cols[1]


def test_read_trajectory_comments_sorting_and_normalisation(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text(
        "# timestamp tx ty tz qx qy qz qw\n\n"
        "2.0 1 2 3 0 0 0 1.0005\n"
        "1.0 0 0 0 0 0 0 1  # trailing comment\n"
    )
    traj = read_trajectory(path)
    np.testing.assert_array_equal(traj.timestamps, [1.0, 2.0])
    np.testing.assert_allclose(traj.poses[1, :3, 3], [1, 2, 3], atol=0)  # tol exact
    # A quaternion off by less than the tolerance is normalised into a rotation.
    np.testing.assert_allclose(traj.poses[1, :3, :3], np.eye(3), atol=1e-15)  # tol 1e-15


@pytest.mark.parametrize(
    "body, expect",
    [
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 1\n", ":2: expected 8 values"),
        ("0 0 0 0 0 0 0 1\n1 0 0 x 0 0 0 1\n", ":2: 'x' is not a number"),
        ("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1.1\n", ":2: quaternion qx qy qz qw has norm 1.1"),
        ("0 0 0 0 0 0 0 1\n1 0 0 nan 0 0 0 1\n", ":2: non-finite value"),
        ("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", ":2: repeated timestamp"),
        ("# only a comment\n\n", "empty trajectory"),
    ],
)
def test_read_trajectory_bad_input(tmp_path, body, expect):
    path = tmp_path / "bad.txt"
    path.write_text(body)
    with pytest.raises(InputError) as info:
        read_trajectory(path)
    msg = str(info.value)
    assert expect in msg and str(path) in msg and "\n" not in msg


def test_read_trajectory_missing_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_trajectory(tmp_path / "nope.txt")


# --- association ------------------------------------------------------------------------


def brute_force_associate(t_a, t_b, max_diff):
    """TUM associate.py, written out: all candidates, smallest difference first, greedy."""
    cands = sorted(
        (abs(a - b), i, j)
        for i, a in enumerate(t_a)
        for j, b in enumerate(t_b)
        if abs(a - b) <= max_diff
    )
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in cands:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


def test_associate_matches_brute_force_and_is_one_to_one():
    rng = np.random.default_rng(4)
    for _ in range(30):
        t_a = np.sort(rng.uniform(0, 2, rng.integers(1, 40)))
        t_b = rng.uniform(0, 2, rng.integers(1, 40))  # unsorted on purpose
        max_diff = rng.uniform(0.005, 0.1)
        try:
            ia, ib = associate(t_a, t_b, max_diff)
        except InputError:
            assert brute_force_associate(t_a, t_b, max_diff) == []
            continue
        assert list(zip(ia.tolist(), ib.tolist())) == brute_force_associate(t_a, t_b, max_diff)
        assert len(set(ib.tolist())) == len(ib)
        assert np.all(np.abs(t_a[ia] - t_b[ib]) <= max_diff)


def test_associate_nearest_wins_and_respects_max_diff():
    t_a = np.array([0.0, 1.0, 2.0])
    t_b = np.array([0.015, 0.004, 1.03, 2.0])
    ia, ib = associate(t_a, t_b, 0.02)
    assert ia.tolist() == [0, 2] and ib.tolist() == [1, 3]


def test_associate_no_match_names_both_ranges():
    with pytest.raises(InputError) as info:
        associate(np.array([0.0, 1.0]), np.array([5.0, 6.0]), 0.02, names=("gt.txt", "est.txt"))
    msg = str(info.value)
    assert "gt.txt spans 0.000000 .. 1.000000 s" in msg
    assert "est.txt spans 5.000000 .. 6.000000 s" in msg


# --- TUM sequences ------------------------------------------------------------------------


# tum_fr3 scaled from its 640x480 images to the 32x24 ones of make_sequence: a camera must
# fit its images (TumSequence refuses a principal point outside them)
SMALL_CAMERA = Intrinsics(535.4 / 20, 539.2 / 20, 320.1 / 20, 247.6 / 20, 5000.0)


def make_sequence(root, n=4, h=24, w=32, *, camera=True, assoc=False, mask=True, gt=True):
    root.mkdir(parents=True, exist_ok=True)
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    rgb_lines, depth_lines, mask_lines, assoc_lines = [], [], [], []
    rng = np.random.default_rng(5)
    depths = []
    for i in range(n):
        t = 100.0 + i / 30
        bgr = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        raw = rng.integers(0, 20000, (h, w), dtype=np.uint16)
        raw[0, :] = 0
        depths.append(raw)
        cv2.imwrite(str(root / f"rgb/{i}.png"), bgr)
        cv2.imwrite(str(root / f"depth/{i}.png"), raw)
        rgb_lines.append(f"{t:.6f} rgb/{i}.png")
        depth_lines.append(f"{t + 0.003:.6f} depth/{i}.png")
        assoc_lines.append(f"{t:.6f} rgb/{i}.png {t + 0.003:.6f} depth/{i}.png")
        if mask:
            (root / "mask").mkdir(exist_ok=True)
            m = np.zeros((h, w), np.uint8)
            m[4:8, 4 + i : 8 + i] = 2
            cv2.imwrite(str(root / f"mask/{i}.png"), m)
            mask_lines.append(f"{t:.6f} mask/{i}.png")
    (root / "rgb.txt").write_text("# timestamp filename\n" + "\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    if assoc:
        (root / "associations.txt").write_text("\n".join(assoc_lines) + "\n")
    if mask:
        (root / "mask.txt").write_text("\n".join(mask_lines) + "\n")
    if camera:
        write_camera_file(root / "camera.txt", SMALL_CAMERA)
    if gt:
        stamps = 100.0 + np.arange(n) / 30
        poses = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
        write_trajectory(root / "groundtruth.txt", Trajectory(stamps, poses))
    return depths


@pytest.mark.parametrize("assoc", [False, True])
def test_tum_sequence_synthetic_folder(tmp_path, assoc):
    depths = make_sequence(tmp_path / "seq", assoc=assoc)
    seq = open_sequence(tmp_path / "seq")
    assert len(seq) == 4 and (seq.height, seq.width) == (24, 32)
    assert seq.name == "seq"
    np.testing.assert_allclose(seq.intrinsics, SMALL_CAMERA, rtol=1e-6)  # tol: 6 digits written
    np.testing.assert_allclose(seq.timestamps, 100.0 + np.arange(4) / 30, atol=5e-7)  # tol 5e-7 s
    assert seq.groundtruth is not None and len(seq.groundtruth) == 4
    frames = list(seq)
    assert all(isinstance(f, Frame) for f in frames)
    f = seq[-1]
    assert f.index == 3 and f.bgr.shape == (24, 32, 3) and f.bgr.dtype == np.uint8
    assert f.depth.dtype == np.float32 and f.depth.shape == (24, 32)
    np.testing.assert_allclose(f.depth, depths[3] / 5000.0, rtol=1e-6)  # tol rel 1e-6 (float32)
    assert np.all(f.depth[0] == 0)
    assert f.mask.dtype == np.uint8 and f.mask[5, 7] == 2 and f.mask[0, 0] == 0
    with pytest.raises(IndexError):
        seq[4]


def test_tum_sequence_camera_rules(tmp_path):
    # the presets' own image size: their principal points must lie in the image
    make_sequence(tmp_path / "seq", n=2, h=480, w=640, camera=False, mask=False, gt=False)
    with pytest.raises(InputError, match="pass a camera preset"):
        TumSequence(tmp_path / "seq")
    seq = TumSequence(tmp_path / "seq", camera="tum_fr1")
    assert seq.intrinsics == PRESETS["tum_fr1"] and seq.groundtruth is None
    assert seq[0].mask is None
    with pytest.raises(InputError, match="unknown camera preset"):
        TumSequence(tmp_path / "seq", camera="kinect9")


@pytest.mark.parametrize(
    "name, expected",
    [
        ("rgbd_dataset_freiburg1_xyz", "tum_fr1"),
        ("rgbd_dataset_freiburg3_walking_xyz", "tum_fr3"),
        ("fr2_desk", "tum_fr2"),
        ("TUM-FR3-sitting", "tum_fr3"),
        ("office_fr12", None),
        ("frame3", None),
        ("7scenes_static_0000_0299", None),
        ("rgbd_bonn_balloon", "bonn"),
        ("rgbd_bonn_moving_obstructing_box2", "bonn"),
        ("bonnet_scan", None),
    ],
)
def test_download_takes_the_camera_its_folder_names(tmp_path, name, expected):
    """A TUM or Bonn download unpacks without camera.txt; its folder name names the camera."""
    assert preset_from_name(name) == expected
    make_sequence(tmp_path / name, n=2, h=480, w=640, camera=False, mask=False, gt=False)
    if expected is None:
        with pytest.raises(InputError, match="pass a camera preset"):
            TumSequence(tmp_path / name)
        return
    seq = TumSequence(tmp_path / name)
    assert seq.intrinsics == PRESETS[expected]
    assert seq.camera_source == f"preset {expected}, from the folder name"
    # an explicit preset still wins
    assert TumSequence(tmp_path / name, camera="ros_default").intrinsics == PRESETS["ros_default"]


def test_in_memory_every_kth_frame_keeps_its_ground_truth(tmp_path):
    make_sequence(tmp_path / "seq", n=5)
    seq = open_sequence(tmp_path / "seq")
    sub = InMemorySequence(seq, step=2)
    assert len(sub) == 3 and sub.name == "seq_every2"
    np.testing.assert_array_equal(sub.timestamps, seq.timestamps[[0, 2, 4]])
    np.testing.assert_array_equal(sub.groundtruth.timestamps, seq.groundtruth.timestamps[[0, 2, 4]])
    np.testing.assert_array_equal(sub[1].depth, seq[2].depth)
    assert len(InMemorySequence(seq, 2, step=2)) == 2
    with pytest.raises(InputError, match="frame step"):
        InMemorySequence(seq, step=0)


def test_tum_sequence_lazy_and_missing_image(tmp_path):
    make_sequence(tmp_path / "seq")
    (tmp_path / "seq/depth/2.png").unlink()
    seq = TumSequence(tmp_path / "seq")  # opening reads no depth image
    seq[1]
    with pytest.raises(InputError, match="depth/2.png"):
        seq[2]
    (tmp_path / "seq/rgb/3.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="cannot read image: .*rgb/3.png"):
        seq[3]


def test_tum_sequence_bad_lists(tmp_path):
    make_sequence(tmp_path / "seq")
    (tmp_path / "seq/mask.txt").write_text("100.000000 mask/0.png\n")
    with pytest.raises(InputError, match="mask.txt: no mask for the frame at 100.033333"):
        TumSequence(tmp_path / "seq")
    (tmp_path / "seq/rgb.txt").write_text("100.0\n")
    with pytest.raises(InputError, match=r"rgb.txt:1: expected 'timestamp filename'"):
        TumSequence(tmp_path / "seq")
    with pytest.raises(InputError, match="sequence folder not found"):
        open_sequence(tmp_path / "nowhere")


# --- real data ------------------------------------------------------------------------------


def test_tum_walking_sequence(require_data):
    seq = open_sequence(require_data("tum_fr3_walking_halfsphere_50"))
    assert len(seq) == 49  # associations.txt pairs 49 of the 50 colour images
    assert (seq.height, seq.width) == (480, 640)
    assert seq.intrinsics.fx == pytest.approx(535.4, abs=1e-9)  # tol 1e-9 px
    assert seq.groundtruth is None
    f = seq[10]
    assert f.bgr.shape == (480, 640, 3) and f.depth.dtype == np.float32
    valid = f.depth[f.depth > 0]
    # 16-bit at 5000 per metre: indoor readings between 0.2 m and 13.1 m.
    assert valid.size > 0.3 * f.depth.size and 0.2 < valid.min() and valid.max() <= 65535 / 5000
    assert np.all(np.diff(seq.timestamps) > 0)


def test_sevenscenes_sequence(require_data):
    seq = open_sequence(require_data("7scenes_static_0000_0299"))
    assert len(seq) == 300 and (seq.height, seq.width) == (480, 640)
    assert seq.intrinsics.depth_scale == pytest.approx(1000.0, abs=0)  # tol exact
    np.testing.assert_allclose(seq.timestamps, np.arange(300) / 30, atol=5e-7)  # tol 5e-7 s
    assert seq.groundtruth is not None and len(seq.groundtruth) == 300
    R = seq.groundtruth.poses[:, :3, :3]
    np.testing.assert_allclose(
        R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )  # tol 1e-12: rotations are orthonormal
    f = seq[150]
    assert f.timestamp == pytest.approx(5.0, abs=5e-7)  # tol 5e-7 s
    valid = f.depth[f.depth > 0]
    # Millimetres at scale 1000: a room seen from a hand-held Kinect, 0.3 m to 8 m.
    assert 0.3 < np.median(valid) < 8.0


def test_first_pose_and_the_ground_truth_of_chosen_frames():
    from jaxvo.host.readers.io import first_pose, groundtruth_of_frames

    poses = np.tile(np.eye(4), (5, 1, 1))
    poses[:, 0, 3] = np.arange(5.0)
    per_frame = Trajectory(np.arange(5) / 30.0, poses)
    seq = type("Seq", (), {"groundtruth": per_frame, "__len__": lambda self: 5})()
    assert np.array_equal(first_pose(seq), poses[0]) and first_pose(seq).dtype == np.float64
    sub = groundtruth_of_frames(seq, np.array([1, 3]))
    assert np.array_equal(sub.poses[:, 0, 3], [1.0, 3.0])
    assert np.array_equal(sub.timestamps, per_frame.timestamps[[1, 3]])
    # a ground truth at its own rate (not one pose a frame) is kept whole, and gives no
    # first pose: the metrics associate it by timestamp
    sparse = type("Seq", (), {"groundtruth": per_frame, "__len__": lambda self: 9})()
    assert groundtruth_of_frames(sparse, np.array([0, 2])) is per_frame
    assert np.array_equal(first_pose(sparse), np.eye(4))
    none = type("Seq", (), {"groundtruth": None, "__len__": lambda self: 3})()
    assert groundtruth_of_frames(none, np.array([0])) is None


def test_the_data_root_defaults_to_shared_data_beside_the_checkout(monkeypatch):
    import jaxvo
    from jaxvo.host.readers.io import data_root

    monkeypatch.delenv("JAXVO_DATA", raising=False)
    checkout = Path(jaxvo.__file__).resolve().parent.parent
    assert data_root() == checkout.parent / "shared" / "data"
    monkeypatch.setenv("JAXVO_DATA", "/elsewhere")
    assert data_root() == Path("/elsewhere")


def test_a_trajectory_writer_reads_back_its_own_poses_whoever_replaced_the_file(tmp_path):
    """Two runs into one --out: each file whole, the last one kept; the first run scored
    (and mapped) the second's file. written() is the text this writer wrote, parsed as the
    file is (its rounding), never the file."""
    from jaxvo.host.readers.io import TrajectoryWriter

    path = tmp_path / "t.txt"
    T = np.eye(4)
    T[0, 3] = 0.123456789123
    with TrajectoryWriter(path) as w:
        w.write(1.0, T)
        assert not path.exists()  # a reader sees the old file (none) until it is whole
    path.write_text("2.0 9 9 9 0 0 0 1\n")  # another run's, whole
    got = w.written()
    np.testing.assert_array_equal(got.timestamps, [1.0])
    np.testing.assert_allclose(got.poses[0], T, atol=5e-10)  # printed to 1e-9 m


def test_the_streaming_and_the_whole_file_writers_write_the_same_tum_lines(tmp_path):
    """One TUM format: TrajectoryWriter (a run's poses as they come) and write_trajectory
    (a whole trajectory) both write jaxvo.trajectory's header and lines, byte for byte."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(5, 4))
    poses = pose_from_tq(rng.normal(size=(5, 3)), q / np.linalg.norm(q, axis=1, keepdims=True))
    stamps = 1.3e9 + np.arange(5) / 30.0
    write_trajectory(tmp_path / "whole.txt", Trajectory(stamps, poses), comment="a\nb")
    with TrajectoryWriter(tmp_path / "stream.txt", comment="a\nb") as w:
        for t, T in zip(stamps, poses):
            w.write(t, T)
    text = (tmp_path / "whole.txt").read_text()
    assert (tmp_path / "stream.txt").read_text() == text
    assert text == tum_header("a\nb") + tum_lines(stamps, poses)
    assert text.splitlines()[:3] == ["# a", "# b", "# timestamp tx ty tz qx qy qz qw"]
    back = read_trajectory(tmp_path / "whole.txt")
    np.testing.assert_allclose(back.poses, poses, atol=5e-9)  # printed to 1e-9
    with pytest.raises(ValueError, match=r"\(N,\) timestamps and \(N, 4, 4\) poses"):
        tum_lines(stamps[:4], poses)


# --- the depth scale check ------------------------------------------------------------


@pytest.fixture(scope="module")
def heavy_cover():
    """Frames of ``heavy_cover_90``: a box filling about 90 % of the view at 0.7-0.8 m, the
    room behind it to 3.5 m, at TUM's depth scale (5000 per metre), which is right."""
    from jaxvo.synth.scenes import make_sequence

    seq = make_sequence("heavy_cover_90", frames=31, seed=0)
    return seq.intrinsics, [seq[i].depth for i in (0, 15, 30)]


def test_a_near_object_filling_the_view_is_no_wrong_depth_scale(heavy_cover):
    """Its median (0.74-0.78 m) lies nearer the typical 2 m at 1000 per metre (3.7-3.9 m),
    and the run warned that the depth scale was probably wrong; the span the view reads
    (0.7 to 3.2 m) says it is right."""
    from jaxvo.host.readers.io import check_depth_scale

    K, depths = heavy_cover
    for i, depth in enumerate(depths):
        assert np.median(depth[depth > 0]) < 0.8  # metres: the box, not the room
        assert check_depth_scale(depth, K, where=f"frame {i}") is None


@pytest.mark.parametrize("factor, likelier", [(0.2, 1000), (5.0, 5000)])
def test_a_wrong_depth_scale_still_warns_with_the_right_one(heavy_cover, factor, likelier):
    """The same frames in millimetres read at 5000 per metre (every depth a fifth), or in
    TUM's units read as millimetres (5 times): the whole span moves, and it is said."""
    from jaxvo.host.readers.io import check_depth_scale

    K, depths = heavy_cover
    K = K._replace(depth_scale=5000.0 if likelier == 1000 else 1000.0)
    for depth in depths:
        note = check_depth_scale(depth * factor, K, where="frame")
        assert note is not None and f"depth_scale {likelier} is likelier" in note
