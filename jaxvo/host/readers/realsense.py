"""RealSense Viewer recordings: librealsense's ROS 1 ``.bag`` layout, read as an RGB-D
sequence (host side; :class:`jaxvo.host.readers.rosbag.BagSequence` uses it for such a bag).

The layout, as librealsense writes it (``src/media/ros/ros_file_format.h``,
``ros_writer.cpp``; topics listed in ``doc/record-and-playback.md``), file versions 2 on:

- ``/device_<d>/sensor_<s>/<Stream>_<i>/image/data``: ``sensor_msgs/Image`` of each stream
  (``Color_0`` ``rgb8`` / ``bgr8`` ..., ``Depth_0`` ``mono16``: Z16, ``Infrared_1`` ...),
  ``header.stamp`` the frame's timestamp;
- ``.../<Stream>_<i>/info/camera_info``: ``sensor_msgs/CameraInfo`` (``K``, ``D`` and
  librealsense's distortion model) of each video stream;
- ``.../<Stream>_<i>/tf/<group>``: ``geometry_msgs/Transform``, the extrinsics from the
  group's point of reference to the stream (points of the reference mapped into the
  stream's frame: librealsense's ``rs2_extrinsics``, whose reference is the depth stream);
- ``/device_<d>/sensor_<s>/option/Depth_Units/value``: ``std_msgs/Float32``, metres per
  Z16 unit.

librealsense writes one thing the message definition does not list: an image header's
``frame_id`` holds its version, ``"1"``, and then, after the pixel data, a ``float32``
``depth_units`` (metres per unit; 0 in colour images). :func:`image_message` reads both.

Where the depth stream is not the colour stream's geometry (another size, another camera
matrix, or extrinsics other than the identity), its depth is registered to the colour image
(:func:`register_depth`), as librealsense's ``rs2::align`` to colour does: each depth pixel's
footprint projected into the colour image, the nearest surface kept.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics, camera_info_distortion, camera_info_intrinsics
from jaxvo.host.frontend.distortion import distort

# /device_<d>/sensor_<s>/<Stream>_<i>/image/data
STREAM_TOPIC = re.compile(r"^(/device_\d+/sensor_(\d+))/([A-Za-z]+)_(\d+)/image/data$")
IMAGE_TYPE = "sensor_msgs/msg/Image"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TRANSFORM_TYPE = "geometry_msgs/msg/Transform"
FLOAT_TYPE = "std_msgs/msg/Float32"
# librealsense's version marker in an image header's frame_id (ros_writer.cpp)
_IMAGE_VERSION = "1"
# a depth pixel's footprint in the colour image is taken this much wider, pixels
# (register_depth); under half a pixel, so that the identity maps each pixel onto itself
_SLIVER = 0.02
# colour and depth cameras within this of each other are one camera (registered already)
_SAME_K = 1e-6  # relative, on fx fy cx cy
_SAME_T = 1e-6  # metres and radians


class Streams(NamedTuple):
    """What a RealSense recording holds for an RGB-D sequence."""

    colour_topic: str
    depth_topic: str
    colour: Intrinsics  # the colour camera, pixels; depth_scale: Z16 units per metre
    depth: Intrinsics  # the depth camera, pixels
    colour_size: tuple[int, int]  # (height, width) of the colour images
    depth_size: tuple[int, int]  # (height, width) of the depth images
    T_colour_depth: np.ndarray  # (4, 4) float64: depth camera points -> colour camera points
    aligned: bool  # the depth images are the colour camera's already: no registration
    description: str  # for the run's summary
    warnings: list[str]


def is_realsense(reader) -> bool:
    """Whether a bag (an open ``rosbags`` reader) has librealsense's stream topics."""
    return any(STREAM_TOPIC.match(c.topic) for c in reader.connections)


def image_message(reader, raw, msgtype: str = IMAGE_TYPE):
    """A ``sensor_msgs/Image`` deserialised, and librealsense's ``depth_units`` after its
    data (metres per unit) where it has one, else None: ``(msg, depth_units)``."""
    from rosbags.highlevel import AnyReaderError  # a size that is not the definition's

    try:
        return reader.deserialize(raw, msgtype), None
    except AnyReaderError as first:
        if len(raw) <= 4:
            raise
        try:
            msg = reader.deserialize(raw[:-4], msgtype)
        except AnyReaderError:
            raise first from None
        if msg.header.frame_id != _IMAGE_VERSION:
            raise first from None
        return msg, _decimal(np.frombuffer(bytes(raw[-4:]), "<f4")[0])


def _decimal(value: np.float32) -> float:
    """A float32 as the decimal it was written from (0.001, not 0.0010000000474974513):
    the shortest decimal that rounds to it."""
    return float(str(np.float32(value)))


def standard_bytes(reader, raw, msgtype: str):
    """A message's bytes as its definition reads them: a librealsense image without the
    ``depth_units`` after its data (what a copy of the recording into a ROS 2 bag takes)."""
    if msgtype != IMAGE_TYPE:
        return raw
    _, units = image_message(reader, raw, msgtype)
    return raw if units is None else raw[:-4]


def _first(reader, topic: str, msgtype: str):
    """The first message on ``topic`` of type ``msgtype``, deserialised, or None."""
    conns = [c for c in reader.connections if c.topic == topic and c.msgtype == msgtype]
    if not conns:  # (no connections given: a reader reads every topic)
        return None
    for conn, _, raw in reader.messages(connections=conns[:1]):
        return reader.deserialize(raw, conn.msgtype)
    return None


def _camera(reader, path: Path, prefix: str, what: str) -> tuple[Intrinsics, tuple, list]:
    """A stream's pinhole camera, image size and warnings from its ``info/camera_info``."""
    topic = f"{prefix}/info/camera_info"
    try:
        info = _first(reader, topic, INFO_TYPE)
    except Exception as exc:  # noqa: BLE001 (a damaged message raises what the parser trips on)
        raise InputError(f"{path} {topic}: cannot read the {what} camera info "
                         f"({type(exc).__name__})") from None
    if info is None:
        raise InputError(f"{path}: no {what} camera info ({topic}); the recording has no "
                         f"intrinsics for {prefix.rsplit('/', 1)[1]}")
    K = camera_info_intrinsics(info, 1.0)  # the depth scale is the depth units' (below)
    if not isinstance(K, Intrinsics):
        raise InputError(f"{path} {topic}: the {what} camera info gives no camera: {K}")
    if not (info.width > 0 and info.height > 0):
        raise InputError(f"{path} {topic}: the {what} camera info gives an image of "
                         f"{info.width}x{info.height}")
    lens, note = camera_info_distortion(info, where=f"{path} {topic}")
    return K._replace(distortion=lens), (int(info.height), int(info.width)), [note] if note else []


def _extrinsics(reader, path: Path, prefix: str) -> dict[int, np.ndarray]:
    """A stream's extrinsics, group -> (4, 4) reference -> stream, from its ``tf/<group>``."""
    out = {}
    for conn in reader.connections:
        m = re.fullmatch(re.escape(prefix) + r"/tf/(\d+)", conn.topic)
        if not m or conn.msgtype != TRANSFORM_TYPE:
            continue
        try:
            tf = _first(reader, conn.topic, TRANSFORM_TYPE)
        except Exception as exc:  # noqa: BLE001
            raise InputError(f"{path} {conn.topic}: cannot read the extrinsics "
                             f"({type(exc).__name__})") from None
        if tf is None:
            continue
        q = np.array([tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w], np.float64)
        t = np.array([tf.translation.x, tf.translation.y, tf.translation.z], np.float64)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(t))
                and abs(np.linalg.norm(q) - 1) < 1e-3):
            raise InputError(f"{path} {conn.topic}: the extrinsics are not a rigid motion "
                             f"(rotation {q.round(6).tolist()} of norm "
                             f"{np.linalg.norm(q):.6g}, translation {t.round(6).tolist()})")
        from jaxvo.transforms import pose_from_tq

        out[int(m.group(1))] = pose_from_tq(t, q)
    return out


def _depth_units(reader, path: Path, sensor_prefix: str, first_units: float | None) -> tuple:
    """Metres per Z16 unit: the first depth image's own (what librealsense's playback uses),
    else the sensor's ``Depth_Units`` option; and where it came from, in words."""
    topic = f"{sensor_prefix}/option/Depth_Units/value"
    if first_units:  # 0: a recording that keeps it in the option only
        units, where = first_units, "the depth images"
    else:
        msg = _first(reader, topic, FLOAT_TYPE)
        if msg is None:
            raise InputError(f"{path}: no depth units (neither {topic} nor the depth images "
                             "give them); pass --depth-scale")
        units, where = _decimal(msg.data), topic
    if not (np.isfinite(units) and units > 0):
        raise InputError(f"{path}: depth units {units:g} m (from {where}) is not a length; "
                         "pass --depth-scale")
    return units, where


def find_streams(reader, path: str | Path, *, rgb_topic: str | None = None,
                 depth_topic: str | None = None, depth_scale: float | None = None) -> Streams:
    """The colour and depth streams of a RealSense recording, their cameras, the depth
    units and the depth-to-colour extrinsics.

    Args:
      reader: the open ``rosbags`` reader of the recording.
      path: the recording (for messages).
      rgb_topic, depth_topic: the streams' ``image/data`` topics (default: the ``Color``
        and ``Depth`` streams of lowest index).
      depth_scale: Z16 units per metre, overriding the recording's depth units.
    Raises:
      InputError: one line naming the stream that is missing or malformed.
    """
    path = Path(path)
    found = {}
    for c in reader.connections:
        m = STREAM_TOPIC.match(c.topic)
        if m and c.msgtype == IMAGE_TYPE:
            found[c.topic] = (m.group(1), m.group(3), int(m.group(4)))
    listed = ", ".join(sorted(t.split("/")[3] for t in found)) or "none"

    def pick(given, kind, option):
        if given is not None:
            if given not in found:
                raise InputError(f"{path}: no image stream {given} (pass {option} an image "
                                 f"topic; streams: {listed})")
            return given
        ours = sorted((i, t) for t, (_, k, i) in found.items() if k == kind)
        if not ours:
            raise InputError(f"{path}: no {kind} stream in the RealSense recording (streams: "
                             f"{listed}; pass {option} a stream's image/data topic)")
        return ours[0][1]

    colour_topic = pick(rgb_topic, "Color", "--rgb-topic")
    depth_topic = pick(depth_topic, "Depth", "--depth-topic")
    c_prefix, d_prefix = (t.removesuffix("/image/data") for t in (colour_topic, depth_topic))
    K_c, c_size, notes = _camera(reader, path, c_prefix, "colour")
    K_d, d_size, d_notes = _camera(reader, path, d_prefix, "depth")
    notes += d_notes
    first = _first_depth_units(reader, path, depth_topic)
    if depth_scale is not None:
        units, units_from = 1.0 / depth_scale, "--depth-scale"
    else:
        units, units_from = _depth_units(reader, path, found[depth_topic][0], first)
    same_camera = c_size == d_size and np.allclose(K_c[:4], K_d[:4], rtol=_SAME_K, atol=0)
    e_c, e_d = _extrinsics(reader, path, c_prefix), _extrinsics(reader, path, d_prefix)
    groups = sorted(set(e_c) & set(e_d))
    if groups:
        T_c_d = e_c[groups[0]] @ np.linalg.inv(e_d[groups[0]])
    elif same_camera:
        T_c_d = np.eye(4)  # one camera's geometry, no extrinsics: registered by the recorder
    else:
        have = f"{c_prefix}/tf/{sorted(e_c) or '-'}, {d_prefix}/tf/{sorted(e_d) or '-'}"
        raise InputError(f"{path}: no depth-to-colour extrinsics (a tf/<group> for both "
                         f"streams in one group; found {have}); the depth cannot be "
                         "registered to the colour image")
    rot = np.linalg.norm(T_c_d[:3, :3] - np.eye(3))
    aligned = same_camera and rot < _SAME_T and np.linalg.norm(T_c_d[:3, 3]) < _SAME_T
    colour = K_c._replace(depth_scale=1.0 / units)
    how = ("aligned to colour already" if aligned else
           f"registered to colour ({d_size[1]}x{d_size[0]} depth, extrinsics translation "
           f"{np.round(T_c_d[:3, 3] * 1000, 1).tolist()} mm)")
    description = (f"RealSense recording {path.name}: colour {c_prefix} {c_size[1]}x"
                   f"{c_size[0]}, depth {d_prefix} at {units:g} m per unit (from "
                   f"{units_from}), {how}; intrinsics from each stream's camera_info")
    return Streams(colour_topic, depth_topic, colour, K_d, c_size, d_size, T_c_d, bool(aligned),
                   description, notes)


def _first_depth_units(reader, path: Path, topic: str) -> float | None:
    """librealsense's ``depth_units`` after the first depth image's data, or None."""
    conns = [c for c in reader.connections if c.topic == topic]
    for _, _, raw in reader.messages(connections=conns[:1]) if conns else ():
        try:
            return image_message(reader, raw)[1]
        except Exception as exc:  # noqa: BLE001 (a damaged message raises what the parser trips on)
            raise InputError(f"{path} {topic}: cannot read the first depth image "
                             f"({type(exc).__name__})") from None
    raise InputError(f"{path} {topic}: no images")


def register_depth(depth: np.ndarray, K_depth: Intrinsics, K_colour: Intrinsics,
                   T_colour_depth: np.ndarray, height: int, width: int) -> np.ndarray:
    """Depth registered to the colour camera, as librealsense's align to colour does.

    Each depth pixel's footprint (its corners at its depth) is projected into the colour
    image; the colour pixels whose centres it covers take its depth along the colour
    camera's axis (at least the one nearest its centre), and where several depth pixels
    land on one colour pixel the nearest surface is kept.

    Args:
      depth: (h, w) float32 metres in the depth camera, 0 = no reading.
      K_depth, K_colour: the two cameras (pixel centres at integer coordinates); the
        colour camera's distortion places each reading at the pixel its lens puts it, as
        librealsense's align does (the depth camera's, rectified on the D400s, is not read).
      T_colour_depth: (4, 4) depth camera points -> colour camera points, metres.
      height, width: the colour image's size.
    Returns:
      (height, width) float32 metres in the colour camera, 0 = no reading.
    """
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    R, t = np.asarray(T_colour_depth[:3, :3], np.float64), np.asarray(T_colour_depth[:3, 3])
    # the point at the pixel's centre in the colour camera, and how it moves per pixel of
    # the depth image (the ray is linear in the pixel), written out per axis: an (n, 3) @
    # (3, 3) product was far slower on a 640x480 image
    xd, yd = (u - K_depth.cx) / K_depth.fx * z, (v - K_depth.cy) / K_depth.fy * z
    centre = [R[i, 0] * xd + R[i, 1] * yd + R[i, 2] * z + t[i] for i in range(3)]
    step_u, step_v = R[:, 0] / K_depth.fx, R[:, 1] / K_depth.fy

    def to_colour(du: float, dv: float):
        """Colour pixels (x, y) and depth of the depth pixels' points offset by (du, dv)."""
        px, py, pz = (centre[i] + z * (du * step_u[i] + dv * step_v[i]) for i in range(3))
        zs = np.maximum(pz, 1e-9)
        if K_colour.distortion is not None:  # where the colour lens puts the point
            uv = distort(np.stack([px / zs, py / zs], axis=-1), K_colour)
            return uv[:, 0], uv[:, 1], pz
        return K_colour.fx * px / zs + K_colour.cx, K_colour.fy * py / zs + K_colour.cy, pz

    x0, y0, _ = to_colour(-0.5, -0.5)
    x1, y1, _ = to_colour(0.5, 0.5)
    xc, yc, zc = to_colour(0.0, 0.0)
    # colour pixel centres inside the footprint, taken _SLIVER wider on each side (its box
    # from two corners misses a small rotation's shear, and neighbours at slightly other
    # depths leave slivers between them: holes in a continuous surface); where it covers
    # no centre, the one nearest its centre
    lo_x = np.ceil(np.minimum(x0, x1) - _SLIVER)
    hi_x = np.floor(np.maximum(x0, x1) + _SLIVER)
    lo_y = np.ceil(np.minimum(y0, y1) - _SLIVER)
    hi_y = np.floor(np.maximum(y0, y1) + _SLIVER)
    empty_x, empty_y = hi_x < lo_x, hi_y < lo_y
    lo_x = np.where(empty_x, np.round(xc), lo_x)
    hi_x = np.where(empty_x, lo_x, hi_x)
    lo_y = np.where(empty_y, np.round(yc), lo_y)
    hi_y = np.where(empty_y, lo_y, hi_y)
    keep = (zc > 0) & np.isfinite(lo_x) & np.isfinite(lo_y)
    span = 4  # footprints wider than 4 colour pixels (a depth camera 4x coarser) are cut
    zbuf = np.full(height * width, np.inf)
    for dy in range(span):
        for dx in range(span):
            x, y = lo_x + dx, lo_y + dy
            m = keep & (x <= hi_x) & (y <= hi_y) & (x >= 0) & (y >= 0) & (x < width) & (y < height)
            if not m.any():
                continue
            np.minimum.at(zbuf, y[m].astype(np.int64) * width + x[m].astype(np.int64), zc[m])
    out = np.where(np.isfinite(zbuf), zbuf, 0.0).astype(np.float32)
    return out.reshape(height, width)
