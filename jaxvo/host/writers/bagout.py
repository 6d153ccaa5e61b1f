"""A run's results as a ROS 2 bag, on the input's own clock (host side).

``jaxvo run INPUT --out-bag DIR`` writes a rosbag2 folder (MCAP storage by default, SQLite 3
on request) with ``rosbags``' writer and its typesys serialisation (CDR), so that a
robotics engineer replays jaxvo's answer beside the input in Foxglove, RViz or ``ros2 bag
play``:

=========================  ==============================  ==========================================
topic                      type                            what
=========================  ==============================  ==========================================
``/jaxvo/odometry``        ``nav_msgs/msg/Odometry``       each kept frame's pose, camera to world
``/tf``                    ``tf2_msgs/msg/TFMessage``      the same pose: world frame -> camera frame
``/jaxvo/dynamic_mask``    ``sensor_msgs/msg/Image``       mono8, 255 = moving, registered to colour
``/jaxvo/camera_info``     ``sensor_msgs/msg/CameraInfo``  the colour camera the mask is registered to
``/jaxvo/overlay``         ``sensor_msgs/msg/Image``       bgr8 tinted by identifier (``--bag-overlay``)
``/jaxvo/static_map``      ``sensor_msgs/msg/PointCloud2`` the static map, once at the end (``--map``)
=========================  ==============================  ==========================================

With ``--with-input`` the input's messages are in it too: a bag's every message copied
through (a ROS 2 bag's bytes as they are; a ROS 1 bag's converted by ``rosbags``'
converter), a folder's frames written on TUM's bag topics (colour ``bgr8``, depth
``32FC1`` metres with NaN for no reading as REP 118 and REP 117 say, camera info), which
``jaxvo run`` reads by default.

Time: every message's ``header.stamp`` is its frame's own sensor time (a bag's image header
stamp to the nanosecond; a folder's ``rgb.txt`` time to the microsecond it is written
with), and it is recorded at the time the input recorded that frame (a bag's colour image's
bag time, else the stamp), so copied input and jaxvo's topics replay together.

Frames (REP 103, REP 105): the camera frame is the colour camera's optical frame (z forward,
x right, y down: REP 103's ``_optical`` suffix; default ``camera_optical_frame``); the world
frame is REP 105's ``odom`` (continuous, drifting, from an odometry source) and has the axes
of jaxvo's trajectory: the first camera's optical axes, or the ground truth's world where
the ground truth gave the first pose. The tf tree holds that one edge, world -> camera.

Covariance: jaxvo's fit gives no covariance of the pose, so the pose covariance is all
zeros, which ROS's message definitions read as "covariance unknown"; jaxvo gives no
velocity, so the twist is zero with its covariance's element 0 at -1, "no estimate"
(``sensor_msgs/msg/Imu``'s stated conventions, the ones ROS writes down).

Whole or nothing, as every output of jaxvo (:class:`jaxvo.host.writers.outputs.OutputFolder`): the
bag is written in a folder of the target's name inside a hidden temporary folder beside the
target (so its storage file is ``NAME/NAME.mcap``, as ``rosbags`` names it after its folder)
and renamed onto it once finished; a failure, or an exception that leaves before
:meth:`BagWriter.finish` (a second Ctrl-C too), removes the temporary folder and leaves
nothing at the target. A failure names the bag's file as the user finds it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import os
from pathlib import Path
from typing import NamedTuple, Self

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.prefetch import BackgroundWriter
from jaxvo.host.writers.outputs import OutputFolder

ODOMETRY_TOPIC = "/jaxvo/odometry"
TF_TOPIC = "/tf"
MASK_TOPIC = "/jaxvo/dynamic_mask"
INFO_TOPIC = "/jaxvo/camera_info"  # image_transport's camera_info beside the mask
OVERLAY_TOPIC = "/jaxvo/overlay"
MAP_TOPIC = "/jaxvo/static_map"
# REP 105's odometry frame, REP 103's optical frame suffix
WORLD_FRAME = "odom"
CAMERA_FRAME = "camera_optical_frame"
STORAGES = ("mcap", "sqlite3")
# the storage file's suffix, as rosbags names it after the bag's folder
_SUFFIX = {"mcap": ".mcap", "sqlite3": ".db3"}
# the message definitions written: ROS 2 Jazzy's (rosbag2 metadata version 9 is Jazzy's)
_STORE = "ros2_jazzy"
_BAG_VERSION = 9
# sensor_msgs/msg/PointField.FLOAT32
_FLOAT32 = 7
# calls waiting for the bag's thread: a few frames' messages (their images are held)
_QUEUE = 16


class Frames(NamedTuple):
    """The tf frame names the bag uses."""

    world: str = WORLD_FRAME  # the odometry's fixed frame
    camera: str = CAMERA_FRAME  # the colour camera's optical frame


def check_frame_id(name: str, *, what: str) -> str:
    """A tf2 frame id as ROS 2 takes it: not empty, no white space, no leading ``/``."""
    if not name or any(c.isspace() for c in name) or name.startswith("/"):
        raise InputError(f"{what} {name!r}: a frame id is a name without spaces or a leading "
                         "'/' (e.g. odom, camera_optical_frame)")
    return name


@dataclasses.dataclass(frozen=True)
class BagOptions:
    """``jaxvo run``'s ROS 2 bag output: ``--out-bag`` and the options that go with it."""

    folder: str | Path | None = None  # the new bag folder (--out-bag); None: no bag
    storage: str | None = None  # --bag-storage (None: mcap)
    world_frame: str | None = None  # --world-frame (None: WORLD_FRAME)
    camera_frame: str | None = None  # --camera-frame (None: CAMERA_FRAME)
    overlay: bool = False  # --bag-overlay: also the image tinted by identifier
    with_input: bool = False  # --with-input: also the input's messages or frames


# the command-line option of each BagOptions field but the folder, for messages
_BAG_OPTIONS = {"storage": "--bag-storage", "world_frame": "--world-frame",
                "camera_frame": "--camera-frame", "overlay": "--bag-overlay",
                "with_input": "--with-input"}


def check_bag_options(options: BagOptions) -> None:
    """``jaxvo run``'s bag options checked before any work: none without ``--out-bag``,
    frame ids ROS takes, and two different frames."""
    if not options.folder:
        given = [flag for name, flag in _BAG_OPTIONS.items() if getattr(options, name)]
        if given:
            raise InputError(f"{', '.join(given)}: for a bag; pass --out-bag DIR")
        return
    world = check_frame_id(options.world_frame or WORLD_FRAME, what="--world-frame")
    camera = check_frame_id(options.camera_frame or CAMERA_FRAME, what="--camera-frame")
    if world == camera:
        raise InputError(f"--world-frame and --camera-frame are both {world!r}; the tf edge "
                         "joins two frames")


def open_bag(options: BagOptions, seq, *, cell: int):
    """The :class:`BagWriter` of ``options`` (checked by :func:`check_bag_options`) for a run
    over ``seq`` with ``cell``-pixel grid cells, or a context of None without a folder."""
    if not options.folder:
        return contextlib.nullcontext()
    frames = Frames(options.world_frame or WORLD_FRAME, options.camera_frame or CAMERA_FRAME)
    return BagWriter(options.folder, seq, storage=options.storage or "mcap", frames=frames,
                     with_input=options.with_input,
                     overlay_cell=cell if options.overlay else None, what="--out-bag")


def check_bag_target(path: str | Path, *, what: str = "--out-bag") -> Path:
    """``path`` as a new bag folder this run can write, checked before any work.

    The bag is written beside it and renamed onto it when complete (an
    :class:`~jaxvo.host.writers.outputs.OutputFolder`), so the folder must not exist yet (or be
    empty), and its parent must take the temporary folder (made and removed here: nothing
    is left).

    Raises:
      InputError: it is a file, a folder that holds anything (an existing bag), or its
        parent is missing or cannot be written.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{what} {p}: exists and is not a folder; give a new folder for the "
                         "bag")
    if p.is_dir() and any(p.iterdir()):
        kind = "an existing bag" if (p / "metadata.yaml").exists() else "a folder with files"
        raise InputError(f"{what} {p}: is {kind}; give a new folder (nothing in it is changed)")
    parent = p.absolute().parent
    if not parent.is_dir():
        raise InputError(f"{what} {p}: folder {parent} does not exist")
    try:
        OutputFolder(p, what=what).discard()  # the bag's temporary folder, made and removed
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write in {parent} ({exc.strerror})") from None
    return p


# the topics jaxvo writes and no sensor does: an input that holds one is a jaxvo run's bag
_OWN_TOPICS = (ODOMETRY_TOPIC, MASK_TOPIC, INFO_TOPIC, OVERLAY_TOPIC, MAP_TOPIC)


def check_bag_input(options: BagOptions, seq) -> None:
    """With ``--with-input``, an input bag that already holds jaxvo's topics (a run's bag
    given again) refused before any work: copied beside this run's messages, two runs'
    odometry, masks and ``/tf`` edges would share one topic at the same stamps.

    Raises:
      InputError: naming the input and the first of jaxvo's topics it holds.
    """
    from jaxvo.host.readers.rosbag import is_bag, open_reader

    path = getattr(seq, "path", "")
    if not (options.folder and options.with_input and is_bag(path)):
        return
    with contextlib.closing(open_reader(Path(path))) as reader:
        topics = {c.topic for c in reader.connections}
    held = [t for t in _OWN_TOPICS if t in topics]
    if held:
        raise InputError(f"--with-input: {path} already holds {held[0]} (a jaxvo run's bag?); "
                         "copied with this run's, two runs' odometry and /tf would share "
                         "their topics; give the bag the first run read, or leave out "
                         "--with-input")


def frame_times(seq) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's header stamp and record time, int64 nanoseconds (N,) each.

    A bag's (``BagSequence.stamps_ns``, ``record_ns``): its images' own header stamps and
    the bag times its colour images were recorded at. Else the timestamps to the
    microsecond (what TUM's lists and jaxvo's trajectory files write) as both.
    """
    stamps = getattr(seq, "stamps_ns", None)
    if stamps is not None:
        return np.asarray(stamps, np.int64), np.asarray(seq.record_ns, np.int64)
    t = np.asarray(seq.timestamps, np.float64)
    if t.size and not (np.all(np.isfinite(t)) and t.min() >= 0):
        raise InputError(f"{seq.name}: a ROS time cannot be negative or not a number (first "
                         f"frame {t[0]:g} s); --out-bag needs times from 0 on")
    ns = np.round(t * 1e6).astype(np.int64) * 1000  # t * 1e6 < 2**53: exact microseconds
    return ns, ns


class BagWriter:
    """Writes a run's results into a new ROS 2 bag, whole or not at all.

    The ``write_*`` methods return at once: the messages are built, serialised and written
    on the bag's own thread (a :class:`~jaxvo.host.frontend.prefetch.BackgroundWriter`, bounded, in
    the order given), so writing overlaps the run's computation; every ``rosbags`` call is
    made there (SQLite takes its connection on one thread only). A failure there is raised
    by a later ``write_*`` or by :meth:`finish`. The bag is an
    :class:`~jaxvo.host.writers.outputs.OutputFolder` (made by ``rosbags`` at its temporary path):
    :meth:`finish` puts it in place; as a context manager, leaving by an exception (or
    before :meth:`finish`) removes everything written, and so does a second Ctrl-C
    (:func:`~jaxvo.host.writers.outputs.abort_pending`).

    Args:
      target: the bag folder to create (checked by :func:`check_bag_target`).
      seq: the sequence the run reads (its camera, size and frame times).
      storage: ``"mcap"`` or ``"sqlite3"``.
      frames: the tf frame names.
      with_input: also write the input: a bag's messages (copied by :meth:`finish`) or,
        for a folder, each frame given to :meth:`write_frame`.
      overlay_cell: the grid's cell size, pixels, to write each mask's frame tinted by
        identifier (``--bag-overlay``); None: no overlay.
      what: how to name the target in messages (default: the path).
    """

    def __init__(self, target: str | Path, seq, *, storage: str = "mcap",
                 frames: Frames | None = None, with_input: bool = False,
                 overlay_cell: int | None = None, what: str | None = None) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        from jaxvo.host.readers.rosbag import is_bag

        if storage not in STORAGES:
            raise InputError(f"bag storage {storage!r}: one of {', '.join(STORAGES)}")
        self.target = Path(target)
        # the storage file as the user finds it, what a failure names
        self.storage_file = self.target / f"{self.target.name}{_SUFFIX[storage]}"
        self.error: OSError | None = None  # the first failure on the bag's thread
        self.frames = frames or Frames()
        self.overlay_cell = overlay_cell
        self.stamps_ns, self.record_ns = frame_times(seq)
        self.input_bag = Path(seq.path) if with_input and is_bag(getattr(seq, "path", "")) else None
        self.input_frames = with_input and self.input_bag is None
        self.ts = get_typestore(Stores(_STORE))
        # the folder whole or not at all; rosbags makes it at the temporary path (it refuses
        # a folder that exists), on the bag's thread
        self._out = OutputFolder(self.target, what=what, make_folder=False)
        self._writer = Writer(self._out.temporary, version=_BAG_VERSION,
                              storage_plugin=StoragePlugin[storage.upper()])
        self._conns: dict[str, object] = {}
        self._info = self._camera_info(seq.intrinsics, seq.height, seq.width)
        self._summary: dict = {}
        self._dry = False  # serialise, do not write (_open)
        self.finished = False
        self._thread = BackgroundWriter(limit=_QUEUE)
        self._submit(self._open, seq.height, seq.width)

    def _submit(self, fn, *args) -> None:
        """``fn(*args)`` on the bag's thread, a failure named (:meth:`_named`)."""
        self._thread.submit(self._named, fn, *args)

    def _named(self, fn, *args) -> None:
        """``fn(*args)``; a failure of the bag's files (a full disk: rosbags' and SQLite's
        errors name no file, or the temporary folder's) as an ``OSError`` naming the bag's
        file where the user will find it, kept so that :meth:`finish` never puts in place
        a bag that failed."""
        import sqlite3

        try:
            fn(*args)
        except OSError as exc:
            where = self._where(exc.filename)
            self.error = exc if where is None else OSError(exc.errno, exc.strerror or str(exc),
                                                           str(where))
            raise self.error from None
        except sqlite3.Error as exc:  # "database or disk is full"
            full = "full" in str(exc)
            self.error = OSError(errno.ENOSPC if full else errno.EIO, os.strerror(
                errno.ENOSPC) if full else f"SQLite: {exc}", str(self.storage_file))
            raise self.error from None

    def _where(self, filename) -> Path | None:
        """The file an error names, as the user will find it: the storage file where it
        names none, the place in the target of one in the temporary folder, None for
        another file (the input bag read: named as it is)."""
        if not filename:
            return self.storage_file
        try:
            return self.target / Path(filename).relative_to(self._out.temporary)
        except ValueError:
            return None

    def write_pose(self, index: int, T_w_c: np.ndarray) -> None:
        """Frame ``index``'s pose (camera to world, (4, 4)) as odometry and as tf."""
        self._submit(self._write_pose, index, np.array(T_w_c, np.float64))

    def write_mask(self, frame, mask: np.ndarray, output=None) -> None:
        """A frame's dynamic mask ((H, W) uint8, 255 = moving, as ``--dynamic-masks`` writes
        it) and the camera it is registered to; with ``overlay_cell``, the frame tinted by
        the identifiers of ``output`` (its pair's ``StepOutput``; None: no overlay)."""
        self._submit(self._write_mask, frame, mask, output)

    def write_frame(self, frame) -> None:
        """With ``with_input`` from a folder: the frame's colour, depth and camera on TUM's
        bag topics (what ``jaxvo run`` reads from a bag by default); else nothing."""
        if self.input_frames:
            self._submit(self._write_frame, frame)

    def write_map(self, pmap, index: int) -> None:
        """The static map (:class:`jaxvo.host.writers.mapping.PointMap`, world frame) as one
        ``PointCloud2`` (x y z float32 and PCL's packed ``rgb``), at frame ``index``'s time."""
        self._submit(self._write_map, pmap, index)

    # -- messages ----------------------------------------------------------------------

    def _open(self, height: int, width: int) -> None:
        """Open the bag, add its topics, and make each message type's serialiser (``rosbags``
        generates it on first use) by serialising a frame's messages without writing them:
        the one-time work, done while the run reads its first frame and loads its step,
        not among the run's steady frames."""
        from jaxvo.host.frontend.frames import Frame

        self._writer.open()
        blank = Frame(0, 0.0, np.zeros((height, width, 3), np.uint8),
                      np.zeros((height, width), np.float32), None)
        self._dry = True
        try:
            self._write_pose(0, np.eye(4))
            self._write_mask(blank, blank.depth.astype(np.uint8), None)
            if self.overlay_cell is not None:
                self._conn(OVERLAY_TOPIC, "sensor_msgs/msg/Image")
            if self.input_frames:
                self._write_frame(blank)
        finally:
            self._dry = False

    def _conn(self, topic: str, msgtype: str):
        conn = self._conns.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.ts)
            self._conns[topic] = conn
        return conn

    def _write(self, topic: str, msgtype: str, record_ns: int, msg) -> None:
        conn, data = self._conn(topic, msgtype), self.ts.serialize_cdr(msg, msgtype)
        if not self._dry:
            self._writer.write(conn, int(record_ns), data)

    def _header(self, stamp_ns: int, frame_id: str):
        T = self.ts.types
        sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=nsec), frame_id=frame_id)

    def _image(self, stamp_ns: int, img: np.ndarray, encoding: str):
        """A ``sensor_msgs/msg/Image`` of ``img`` ((H, W) or (H, W, C), little-endian)."""
        h, w = img.shape[:2]
        data = np.ascontiguousarray(img).view(np.uint8).reshape(-1)
        return self.ts.types["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, self.frames.camera), height=h, width=w,
            encoding=encoding, is_bigendian=0, step=data.size // h, data=data)

    def _camera_info(self, K, height: int, width: int):
        T = self.ts.types
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                    do_rectify=False)
        k = np.array([K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1], np.float64)
        p = np.array([K.fx, 0, K.cx, 0, 0, K.fy, K.cy, 0, 0, 0, 1, 0], np.float64)
        # images jaxvo reads are pinhole (undistorted): plumb_bob with zero coefficients
        return lambda stamp_ns: T["sensor_msgs/msg/CameraInfo"](
            header=self._header(stamp_ns, self.frames.camera), height=height, width=width,
            distortion_model="plumb_bob", d=np.zeros(5), k=k, r=np.eye(3).reshape(-1), p=p,
            binning_x=0, binning_y=0, roi=roi)

    def _pose(self, T_w_c: np.ndarray):
        from jaxvo.transforms import rotation_to_quat

        T = np.asarray(T_w_c, np.float64)
        qx, qy, qz, qw = (float(v) for v in rotation_to_quat(T[:3, :3]))
        return [float(v) for v in T[:3, 3]], (qx, qy, qz, qw)

    def _write_pose(self, index: int, T_w_c: np.ndarray) -> None:
        T = self.ts.types
        (x, y, z), (qx, qy, qz, qw) = self._pose(T_w_c)
        stamp, at = self.stamps_ns[index], self.record_ns[index]
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z),
            orientation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))
        no_estimate = np.zeros(36)
        no_estimate[0] = -1.0
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        odom = T["nav_msgs/msg/Odometry"](
            header=self._header(stamp, self.frames.world), child_frame_id=self.frames.camera,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
                covariance=no_estimate))
        self._write(ODOMETRY_TOPIC, "nav_msgs/msg/Odometry", at, odom)
        tf = T["geometry_msgs/msg/TransformStamped"](
            header=self._header(stamp, self.frames.world), child_frame_id=self.frames.camera,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)))
        self._write(TF_TOPIC, "tf2_msgs/msg/TFMessage", at,
                    T["tf2_msgs/msg/TFMessage"](transforms=[tf]))

    def _write_mask(self, frame, mask: np.ndarray, output) -> None:
        stamp, at = self.stamps_ns[frame.index], self.record_ns[frame.index]
        self._write(MASK_TOPIC, "sensor_msgs/msg/Image", at, self._image(stamp, mask, "mono8"))
        self._write(INFO_TOPIC, "sensor_msgs/msg/CameraInfo", at, self._info(stamp))
        if self.overlay_cell is not None and output is not None:
            from jaxvo.host.writers.masks import overlay

            tinted = overlay(frame.bgr, output.ids, self.overlay_cell)
            self._write(OVERLAY_TOPIC, "sensor_msgs/msg/Image", at,
                        self._image(stamp, tinted, "bgr8"))

    def _write_frame(self, frame) -> None:
        from jaxvo.host.readers.rosbag import TUM_TOPICS

        stamp, at = self.stamps_ns[frame.index], self.record_ns[frame.index]
        depth = np.where(frame.depth > 0, frame.depth, np.float32(np.nan)).astype("<f4")
        rgb, dep, info = TUM_TOPICS
        self._write(rgb, "sensor_msgs/msg/Image", at, self._image(stamp, frame.bgr, "bgr8"))
        self._write(dep, "sensor_msgs/msg/Image", at, self._image(stamp, depth, "32FC1"))
        self._write(info, "sensor_msgs/msg/CameraInfo", at, self._info(stamp))

    def _write_map(self, pmap, index: int) -> None:
        T = self.ts.types
        n = len(pmap.points)
        rows = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
        for i, axis in enumerate("xyz"):
            rows[axis] = pmap.points[:, i]
        c = np.asarray(pmap.colours, np.uint32)
        rows["rgb"] = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]  # 0x00RRGGBB, read as float32
        fields = [T["sensor_msgs/msg/PointField"](name=name, offset=4 * i, datatype=_FLOAT32,
                                                  count=1) for i, name in enumerate(("x", "y", "z", "rgb"))]
        cloud = T["sensor_msgs/msg/PointCloud2"](
            header=self._header(self.stamps_ns[index], self.frames.world), height=1, width=n,
            fields=fields, is_bigendian=False, point_step=16, row_step=16 * n,
            data=rows.view(np.uint8).reshape(-1), is_dense=True)
        self._write(MAP_TOPIC, "sensor_msgs/msg/PointCloud2", self.record_ns[index], cloud)

    # -- the input, the end --------------------------------------------------------------

    def _copy_input(self) -> int:
        """Every message of the input bag, each at its own bag time: a ROS 2 bag's bytes as
        they are, a ROS 1 bag's converted as ``rosbags-convert`` converts them."""
        import io

        from rosbags.convert.converter import create_connections_converters

        from jaxvo.host.readers.realsense import is_realsense, standard_bytes
        from jaxvo.host.readers.rosbag import open_reader

        count = 0
        with (contextlib.closing(open_reader(self.input_bag)) as reader,
              contextlib.redirect_stdout(io.StringIO())):  # its notes on types migrated
            connections = list(reader.connections)
            # into this bag's own definitions (one per type: an input's CameraInfo and jaxvo's
            # are one type), the bytes kept where the wire format is the same; a topic and
            # type jaxvo writes too (an input /tf) shares jaxvo's connection
            connmap, convmap = create_connections_converters(connections, self.ts, reader,
                                                             self._writer)
            realsense = is_realsense(reader)
            for rconn, t_ns, raw in reader.messages(connections=connections):
                data = standard_bytes(reader, raw, rconn.msgtype) if realsense else raw
                try:
                    out = convmap[rconn.msgtype](data)
                except Exception as exc:  # noqa: BLE001 (a message the converter cannot read)
                    raise InputError(f"{self.input_bag} {rconn.topic}: message {count + 1} "
                                     f"cannot be written to the bag ({type(exc).__name__}: "
                                     f"{exc})") from None
                self._writer.write(connmap[(rconn.id, rconn.owner)], t_ns, out)
                count += 1
        return count

    def _close(self) -> None:
        """Copy the input bag (``with_input``) and close the bag (on the bag's thread)."""
        copied = self._copy_input() if self.input_bag is not None else 0
        counts = {c.topic: self._writer.counts[c.id] for c in self._writer.connections}
        self._writer.close()
        self._summary = {"bag": str(self.target), "bag_messages": sum(counts.values()),
                         "bag_input_messages": copied, "bag_topics": len(counts)}

    def finish(self) -> dict:
        """Every message written, the input bag copied (``with_input``), the bag closed and
        renamed into place; the summary's part (``bag``, ``bag_messages``,
        ``bag_input_messages``, ``bag_topics``)."""
        self._submit(self._close)
        self._thread.close()  # waits; raises what failed on the bag's thread
        if self.error is not None:  # raised before, by a write_* on another thread
            raise self.error
        self._out.commit()
        self.finished = True
        return self._summary

    def abort(self) -> None:
        """Remove everything written; the target is left as it was."""
        if self.finished:
            return
        self.finished = True
        with contextlib.suppress(BaseException):  # a failure already raised, or Ctrl-C
            self._thread.submit(self._writer.abort)  # its files closed on its own thread
        with contextlib.suppress(BaseException):
            self._thread.close()
        self._out.discard()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if not self.finished:  # an error, or the run left before finish()
            self.abort()
