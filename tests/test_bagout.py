"""``jaxvo run --out-bag``: a run's results as a ROS 2 bag, read back by independent readers
(``rosbags``' reader, and the ``mcap`` library for the MCAP file): the message types and
counts, stamps equal to the input frames', poses equal to the trajectory file's, masks equal
to ``--dynamic-masks``', the map equal to the PLY; an input bag's every message kept; and the
bag whole or not at all (refused targets, a failure, Ctrl-C)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags", reason="rosbags is not installed (a dependency of jaxvo)")

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from test_realsense import write_realsense
from test_rosbag import image_msg, info_msg, write_bag

from jaxvo.cli.main import main
from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.host.readers.io import open_sequence
from jaxvo.host.readers.realsense import image_message
from jaxvo.host.readers.rosbag import TUM_TOPICS
from jaxvo.host.writers import bagout
from jaxvo.host.writers.bagout import (
    INFO_TOPIC,
    MAP_TOPIC,
    MASK_TOPIC,
    ODOMETRY_TOPIC,
    OVERLAY_TOPIC,
    TF_TOPIC,
    check_frame_id,
    frame_times,
)
from jaxvo.synth.scenes import make_sequence, write_sequence
from jaxvo.trajectory import read_trajectory
from jaxvo.transforms import rotation_to_quat

N = 6  # frames: a few pairs, so that masks move and the map has points


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "handheld"
    write_sequence(make_sequence("handheld_fast", frames=N, seed=1), out)
    return out


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err, *needles):
    assert code == 2 and err.count("\n") == 1 and err.startswith("jaxvo: error: "), err
    for needle in needles:
        assert needle in err, (needle, err)


def read_bag(path: Path) -> dict[str, list]:
    """topic -> [(bag time ns, message, raw bytes)] with rosbags' reader, in bag time order."""
    out: dict[str, list] = {}
    with AnyReader([path]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, t_ns, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t_ns, reader.deserialize(raw, conn.msgtype),
                                                   bytes(raw)))
    out["_types"] = types
    return out


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def read_ply(path: Path) -> np.ndarray:
    """A binary little-endian PLY of x y z float, red green blue uchar, read with numpy."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    dtype = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")]
    return np.frombuffer(data[end:], dtype=dtype)


def no_leftovers(target: Path) -> None:
    """Nothing of a bag is left beside its target but the target itself."""
    assert not [p for p in target.parent.iterdir() if p.name.startswith(f".{target.name}.")]


def test_a_run_writes_a_bag_that_independent_readers_read_back(folder, tmp_path, capsys):
    traj, dyn, bag, ply = (tmp_path / "traj.txt", tmp_path / "dyn", tmp_path / "run_bag",
                           tmp_path / "map.ply")
    code, out, err = cli(capsys, "run", folder, "--out", traj, "--dynamic-masks", dyn,
                         "--out-bag", bag, "--bag-overlay", "--map", ply, "--with-input",
                         "-q", "--json")
    assert code == 0, err
    summary = json.loads(out)
    seq = open_sequence(folder)
    est = read_trajectory(traj)
    assert len(est) == N and summary["bag"] == str(bag)
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "run_bag.mcap"]
    no_leftovers(bag)
    got = read_bag(bag)
    assert got["_types"] == {
        ODOMETRY_TOPIC: "nav_msgs/msg/Odometry", TF_TOPIC: "tf2_msgs/msg/TFMessage",
        MASK_TOPIC: "sensor_msgs/msg/Image", INFO_TOPIC: "sensor_msgs/msg/CameraInfo",
        OVERLAY_TOPIC: "sensor_msgs/msg/Image", MAP_TOPIC: "sensor_msgs/msg/PointCloud2",
        TUM_TOPICS[0]: "sensor_msgs/msg/Image", TUM_TOPICS[1]: "sensor_msgs/msg/Image",
        TUM_TOPICS[2]: "sensor_msgs/msg/CameraInfo"}
    pngs = sorted(dyn.glob("*.png"))
    counts = {t: len(v) for t, v in got.items() if t != "_types"}
    assert counts == {ODOMETRY_TOPIC: N, TF_TOPIC: N, MASK_TOPIC: len(pngs),
                      INFO_TOPIC: len(pngs), OVERLAY_TOPIC: len(pngs) - 1, MAP_TOPIC: 1,
                      **{t: N for t in TUM_TOPICS}}
    assert summary["bag_messages"] == sum(counts.values())
    # the input frames' own times (rgb.txt's, written to the microsecond), as header stamps
    # and as the times the messages were recorded at
    frame_ns = [round(t * 1e6) * 1000 for t in seq.timestamps]
    for topic in (ODOMETRY_TOPIC, MASK_TOPIC, *TUM_TOPICS):
        assert [stamp_ns(m) for _, m, _ in got[topic]] == frame_ns[: len(got[topic])], topic
        assert [t for t, _, _ in got[topic]] == frame_ns[: len(got[topic])], topic
    # poses: the trajectory file's (camera to world), as odometry and as tf world -> camera
    q_file = rotation_to_quat(est.poses[:, :3, :3])
    for k, ((_, odom, _), (_, tf, _)) in enumerate(zip(got[ODOMETRY_TOPIC], got[TF_TOPIC])):
        p, o = odom.pose.pose.position, odom.pose.pose.orientation
        np.testing.assert_allclose([p.x, p.y, p.z], est.poses[k, :3, 3], atol=1e-9)
        np.testing.assert_allclose([o.x, o.y, o.z, o.w], q_file[k], atol=1e-9)  # tol: the file
        assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "camera_optical_frame")
        np.testing.assert_array_equal(odom.pose.covariance, np.zeros(36))  # unknown
        assert odom.twist.covariance[0] == -1.0  # no estimate
        (edge,) = tf.transforms
        assert (edge.header.frame_id, edge.child_frame_id) == ("odom", "camera_optical_frame")
        t, r = edge.transform.translation, edge.transform.rotation
        assert [t.x, t.y, t.z, r.x, r.y, r.z, r.w] == [p.x, p.y, p.z, o.x, o.y, o.z, o.w]
    # masks: --dynamic-masks' PNGs, pixel for pixel, in the colour camera's frame and size
    for (_, mask, _), png in zip(got[MASK_TOPIC], pngs):
        assert png.name == f"{stamp_ns(mask) / 1e9:.6f}.png"
        assert (mask.encoding, mask.header.frame_id) == ("mono8", "camera_optical_frame")
        img = np.asarray(mask.data).reshape(mask.height, mask.width)
        np.testing.assert_array_equal(img, cv2.imread(str(png), cv2.IMREAD_UNCHANGED))
    K = seq.intrinsics
    for _, info, _ in got[INFO_TOPIC]:
        np.testing.assert_array_equal(info.k, [K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1])
        assert (info.height, info.width) == (seq.height, seq.width)
    # the input: each frame's colour and depth as read (NaN for no reading, REP 118)
    for k, ((_, colour, _), (_, depth, _)) in enumerate(zip(got[TUM_TOPICS[0]],
                                                             got[TUM_TOPICS[1]])):
        f = seq[k]
        np.testing.assert_array_equal(np.asarray(colour.data).reshape(f.bgr.shape), f.bgr)
        d = np.frombuffer(bytes(depth.data), "<f4").reshape(f.depth.shape)
        np.testing.assert_array_equal(np.nan_to_num(d, nan=0.0), f.depth)
        assert depth.encoding == "32FC1" and np.isnan(d[f.depth == 0]).all()
    # the map: the PLY's points and colours, in the world frame, at the last frame's time
    ((t_map, cloud, _),) = got[MAP_TOPIC]
    ply_rows = read_ply(ply)
    assert cloud.width == len(ply_rows) == summary["map_points"] and cloud.header.frame_id == "odom"
    assert t_map == frame_ns[-1] and [f.name for f in cloud.fields] == ["x", "y", "z", "rgb"]
    rows = np.frombuffer(bytes(cloud.data), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                             ("rgb", "<u4")])
    for axis in "xyz":
        np.testing.assert_array_equal(rows[axis], ply_rows[axis])
    np.testing.assert_array_equal(rows["rgb"], (ply_rows["r"].astype(np.uint32) << 16)
                                  | (ply_rows["g"].astype(np.uint32) << 8) | ply_rows["b"])

    # the same file through the mcap library: ROS 2 schemas, CDR messages, the same bytes
    from mcap.reader import make_reader

    (mcap_file,) = bag.glob("*.mcap")
    with open(mcap_file, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        seen: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert (schema.encoding, channel.message_encoding) == ("ros2msg", "cdr")
            assert schema.name == got["_types"][channel.topic]
            seen.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    assert {t: len(v) for t, v in seen.items()} == counts
    for topic, messages in seen.items():
        assert messages == [(t, raw) for t, _, raw in got[topic]], topic


def ros2_input(path: Path, frames, K: Intrinsics) -> Path:
    """A ROS 2 bag as a robot records one: TUM's image topics (each recorded a moment after
    its stamp), an IMU, and its own /tf (map -> base_link), which jaxvo's /tf joins."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    with Writer2(path, version=9) as w:
        conns = [w.add_connection(t, m, typestore=ts) for t, m in (
            (TUM_TOPICS[0], "sensor_msgs/msg/Image"), (TUM_TOPICS[1], "sensor_msgs/msg/Image"),
            (TUM_TOPICS[2], "sensor_msgs/msg/CameraInfo"), ("/imu", "sensor_msgs/msg/Imu"),
            ("/tf", "tf2_msgs/msg/TFMessage"))]
        for k, f in enumerate(frames):
            t_ns = 1_305_031_102_175_304_123 + k * 33_333_333  # nanoseconds in the stamps
            t = t_ns / 1e9
            rgb = image_msg(ts, t, f.bgr[..., ::-1], "rgb8", False)
            rgb.header.stamp.sec, rgb.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
            depth = image_msg(ts, t, f.depth, "32FC1", False)
            depth.header.stamp = rgb.header.stamp
            w.write(conns[0], t_ns + 5000, ts.serialize_cdr(rgb, "sensor_msgs/msg/Image"))
            w.write(conns[1], t_ns + 7000, ts.serialize_cdr(depth, "sensor_msgs/msg/Image"))
            if k == 0:
                w.write(conns[2], t_ns, ts.serialize_cdr(
                    info_msg(ts, t, K, *f.bgr.shape[:2], False), "sensor_msgs/msg/CameraInfo"))
            for j in range(3):  # an IMU at 3 times the frame rate
                imu = T["sensor_msgs/msg/Imu"](
                    header=rgb.header, orientation=T["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
                    angular_velocity=T["geometry_msgs/msg/Vector3"](x=0.1 * j, y=0.0, z=0.0),
                    angular_velocity_covariance=np.zeros(9),
                    linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=9.81),
                    linear_acceleration_covariance=np.zeros(9))
                w.write(conns[3], t_ns + j * 11_111_111, ts.serialize_cdr(imu, "sensor_msgs/msg/Imu"))
            edge = T["geometry_msgs/msg/TransformStamped"](
                header=T["std_msgs/msg/Header"](stamp=rgb.header.stamp, frame_id="map"),
                child_frame_id="base_link", transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=0.01 * k, y=0.0, z=0.0),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)))
            w.write(conns[4], t_ns, ts.serialize_cdr(T["tf2_msgs/msg/TFMessage"](
                transforms=[edge]), "tf2_msgs/msg/TFMessage"))
    return path


def test_a_ros2_bag_written_back_with_its_input_keeps_every_message(tmp_path, capsys):
    """SQLite 3 storage; the input's every message at its own bag time, byte for byte; the
    odometry stamped with the colour images' header stamps to the nanosecond and recorded at
    their bag times."""
    seq = make_sequence("handheld_fast", frames=4, seed=2)
    src = ros2_input(tmp_path / "robot", [seq[i] for i in range(4)], seq.intrinsics)
    bag = tmp_path / "out"
    code, out, err = cli(capsys, "run", src, "--out", tmp_path / "t.txt", "--out-bag", bag,
                         "--with-input", "--bag-storage", "sqlite3", "-q", "--json")
    assert code == 0, err
    assert list(bag.glob("*.db3")) and "storage_identifier: sqlite3" in (
        bag / "metadata.yaml").read_text()
    before, after = read_bag(src), read_bag(bag)
    for topic in ("/imu", *TUM_TOPICS):
        assert [(t, raw) for t, _, raw in after[topic]] == [(t, raw) for t, _, raw in
                                                           before[topic]], topic
    theirs = [(t, raw) for t, _, raw in before["/tf"]]
    ours = [(t, raw) for t, m, raw in after["/tf"] if m.transforms[0].child_frame_id ==
            "base_link"]
    assert ours == theirs and len(after["/tf"]) == len(theirs) + 4  # and jaxvo's four
    assert json.loads(out)["bag_input_messages"] == sum(len(before[t]) for t in before
                                                        if t != "_types")
    colour = before[TUM_TOPICS[0]]
    assert [stamp_ns(m) for _, m, _ in after[ODOMETRY_TOPIC]] == [stamp_ns(m) for _, m, _ in
                                                                  colour]
    assert [t for t, _, _ in after[ODOMETRY_TOPIC]] == [t for t, _, _ in colour]


@pytest.mark.parametrize("kind", ["ros1", "realsense"])
def test_a_ros1_bag_with_its_input_is_converted_message_for_message(tmp_path, capsys, kind):
    """A ROS 1 bag's messages converted as rosbags-convert converts them (a RealSense
    recording's images without librealsense's depth units after the data): each topic's
    every message, its fields as before."""
    seq = make_sequence("handheld_fast", frames=3, seed=2)
    frames = [seq[i] for i in range(3)]
    src = (write_bag(tmp_path / "in.bag", frames, ros1=True) if kind == "ros1" else
           write_realsense(tmp_path / "in.bag", frames, seq.intrinsics))
    bag = tmp_path / "out"
    code, _, err = cli(capsys, "run", src, "--out", tmp_path / "t.txt", "--out-bag", bag,
                       "--with-input", "-q")
    assert code == 0, err
    after = read_bag(bag)
    with AnyReader([src]) as reader:
        for conn in reader.connections:
            mine = after[conn.topic]
            theirs = list(reader.messages(connections=[conn]))
            assert [t for t, _, _ in mine] == [t for _, t, _ in theirs], conn.topic
            if conn.msgtype == "sensor_msgs/msg/Image":
                for (_, m, _), (_, _, raw) in zip(mine, theirs):
                    old = image_message(reader, raw)[0]
                    assert (m.encoding, m.width, m.height) == (old.encoding, old.width,
                                                               old.height)
                    np.testing.assert_array_equal(m.data, old.data)
                    assert stamp_ns(m) == stamp_ns(old)


# --- whole or nothing ------------------------------------------------------------------


def test_targets_refused_before_any_work(folder, tmp_path, capsys):
    bag2 = write_bag(tmp_path / "in2", [make_sequence("static", frames=2, seed=0)[i]
                                        for i in range(2)], ros1=False)
    existing = tmp_path / "existing"
    existing.mkdir()
    (existing / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    listing = sorted(p.name for p in existing.iterdir())
    cases = [
        ((bag2, "--out-bag", bag2), ("--out-bag", "which this command reads")),
        ((folder, "--out-bag", folder), ("--out-bag", "which this command reads")),
        ((folder, "--out-bag", existing), ("is an existing bag; give a new folder",)),
        ((folder, "--out-bag", folder / "rgb.txt"), ("which this command reads",)),
        ((folder, "--out-bag", tmp_path / "no" / "such" / "bag"), ("does not exist",)),
        ((folder, "--bag-storage", "sqlite3"), ("--bag-storage: for a bag; pass --out-bag",)),
        ((folder, "--out-bag", tmp_path / "b", "--world-frame", "/odom"),
         ("--world-frame '/odom'",)),
        ((folder, "--out-bag", tmp_path / "b", "--camera-frame", "odom"),
         ("--world-frame and --camera-frame are both 'odom'",)),
    ]
    for (src, *rest), needles in cases:
        code, _, err = cli(capsys, "run", src, "--out", tmp_path / "t.txt", *rest)
        one_line_error(code, err, *needles)
    assert sorted(p.name for p in existing.iterdir()) == listing  # nothing in it changed
    code, _, err = cli(capsys, "run", folder, "--out", tmp_path / "b" / "t.txt",
                       "--out-bag", tmp_path / "b")
    one_line_error(code, err, "lies in the folder of --out-bag")
    assert not (tmp_path / "b").exists()


def test_an_input_bag_that_holds_jaxvos_topics_is_refused_with_input(folder, tmp_path,
                                                                       capsys):
    """A run's bag (written --with-input) given again --with-input: its odometry and /tf
    were copied beside the new run's, 12 odometry messages on one topic at 6 stamps, and
    nothing said. Refused in one line, naming the topic, before any work; without
    --with-input the bag is read as any other."""
    first = tmp_path / "first"
    code, _, err = cli(capsys, "run", folder, "--out", tmp_path / "t1.txt", "--out-bag",
                       first, "--with-input", "-q")
    assert code == 0, err
    code, _, err = cli(capsys, "run", first, "--out", tmp_path / "t2.txt", "--out-bag",
                       tmp_path / "second", "--with-input", "-q")
    one_line_error(code, err, f"--with-input: {first} already holds {ODOMETRY_TOPIC}")
    assert not (tmp_path / "t2.txt").exists() and not (tmp_path / "second").exists()
    code, _, err = cli(capsys, "run", first, "--out", tmp_path / "t2.txt", "--out-bag",
                       tmp_path / "second", "-q")
    assert code == 0, err
    assert len(read_bag(tmp_path / "second")[ODOMETRY_TOPIC]) == N


def test_an_unwritable_folder_is_one_line(folder, tmp_path, capsys):
    import os

    if os.geteuid() != 0:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
    else:  # root writes anywhere on a normal file system; sysfs refuses new folders to all
        ro = Path("/sys/kernel")
        if not ro.is_dir():
            pytest.skip("running as root without /sys: no folder refuses writes")
    code, _, err = cli(capsys, "run", folder, "--out", tmp_path / "t.txt", "--out-bag",
                       ro / "bag")
    one_line_error(code, err, f"--out-bag {ro / 'bag'}: cannot write in {ro}")


def test_ctrl_c_during_the_frames_keeps_a_whole_bag_of_what_was_computed(
        folder, tmp_path, capsys, monkeypatch):
    """As the trajectory file keeps every pose computed, the bag is finished with them."""
    from jaxvo.odometry import Odometry

    real_submit = Odometry.submit
    calls = {"n": 0}

    def submit(self, *a, **kw):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real_submit(self, *a, **kw)

    monkeypatch.setattr(Odometry, "submit", submit)
    bag = tmp_path / "bag"
    code, out, _ = cli(capsys, "run", folder, "--out", tmp_path / "t.txt", "--out-bag", bag,
                         "-q", "--json")
    assert code == 130 and json.loads(out)["interrupted"]
    got = read_bag(bag)
    assert len(got[ODOMETRY_TOPIC]) == len(read_trajectory(tmp_path / "t.txt")) == 3
    assert len(got[MASK_TOPIC]) == 3
    no_leftovers(bag)


def test_ctrl_c_after_the_frames_finishes_the_bag_as_the_trajectory(folder, tmp_path, capsys,
                                                                   monkeypatch):
    """A Ctrl-C after the last frame (here while the bag is finished; a long --with-input
    copy) asks the run to stop: the bag is still finished, whole with every frame, as the
    trajectory is put in place with every pose, and the run says it was interrupted."""
    import os
    import signal

    real = bagout.BagWriter.finish

    def finish(self):
        os.kill(os.getpid(), signal.SIGINT)  # the first Ctrl-C: a request, no exception
        return real(self)

    monkeypatch.setattr(bagout.BagWriter, "finish", finish)
    bag = tmp_path / "bag"
    code, out, _ = cli(capsys, "run", folder, "--out", tmp_path / "t.txt", "--out-bag", bag,
                       "-q", "--json")
    assert code == 130 and json.loads(out)["interrupted"]
    assert len(read_bag(bag)[ODOMETRY_TOPIC]) == len(read_trajectory(tmp_path / "t.txt")) == N
    no_leftovers(bag)


@pytest.mark.parametrize("fail_in, error, named", [
    # the run's thread, the error naming its file
    ("write_mask", OSError(28, "No space left on device", "bag.mcap"), "bag.mcap"),
    # the bag's thread, as rosbags' MCAP writer fails on a full disk: no file named
    ("_write_mask", OSError(28, "No space left on device"), "bag/bag.mcap"),
    ("finish", KeyboardInterrupt(), None),  # Ctrl-C after the frames, while it is finished
], ids=["disk-full", "disk-full-on-the-bag-thread", "ctrl-c-at-the-end"])
def test_a_bag_that_cannot_be_finished_leaves_nothing(folder, tmp_path, capsys, monkeypatch,
                                                      fail_in, error, named):
    """A bag that fails (a full disk) said 'No space left on device' naming no file, and
    the run's trajectory, on a disk that may be healthy, was discarded with it. Now the
    bag's file is named, the run stops at the next frame and the trajectory keeps the poses
    computed; the bag is not written."""
    calls = {"n": 0}
    real = getattr(bagout.BagWriter, fail_in)

    def failing(self, *a, **kw):
        calls["n"] += 1
        if calls["n"] == 2 or fail_in == "finish":  # the bag open, half written
            raise error
        return real(self, *a, **kw)

    monkeypatch.setattr(bagout.BagWriter, fail_in, failing)
    bag = tmp_path / "bag"
    code, _, err = cli(capsys, "run", folder, "--out", tmp_path / "t.txt", "--out-bag", bag,
                       "-q")
    if isinstance(error, OSError):
        one_line_error(code, err, f"{tmp_path / named if '/' in named else named}: No space "
                       "left on device")
    else:
        assert code == 130 and "interrupted" in err
    assert 1 <= len(read_trajectory(tmp_path / "t.txt")) <= N
    assert not bag.exists()
    no_leftovers(bag)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_full_disk_under_the_bag_names_its_file_and_keeps_the_trajectory(
        folder, tmp_path, storage):
    """A real full disk (a 300 KiB tmpfs in a user namespace, where the kernel allows one)
    under --out-bag, the trajectory on a healthy disk: one line naming the bag's file (MCAP
    fails during the frames, SQLite when the bag is closed), exit 2, the trajectory whole
    with the poses computed, nothing left on the full disk."""
    import os
    import shlex
    import signal
    import subprocess
    import sys

    mount, traj = tmp_path / "small", tmp_path / "t.txt"
    mount.mkdir()
    run = [sys.executable, "-c", "import sys; from jaxvo.cli.main import main; "
           "sys.exit(main())", "run", str(folder), "--out", str(traj), "--out-bag",
           str(mount / "bag"), "--bag-storage", storage, "-q"]
    shell = (f"mount -t tmpfs -o size=300k tmpfs {mount} && {shlex.join(run)}; echo $?; "
             f"ls -A {mount}")
    proc = subprocess.Popen(["unshare", "-rm", "sh", "-c", shell], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the run never ended")
    if "jaxvo" not in err and "mount" in err:
        pytest.skip(f"no tmpfs in a user namespace here: {err.strip()[:200]}")
    suffix = ".mcap" if storage == "mcap" else ".db3"
    assert out == "2\n", (out, err[-2000:])  # the exit status, and nothing on the disk
    assert err.startswith(f"jaxvo: error: {mount / 'bag' / ('bag' + suffix)}: No space left "
                          "on device") and err.count("\n") == 1, err[-2000:]
    assert 1 <= len(read_trajectory(traj)) <= N
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small", "t.txt"]


# --- the pieces -------------------------------------------------------------------------


@pytest.mark.parametrize("storage, suffix", [("mcap", ".mcap"), ("sqlite3", ".db3")])
def test_the_storage_file_is_named_after_the_bag_not_its_temporary_folder(
        folder, tmp_path, storage, suffix):
    """rosbags names the storage file after the folder it writes in: the bag is written in
    a folder of the target's own name (inside a hidden one), so that the file is
    ``run_bag/run_bag.mcap`` as docs/ros.md says, and metadata.yaml lists that name."""
    from ruamel.yaml import YAML  # rosbags' own YAML library

    bag = tmp_path / "run_bag"
    name = f"run_bag{suffix}"
    with bagout.BagWriter(bag, open_sequence(folder), storage=storage) as writer:
        writer.write_pose(0, np.eye(4))
        # what a failure names: the bag's files where the user finds them, another as is
        assert writer._where(None) == bag / name
        assert writer._where(str(writer._out.temporary / "metadata.yaml")) == (
            bag / "metadata.yaml")
        assert writer._where(str(folder / "rgb.txt")) is None
        writer.finish()
    assert sorted(p.name for p in bag.iterdir()) == sorted(["metadata.yaml", name])
    info = YAML(typ="safe").load((bag / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"]
    assert info["relative_file_paths"] == [name]
    assert [f["path"] for f in info["files"]] == [name]
    assert len(read_bag(bag)[ODOMETRY_TOPIC]) == 1
    no_leftovers(bag)


def test_a_second_ctrl_c_leaves_no_bag_and_nothing_beside(folder, tmp_path):
    """A second Ctrl-C ends the process at once, settling the outputs being written first
    (abort_pending): the bag's temporary folder is one of them, removed as a half-written
    file is, so that nothing of the bag outlives the process."""
    import time

    from jaxvo.host.writers.outputs import abort_pending

    bag = tmp_path / "bag"
    writer = bagout.BagWriter(bag, open_sequence(folder))
    writer.write_pose(0, np.eye(4))
    for _ in range(500):  # rosbags makes the folder on the bag's thread
        if any(bag.parent.glob(f".{bag.name}.*/*")):
            break
        time.sleep(0.01)
    else:
        pytest.fail("the bag's temporary folder was never made")
    abort_pending()
    assert not bag.exists()
    no_leftovers(bag)
    writer.abort()  # its thread (the process would have ended)
    assert not bag.exists()
    no_leftovers(bag)


def test_frame_ids_and_times():
    assert check_frame_id("base_link", what="--camera-frame") == "base_link"
    for bad in ("", "a b", "/odom"):
        with pytest.raises(InputError, match="frame id"):
            check_frame_id(bad, what="--world-frame")

    class Seq:
        name = "s"
        timestamps = np.array([1305031102.175304, 1305031102.211214])

    stamps, record = frame_times(Seq)
    assert stamps.tolist() == record.tolist() == [1305031102175304000, 1305031102211214000]
    Seq.timestamps = np.array([-1.0, 0.0])
    with pytest.raises(InputError, match="cannot be negative"):
        frame_times(Seq)
