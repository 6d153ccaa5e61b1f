"""RGB-D sequences from ROS bags: ROS 1 ``.bag`` files and ROS 2 bag folders (host side).

Read with ``rosbags`` (pure Python, no ROS install). A :class:`BagSequence` is a sequence as
``io.TumSequence`` is (``name``, ``intrinsics``, ``height``, ``width``, ``timestamps``,
``groundtruth``, ``__len__``, ``__getitem__ -> Frame``, lazy), so ``jaxvo run``, studies and
everything downstream take a bag as they take a folder; :func:`jaxvo.host.readers.io.open_sequence`
opens one when given a ``.bag`` file or a folder with ``metadata.yaml``.

Topics: the TUM RGB-D bags' by default (:data:`TUM_TOPICS`); the camera info is the one
beside the colour topic (``/camera/rgb/image_color`` -> ``/camera/rgb/camera_info``).
Encodings (``sensor_msgs/Image``): colour ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8``;
depth ``32FC1`` metres (TUM's bags; NaN = no reading) or ``16UC1`` / ``mono16``
millimetres (ROS REP 118; ``depth_scale`` gives other units, e.g. TUM's 5000 per metre).
Frames are the colour images, each paired with the depth image
nearest in time within ``max_diff`` (:func:`jaxvo.trajectory.associate`, as for folders), both
timed by their header stamps (sensor time, as TUM's ``rgb.txt``), not by when they were
recorded. Opening reads the two image topics once to learn the stamps; frames are decoded
only when asked for, each found again by its bag time and its place among the topic's
messages at that time (a converter may write every message at one bag time).

A RealSense Viewer recording (librealsense's ``/device_0/sensor_*/...`` topics) is read
through :mod:`jaxvo.host.readers.realsense`: its colour and depth streams, their cameras, the depth
units and, where the depth is another camera's, the depth registered to the colour image.
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import (
    Intrinsics,
    camera_info_distortion,
    camera_info_intrinsics,
    check_intrinsics,
    depth_metres,
    preset,
)
from jaxvo.host.frontend.frames import (
    Frame,
    check_frame_size,
    frame_index,
    given_camera,
    preset_from_name,
)
from jaxvo.host.readers.realsense import find_streams, image_message, is_realsense, register_depth
from jaxvo.trajectory import associate

# colour, depth and camera-info topics of the TUM RGB-D benchmark's bags
TUM_TOPICS = ("/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info")
IMAGE_TYPE = "sensor_msgs/msg/Image"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
# ROS REP 118: 16-bit depth images are millimetres
ROS_DEPTH_UNITS_PER_METRE = 1000.0
# colour encodings -> (channels, the channel order that makes BGR)
# raw messages a cursor keeps after passing them (frames read ahead arrive nearly in order)
_RECENT = 8
_COLOUR = {"rgb8": (3, [2, 1, 0]), "bgr8": (3, [0, 1, 2]), "rgba8": (4, [2, 1, 0]),
           "bgra8": (4, [0, 1, 2]), "mono8": (1, [0, 0, 0])}


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a ROS 1 bag (a ``.bag`` file) or a ROS 2 bag (a folder with
    ``metadata.yaml``)."""
    p = Path(path)
    return (p.is_file() and p.suffix == ".bag") or (p.is_dir() and (p / "metadata.yaml").is_file())


def open_reader(path: Path):
    """An open ``rosbags`` reader of a ROS 1 or ROS 2 bag (a damaged bag: one line)."""
    try:
        from rosbags.highlevel import AnyReader, AnyReaderError
    except ImportError:
        raise InputError("reading ROS bags needs rosbags: pip install 'rosbags>=0.11'") from None
    try:
        reader = AnyReader([path])
        reader.open()
    except AnyReaderError as exc:  # rosbags wraps each format's reader errors in it
        raise InputError(f"{path}: cannot read the bag ({exc})") from None
    except Exception as exc:  # noqa: BLE001 (random bytes raise what the parser trips on)
        raise InputError(f"{path}: cannot read the bag ({_why(exc)})") from None
    return reader


def _why(exc: Exception) -> str:
    """A reader failure in a few words (its type where its text says nothing)."""
    text = str(exc).splitlines()[0][:160] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _stamp_ns(msg) -> int:
    """A message's header stamp, integer nanoseconds (exact, as a ROS time is)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _pixels(msg, channels: int, dtype: str) -> np.ndarray:
    """The (H, W, channels) pixel array of a ``sensor_msgs/Image``, rows padded to ``step``."""
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dt.itemsize
    data = np.frombuffer(msg.data, np.uint8)
    if msg.step < row_bytes or data.size < msg.step * msg.height:
        raise InputError(f"{msg.encoding} image of {msg.width}x{msg.height} with step "
                         f"{msg.step} holds {data.size} bytes: truncated")
    rows = data[: msg.step * msg.height].reshape(msg.height, msg.step)[:, :row_bytes]
    return rows.copy().view(dt).reshape(msg.height, msg.width, channels).astype(dtype)


def colour_bgr(msg) -> np.ndarray:
    """(H, W, 3) uint8 BGR from a colour ``sensor_msgs/Image`` (see the module docstring)."""
    enc = msg.encoding.lower()
    if enc not in _COLOUR:
        raise InputError(f"colour encoding {msg.encoding!r} is not read "
                         f"({', '.join(_COLOUR)} are)")
    channels, order = _COLOUR[enc]
    return np.ascontiguousarray(_pixels(msg, channels, "uint8")[..., order])


def is_float_depth(msg) -> bool:
    """Whether a depth ``sensor_msgs/Image`` holds float metres (``32FC1``), not raw units."""
    return msg.encoding.upper() == "32FC1"


def depth_m(msg, units_per_metre: float = ROS_DEPTH_UNITS_PER_METRE) -> np.ndarray:
    """(H, W) float32 metres, 0 = no reading, from a depth ``sensor_msgs/Image``
    (``32FC1`` metres, or ``16UC1`` / ``mono16`` raw units, ``units_per_metre`` of them a
    metre: millimetres by default, as ROS REP 118)."""
    enc = msg.encoding.upper()
    if enc == "32FC1":
        d = _pixels(msg, 1, "float32")[..., 0]
        return np.where(np.isfinite(d) & (d > 0), d, np.float32(0)).astype(np.float32)
    if enc in ("16UC1", "MONO16"):
        raw = _pixels(msg, 1, "uint16")[..., 0]
        return depth_metres(raw, Intrinsics(1, 1, 0, 0, units_per_metre))
    raise InputError(f"depth encoding {msg.encoding!r} is not read (32FC1 metres, 16UC1 "
                     "millimetres are)")


class BagSequence:
    """An RGB-D sequence in a ROS 1 or ROS 2 bag, frames decoded only when asked for.

    Args:
      path: a ``.bag`` file (ROS 1) or a ROS 2 bag folder.
      camera: a preset name or :class:`Intrinsics`; overrides the bag's camera info. Without
        either, a bag named as TUM and Bonn name theirs takes that camera's preset.
      max_diff: largest colour-depth time difference when pairing them, seconds.
      rgb_topic: the colour topic (default TUM's ``/camera/rgb/image_color``; a RealSense
        recording's ``Color`` stream).
      depth_topic: the depth topic (default TUM's ``/camera/depth/image``; a RealSense
        recording's ``Depth`` stream).
      depth_scale: raw units per metre of 16-bit depth (default 1000, ROS REP 118's
        millimetres); refused for ``32FC1`` depth, which is metres.

    Attributes:
      warnings: one-line warnings (frames left out, camera info against the name's preset).
      frames_listed: colour images in the bag, paired or not.
      camera_source: where the intrinsics came from, in words.
      float_depth: the depth topic holds float metres (``32FC1``), not raw units.
      stamps_ns: (N,) int64 each frame's colour header stamp, nanoseconds (exact).
      record_ns: (N,) int64 the bag time each frame's colour image was recorded at, ns.
      realsense: the :class:`jaxvo.host.readers.realsense.Streams` of a RealSense recording, or None.
    """

    groundtruth = None  # bags carry the motion capture as tf frames, not read here

    def __init__(self, path: str | Path, *, camera: str | Intrinsics | None = None,
                 max_diff: float = 0.02, rgb_topic: str | None = None,
                 depth_topic: str | None = None, depth_scale: float | None = None) -> None:
        self.path = Path(path)
        if not max_diff >= 0:  # also NaN
            raise InputError(f"max time difference must be >= 0 s, got {max_diff}")
        self.name = self.path.resolve().name.removesuffix(".bag")
        self.warnings: list[str] = []
        self._lock = threading.Lock()  # frames are read from several threads (read_ahead)
        self._cursor: dict[str, list] = {}  # topic -> [bag time, next place, messages]
        self._recent: dict[tuple, bytes] = {}  # the last messages a cursor passed
        self._reader = open_reader(self.path)
        # a RealSense Viewer recording names its own streams, cameras and depth units
        self.realsense = (find_streams(self._reader, self.path, rgb_topic=rgb_topic,
                                       depth_topic=depth_topic, depth_scale=depth_scale)
                          if is_realsense(self._reader) else None)
        if self.realsense is not None:
            rgb_topic, depth_topic = self.realsense.colour_topic, self.realsense.depth_topic
            self.warnings += self.realsense.warnings
        rgb_topic = rgb_topic or TUM_TOPICS[0]
        depth_topic = depth_topic or TUM_TOPICS[1]
        self._conns = {t: self._connection(t, IMAGE_TYPE, option)
                       for t, option in ((rgb_topic, "--rgb-topic"),
                                         (depth_topic, "--depth-topic"))}
        t_rgb, at_rgb = self._stamps(rgb_topic)
        t_depth, at_depth = self._stamps(depth_topic)
        ia, ib = associate(t_rgb / 1e9, t_depth / 1e9, max_diff, names=(rgb_topic, depth_topic))
        self.timestamps = t_rgb[ia] / 1e9
        # each frame's header stamp and the bag time its colour image was recorded at, ns
        self.stamps_ns, self.record_ns = t_rgb[ia], at_rgb[ia, 0]
        self._at = [(rgb_topic, at_rgb[i], depth_topic, at_depth[j]) for i, j in zip(ia, ib)]
        self.frames_listed = len(t_rgb)
        for topic, count, other in ((rgb_topic, len(t_rgb), "depth"),
                                    (depth_topic, len(t_depth), "colour")):
            if count > len(ia):
                self.warnings.append(f"{self.path} {topic}: {count - len(ia)} of {count} "
                                     f"images have no {other} image within {max_diff:g} s "
                                     "(--max-diff) and are left out")
        first = self._decode(rgb_topic, at_rgb[ia[0]], colour_bgr)
        self.height, self.width = first.shape[:2]
        self.float_depth = self._decode(depth_topic, at_depth[ib[0]], is_float_depth)
        if self.float_depth and depth_scale is not None:
            raise InputError(f"{self.path} {depth_topic}: depth is 32FC1 metres; --depth-scale "
                             "is for 16-bit depth in raw units")
        if self.realsense is not None:
            self._units = self.realsense.colour.depth_scale
            K, self.camera_source = given_camera(camera) or (self.realsense.colour,
                                                             self.realsense.description)
            self._check_realsense_sizes(at_depth[ib[0]])  # after self._units
        else:
            self._units = float(depth_scale or ROS_DEPTH_UNITS_PER_METRE)
            info_topic = rgb_topic.rsplit("/", 1)[0] + "/camera_info"
            K, self.camera_source = self._intrinsics(camera, info_topic)
        # the depth's own unit, whatever the camera's source says (a preset's is a folder's)
        self.intrinsics = K._replace(depth_scale=self._units)
        if depth_scale is not None:
            self.camera_source += f", depth_scale {self._units:g} given"
        check_intrinsics(self.intrinsics, where=self.camera_source, width=self.width,
                         height=self.height)

    def _connection(self, topic: str, msgtype: str, option: str):
        conns = [c for c in self._reader.connections if c.topic == topic]
        if not conns:
            images = sorted({c.topic for c in self._reader.connections if c.msgtype == msgtype})
            raise InputError(f"{self.path}: no topic {topic} (pass {option}; image topics: "
                             f"{', '.join(images) or 'none'})")
        if conns[0].msgtype != msgtype:
            raise InputError(f"{self.path} {topic}: {conns[0].msgtype}, not {msgtype}")
        return conns[0]

    def _check_realsense_sizes(self, at_depth) -> None:
        """The first colour and depth images are the sizes their camera infos give, and the
        first depth image reads (its encoding)."""
        rs = self.realsense
        depth = self._message(rs.depth_topic, at_depth)
        for topic, got, want in ((rs.colour_topic, (self.height, self.width), rs.colour_size),
                                 (rs.depth_topic, (depth.height, depth.width), rs.depth_size)):
            if got != want:
                raise InputError(f"{self.path} {topic}: images of {got[1]}x{got[0]}, but its "
                                 f"camera info is for {want[1]}x{want[0]}")
        self._decode(rs.depth_topic, at_depth, self._depth)

    def _deserialize(self, raw, msgtype: str):
        """A message deserialised (a RealSense image without the depth units after it)."""
        if self.realsense is not None and msgtype == IMAGE_TYPE:
            return image_message(self._reader, raw, msgtype)[0]
        return self._reader.deserialize(raw, msgtype)

    def _depth(self, msg) -> np.ndarray:
        """(H, W) float32 metres from a depth image, registered to colour where a RealSense
        recording's depth is another camera's."""
        depth = depth_m(msg, self._units)
        rs = self.realsense
        if rs is None or rs.aligned:
            return depth
        return register_depth(depth, rs.depth, rs.colour, rs.T_colour_depth, self.height,
                              self.width)

    def _stamps(self, topic: str) -> tuple[np.ndarray, np.ndarray]:
        """Header stamps (N,) int64 nanoseconds of a topic's images in time order, and where
        to find each again: (N, 2) int, its bag time in nanoseconds and its place among the
        topic's messages at that time; a repeated stamp keeps the first image."""
        stamps, at = [], []
        try:
            for conn, t_ns, raw in self._reader.messages(connections=[self._conns[topic]]):
                stamps.append(_stamp_ns(self._deserialize(raw, conn.msgtype)))
                same = at[-1][1] + 1 if at and at[-1][0] == t_ns else 0
                at.append((t_ns, same))
        except Exception as exc:  # noqa: BLE001 (a damaged bag raises what the parser trips on)
            raise InputError(f"{self.path} {topic}: cannot read message {len(stamps) + 1} "
                             f"({_why(exc)})") from None
        if not stamps:
            raise InputError(f"{self.path} {topic}: no images")
        t = np.asarray(stamps, np.int64)
        order = np.argsort(t, kind="stable")
        keep = order[np.concatenate([[True], np.diff(t[order]) > 0])]
        if len(keep) < len(t):
            self.warnings.append(f"{self.path} {topic}: {len(t) - len(keep)} images repeat an "
                                 "earlier image's stamp; left out")
        return t[keep], np.asarray(at, np.int64).reshape(-1, 2)[keep]

    def _decode(self, topic: str, at, decode):
        """``decode`` of the image of ``topic`` at ``at``, its failure naming bag and topic."""
        msg = self._message(topic, at)  # its own errors name the bag and topic
        try:
            return decode(msg)
        except InputError as exc:
            raise InputError(f"{self.path} {topic}: {exc}") from None

    def _message(self, topic: str, at):
        """The image of ``topic`` at ``at`` = (bag time ns, place among the topic's messages
        at that time), deserialised."""
        t_ns, place = (int(v) for v in at)  # a NumPy integer binds as no time in ROS 2's SQLite
        conn = self._conns[topic]
        with self._lock:
            raw = self._recent.get((topic, t_ns, place))
            if raw is None:
                raw = self._raw(conn, topic, t_ns, place)
        try:
            return self._deserialize(raw, conn.msgtype)
        except Exception as exc:  # noqa: BLE001 (a damaged message raises what the parser trips on)
            raise InputError(f"{self.path} {topic}: cannot read the image at bag time {t_ns} "
                             f"ns ({_why(exc)})") from None

    def _raw(self, conn, topic: str, t_ns: int, place: int) -> bytes:
        """The raw message: read on from the topic's cursor at this bag time (messages that
        share a bag time are read in order once, not from the first again each time)."""
        cursor = self._cursor.get(topic)
        if cursor is None or cursor[0] != t_ns or cursor[1] > place:
            cursor = [t_ns, 0, self._reader.messages(connections=[conn], start=t_ns,
                                                     stop=t_ns + 1)]
            self._cursor[topic] = cursor
        try:
            for _, _, raw in cursor[2]:
                cursor[1] += 1
                self._recent[(topic, t_ns, cursor[1] - 1)] = raw
                while len(self._recent) > _RECENT:  # read ahead asks nearly in order
                    del self._recent[next(iter(self._recent))]
                if cursor[1] - 1 == place:
                    return raw
        except Exception as exc:  # noqa: BLE001 (a damaged bag raises what the parser trips on)
            self._cursor.pop(topic, None)
            raise InputError(f"{self.path} {topic}: cannot read the image at bag time {t_ns} "
                             f"ns ({_why(exc)})") from None
        self._cursor.pop(topic, None)
        raise InputError(f"{self.path} {topic}: no image at bag time {t_ns} ns")

    def _intrinsics(self, camera, info_topic: str) -> tuple[Intrinsics, str]:
        """The ``camera`` given, else the bag's camera info, else the name's preset."""
        given = given_camera(camera)
        if given is not None:
            return given
        guess = preset_from_name(self.name)
        conns = [c for c in self._reader.connections
                 if c.topic == info_topic and c.msgtype == INFO_TYPE]
        K = "there is none"
        if conns:
            with self._lock:
                for c, _, raw in self._reader.messages(connections=conns[:1]):
                    info = self._reader.deserialize(raw, c.msgtype)
                    K = camera_info_intrinsics(info, ROS_DEPTH_UNITS_PER_METRE)
                    break
        if isinstance(K, Intrinsics):
            lens, note = camera_info_distortion(info, where=f"{self.path} {info_topic}")
            K = K._replace(distortion=lens)
            self.warnings += [note] if note else []
            if guess is not None and preset(guess)[:4] != K[:4]:
                self.warnings.append(
                    f"{self.path} {info_topic}: fx {K.fx:g} fy {K.fy:g} cx {K.cx:g} cy "
                    f"{K.cy:g}, not the {guess} preset its name points to (--camera {guess} "
                    "takes the preset)")
            return K, f"{self.path} {info_topic}"
        if guess is None:
            what = (f"no camera info on {info_topic}" if K == "there is none"
                    else f"the camera info on {info_topic} gives no camera: {K}")
            raise InputError(f"{self.path}: {what}; pass --camera or --intrinsics")
        return preset(guess), f"preset {guess}, from the bag's name"

    def files(self, frames: int | None = None) -> list[Path]:
        """What reading the bag touches (any number of frames): a ROS 1 bag file, or the
        files of a ROS 2 bag folder (what no output may overwrite)."""
        if self.path.is_file():
            return [self.path]
        return sorted(p for p in self.path.iterdir() if p.is_file())

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, index: int) -> Frame:
        """Decode frame ``index`` from the bag (negative indices count from the end)."""
        index = frame_index(index, len(self))
        rgb_topic, at_rgb, depth_topic, at_depth = self._at[index]
        bgr = self._decode(rgb_topic, at_rgb, colour_bgr)
        depth = self._decode(depth_topic, at_depth, self._depth)
        for topic, img in ((rgb_topic, bgr), (depth_topic, depth)):
            check_frame_size(f"{self.path} {topic} frame {index}", img, self.height, self.width)
        return Frame(index, float(self.timestamps[index]), bgr, depth, None)

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"BagSequence({self.name!r}, {len(self)} frames, {self.width}x{self.height})"
