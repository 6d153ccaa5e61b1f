"""ROS bags in: sequences written with rosbags' own ROS 1 and ROS 2 writers read back as the
frames written, through ``open_sequence`` and ``jaxvo run``; a bag of the shared TUM clip
gives the folder's trajectory."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="rosbags is not installed (a dependency of jaxvo)")

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Distortion, Intrinsics
from jaxvo.host.readers.io import open_sequence
from jaxvo.host.readers.rosbag import TUM_TOPICS, BagSequence, colour_bgr, depth_m
from jaxvo.synth.scenes import make_sequence
from jaxvo.trajectory import read_trajectory

K_INFO = Intrinsics(535.4, 539.2, 320.1, 247.6, 1000.0)


def image_msg(ts, stamp: float, img: np.ndarray, encoding: str, ros1: bool):
    """A sensor_msgs/Image of ``img`` ((H, W) or (H, W, C)) at header time ``stamp`` s."""
    T = ts.types
    sec, usec = divmod(round(stamp * 1e6), 1_000_000)  # TUM's stamps are whole microseconds
    nsec = usec * 1000
    stamp_msg = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    header = (T["std_msgs/msg/Header"](seq=0, stamp=stamp_msg, frame_id="cam") if ros1
              else T["std_msgs/msg/Header"](stamp=stamp_msg, frame_id="cam"))
    h, w = img.shape[:2]
    data = np.ascontiguousarray(img).view(np.uint8).reshape(-1)
    return T["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding=encoding,
                                      is_bigendian=0, step=data.size // h, data=data)


def info_msg(ts, stamp: float, K: Intrinsics, h: int, w: int, ros1: bool):
    T = ts.types
    img = image_msg(ts, stamp, np.zeros((1, 1), np.uint8), "mono8", ros1)
    kmat = np.array([K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1], np.float64)
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                do_rectify=False)
    lens = K.distortion or Distortion("plumb_bob", (0.0,) * 5)
    fields = {"D" if ros1 else "d": np.asarray(lens.coeffs, np.float64), "K" if ros1 else "k": kmat,
              "R" if ros1 else "r": np.eye(3).ravel(),
              "P" if ros1 else "p": np.zeros(12)}
    return T["sensor_msgs/msg/CameraInfo"](header=img.header, height=h, width=w,
                                           distortion_model=lens.model, binning_x=0,
                                           binning_y=0, roi=roi, **fields)


def write_bag(path: Path, frames, *, ros1: bool, rgb_encoding="rgb8", depth_encoding="32FC1",
              K: Intrinsics | None = K_INFO, topics=TUM_TOPICS, depth_offset=1e-5,
              bag_time: int | None = None, depth_units: float = 1000.0):
    """Write ``frames`` (``Frame``s: BGR uint8, depth float32 metres) as a TUM-like bag:
    colour at the frame's time, depth ``depth_offset`` s later, camera info once; 16-bit
    depth in ``depth_units`` per metre. ``bag_time``: every message recorded at that bag
    time (ns), as converters that write ``writer.write(conn, 0, ...)``."""
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    writer = Writer1(path) if ros1 else Writer2(path, version=9)
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    with writer as w:
        c_rgb = w.add_connection(topics[0], "sensor_msgs/msg/Image", typestore=ts)
        c_depth = w.add_connection(topics[1], "sensor_msgs/msg/Image", typestore=ts)
        c_info = w.add_connection(topics[2], "sensor_msgs/msg/CameraInfo", typestore=ts)
        for k, f in enumerate(frames):
            bgr = f.bgr
            # an encoding jaxvo does not read is written as BGR bytes under that name
            colour = {"rgb8": bgr[..., ::-1], "mono8": bgr[..., 1]}.get(rgb_encoding, bgr)
            depth = (f.depth if depth_encoding == "32FC1"
                     else np.round(f.depth * depth_units).astype(np.uint16))
            t_ns = int(f.timestamp * 1e9) + 1000  # recorded a moment after the stamp
            t_ns = t_ns if bag_time is None else bag_time
            if k == 0 and K is not None:
                h, w_ = bgr.shape[:2]
                w.write(c_info, t_ns, serialize(info_msg(ts, f.timestamp, K, h, w_, ros1),
                                                "sensor_msgs/msg/CameraInfo"))
            w.write(c_rgb, t_ns, serialize(image_msg(ts, f.timestamp, colour, rgb_encoding,
                                                     ros1), "sensor_msgs/msg/Image"))
            w.write(c_depth, t_ns + (2000 if bag_time is None else 0), serialize(
                image_msg(ts, f.timestamp + depth_offset, depth, depth_encoding, ros1),
                "sensor_msgs/msg/Image"))
    return path


@pytest.fixture(scope="module")
def frames():
    seq = make_sequence("handheld_fast", frames=4, seed=2)
    return [seq[i] for i in range(len(seq))]


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_bag_reads_back_the_frames(tmp_path, frames, ros1):
    path = write_bag(tmp_path / ("seq.bag" if ros1 else "seq"), frames, ros1=ros1)
    seq = open_sequence(path)
    assert isinstance(seq, BagSequence) and len(seq) == len(frames) and seq.warnings == []
    assert seq.name == "seq" and (seq.height, seq.width) == frames[0].bgr.shape[:2]
    assert seq.intrinsics == K_INFO and "camera_info" in seq.camera_source
    np.testing.assert_allclose(seq.timestamps, [f.timestamp for f in frames], atol=1e-6)
    for f, g in zip(frames, seq):
        np.testing.assert_array_equal(g.bgr, f.bgr)  # rgb8 -> BGR, exact
        np.testing.assert_array_equal(g.depth, f.depth)  # float32 metres, exact
        assert g.mask is None and g.depth.dtype == np.float32
    assert seq.groundtruth is None


def test_encodings_and_camera_override(tmp_path, frames):
    """bgr8 colour, 16UC1 millimetre depth, no camera info: --camera is then required."""
    path = write_bag(tmp_path / "enc.bag", frames, ros1=True, rgb_encoding="bgr8",
                     depth_encoding="16UC1", K=None)
    with pytest.raises(InputError, match="no camera info on /camera/rgb/camera_info"):
        open_sequence(path)
    seq = open_sequence(path, camera="tum_fr3")
    assert seq.camera_source == "preset tum_fr3"
    g = seq[1]
    np.testing.assert_array_equal(g.bgr, frames[1].bgr)
    # millimetres: within half a millimetre of the float depth written
    assert np.max(np.abs(g.depth - frames[1].depth)) <= 5e-4 + 1e-6  # tol 0.5 mm


def test_topics_and_association(tmp_path, frames):
    """Other topics by option; colour and depth paired by nearest stamp within max_diff."""
    topics = ("/cam/color", "/cam/depth", "/cam/camera_info")
    path = write_bag(tmp_path / "t.bag", frames, ros1=True, topics=topics)
    with pytest.raises(InputError, match=r"no topic /camera/rgb/image_color \(pass --rgb-topic;"
                                         r" image topics: /cam/color, /cam/depth\)"):
        open_sequence(path)
    seq = open_sequence(path, rgb_topic="/cam/color", depth_topic="/cam/depth")
    assert len(seq) == len(frames) and seq.intrinsics == K_INFO
    # depth k at t_k + 0.05 s lies 0.0167 s from colours k + 1 and k + 2 (30 Hz): one-to-one,
    # colours 1..3 pair and colour 0 and the last depth are left out
    far = write_bag(tmp_path / "far.bag", frames, ros1=True, depth_offset=0.05)
    seq = open_sequence(far)
    assert len(seq) == 3 and len(seq.warnings) == 2
    np.testing.assert_allclose(seq.timestamps, [f.timestamp for f in frames[1:]], atol=1e-6)
    assert "1 of 4 images have no depth image within 0.02 s" in seq.warnings[0]
    with pytest.raises(InputError, match="no timestamps match within 0.01 s"):
        open_sequence(far, max_diff=0.01)


def test_decoders_reject_unknown_encodings(frames):
    ts = get_typestore(Stores.ROS1_NOETIC)
    msg = image_msg(ts, 1.0, frames[0].bgr, "yuv422", True)
    with pytest.raises(InputError, match="colour encoding 'yuv422'"):
        colour_bgr(msg)
    with pytest.raises(InputError, match="depth encoding 'yuv422'"):
        depth_m(msg)


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_bad_bags_are_one_line(tmp_path, frames, capsys):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    for argv, expect in (
        (["run", junk, "--out", tmp_path / "t.txt"], "cannot read the bag"),
        (["run", write_bag(tmp_path / "ok.bag", frames, ros1=True), "--out", tmp_path / "t.txt",
          "--rgb-topic", "/nope"], "no topic /nope"),
        (["run", tmp_path, "--out", tmp_path / "t.txt", "--depth-topic", "/d"], "not a ROS bag"),
        (["run", tmp_path / "ok.bag", "--out", tmp_path / "ok.bag"], "would overwrite the input"),
    ):
        code, _, err = cli(capsys, *argv)
        assert code == 2 and err.count("\n") == 1 and err.startswith("jaxvo: error: "), err
        assert expect in err, err


def test_tum_clip_bag_gives_the_folders_trajectory(require_data, tmp_path, capsys):
    """The shared TUM clip written as a ROS 1 bag (colour rgb8, depth 32FC1 metres, as TUM's
    bags) and as a ROS 2 bag: ``jaxvo run`` gives the folder's trajectory."""
    folder = require_data("tum_fr3_walking_halfsphere_50")
    seq = open_sequence(folder)
    n = 12  # enough pairs to compare trajectories; the run's cost is in the compile
    frames = [seq[i] for i in range(n)]
    trajs = {}
    for name, path in (("folder", folder),
                       ("ros1", write_bag(tmp_path / "clip.bag", frames, ros1=True,
                                          K=seq.intrinsics, depth_offset=0.0)),
                       ("ros2", write_bag(tmp_path / "clip2", frames, ros1=False,
                                          K=seq.intrinsics, depth_offset=0.0))):
        out = tmp_path / f"{name}.txt"
        code, stdout, err = cli(capsys, "run", path, "--out", out, "--frames", n, "--json",
                                "--quiet")
        assert code == 0, err
        assert json.loads(stdout)["poses_written"] == n
        trajs[name] = read_trajectory(out)
    for name in ("ros1", "ros2"):
        np.testing.assert_allclose(trajs[name].timestamps, trajs["folder"].timestamps,
                                   atol=1e-6)  # tol 1 us: stamps via sec + nanosec
        np.testing.assert_allclose(trajs[name].poses, trajs["folder"].poses,
                                   atol=1e-9)  # tol 1e-9: the file's printed precision


def test_a_study_takes_a_bag(tmp_path, frames):
    """A study spec names a bag as it names a folder; the flow cache's key changes when the
    bag is written anew."""
    import os

    from jaxvo.config import Config
    from jaxvo.study import runner as study

    bag = write_bag(tmp_path / "seq.bag", frames, ros1=True)
    spec = tmp_path / "spec.toml"
    spec.write_text('[[sequences]]\npath = "seq.bag"\nframes = 3\n')
    (s,) = study.load_spec(spec).sequences
    assert s.path == str(bag.resolve())
    data, cached = study.sequence_data(s, Config(), None)  # the study's frames and flow
    assert not cached and data.flows.valid.shape[0] == 2 and len(data.timestamps) == 3
    key = study.sequence_key(s, Config())
    os.utime(bag, ns=(0, 0))  # as if written again
    study.sequence_key.cache_clear()  # memoised within a process; a new run computes it anew
    assert study.sequence_key(s, Config()) != key


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_messages_at_one_bag_time_are_found_by_themselves(tmp_path, frames, ros1):
    """A converter that writes every message at bag time 0 (header stamps differ): each
    frame is its own image, not the first one again."""
    path = write_bag(tmp_path / ("zero.bag" if ros1 else "zero"), frames, ros1=ros1,
                     bag_time=0)
    seq = open_sequence(path)
    assert len(seq) == len(frames)
    np.testing.assert_allclose(seq.timestamps, [f.timestamp for f in frames], atol=1e-6)
    order = [2, 0, 3, 1, 1, 3]  # out of order and again: each read finds its own message
    for i in order:
        np.testing.assert_array_equal(seq[i].bgr, frames[i].bgr)
        np.testing.assert_array_equal(seq[i].depth, frames[i].depth)


def test_bags_of_random_bytes_or_cut_short_are_one_line(tmp_path, frames, capsys):
    rng = np.random.default_rng(0)
    junk = tmp_path / "junk.bag"
    junk.write_bytes(rng.bytes(4096))  # rosbags raised UnicodeDecodeError (34 lines)
    whole = write_bag(tmp_path / "whole.bag", frames, ros1=True).read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(whole[: len(whole) // 2])
    ros2 = tmp_path / "ros2"
    ros2.mkdir()
    (ros2 / "metadata.yaml").write_bytes(rng.bytes(300))
    for path in (junk, cut, ros2):
        with pytest.raises(InputError, match=str(path.name)):
            open_sequence(path)
        code, _, err = cli(capsys, "run", path, "--out", tmp_path / "t.txt")
        assert code == 2 and err.count("\n") == 1 and err.startswith("jaxvo: error: "), err
        assert str(path) in err, err


def test_a_colour_encoding_not_read_names_the_bag_and_topic(tmp_path, frames):
    path = write_bag(tmp_path / "yuv.bag", frames, ros1=True, rgb_encoding="yuv422")
    with pytest.raises(InputError, match=r"yuv.bag /camera/rgb/image_color: colour encoding "
                                         r"'yuv422' is not read"):
        open_sequence(path)


@pytest.mark.parametrize("ros1", [True, False], ids=["ros1", "ros2"])
def test_camera_info_distortion_is_read(tmp_path, frames, ros1):
    """The camera info's lens comes with its K; a fisheye's, which jaxvo does not undo, is a
    warning and the images are taken as pinhole."""
    lens = Distortion("rational_polynomial", (0.1, -0.05, 0.001, -0.002, 0.01, 0.02, -0.01, 0.0))
    path = write_bag(tmp_path / ("lens.bag" if ros1 else "lens"), frames[:2], ros1=ros1,
                     K=K_INFO._replace(distortion=lens))
    seq = open_sequence(path)
    assert seq.intrinsics == K_INFO._replace(distortion=lens) and seq.warnings == []
    fisheye = Distortion("equidistant", (0.1, 0.01, 0.0, 0.0))
    path = write_bag(tmp_path / ("eq.bag" if ros1 else "eq"), frames[:2], ros1=ros1,
                     K=K_INFO._replace(distortion=fisheye))
    seq = open_sequence(path)
    assert seq.intrinsics.distortion is None
    assert any("equidistant distortion" in w and "pinhole" in w for w in seq.warnings)


def test_camera_info_without_calibration_is_said_as_such(tmp_path, frames):
    path = write_bag(tmp_path / "zero_k.bag", frames, ros1=True,
                     K=Intrinsics(0.0, 0.0, 0.0, 0.0, 1000.0))
    with pytest.raises(InputError, match=r"the camera info on /camera/rgb/camera_info "
                                         r"gives no camera: its K is all zero .*; pass --camera"):
        open_sequence(path)


def test_16_bit_depth_in_other_units_takes_depth_scale(tmp_path, frames, capsys):
    """16UC1 depth in TUM's 5000 per metre: read as millimetres it is 5 times too far, and
    the warning's advice (--depth-scale 5000) is one a bag takes."""
    path = write_bag(tmp_path / "tum_units.bag", frames, ros1=True, depth_encoding="16UC1",
                     depth_units=5000.0)
    seq = open_sequence(path)
    assert seq.intrinsics.depth_scale == 1000.0 and not seq.float_depth
    np.testing.assert_allclose(seq[1].depth, frames[1].depth * 5, atol=2e-3)  # tol 5 raw units
    code, _, err = cli(capsys, "run", path, "--out", tmp_path / "a.txt", "--frames", 2, "-q")
    assert "depth_scale 5000 is likelier (--depth-scale)" in err, err
    seq = open_sequence(path, depth_scale=5000.0)
    assert seq.intrinsics.depth_scale == 5000.0 and "depth_scale 5000 given" in seq.camera_source
    np.testing.assert_allclose(seq[1].depth, frames[1].depth, atol=1e-4)  # tol 0.5 raw unit
    metres = write_bag(tmp_path / "metres.bag", frames, ros1=True)
    code, _, err = cli(capsys, "run", metres, "--out", tmp_path / "b.txt", "--depth-scale", 5000)
    assert code == 2 and err.count("\n") == 1, err
    assert "/camera/depth/image: depth is 32FC1 metres; --depth-scale is for 16-bit" in err
