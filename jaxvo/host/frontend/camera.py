"""Pinhole camera intrinsics and depth scale (host side, numpy)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.distortion import DISTORTION_MODELS, Distortion, undistort


class Intrinsics(NamedTuple):
    """Pinhole intrinsics in pixels, the depth scale in raw units per metre and the lens's
    distortion (None: the images are taken as pinhole). The device side reads
    ``fx fy cx cy`` only: the host undoes the distortion before any point crosses."""

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float = 5000.0
    distortion: Distortion | None = None

    @property
    def focal(self) -> float:
        """The mean focal length, pixels: metres per pixel at depth z is z / focal (a
        negative ``fy``, a camera whose y axis points up, counts by its size)."""
        return 0.5 * (abs(float(self.fx)) + abs(float(self.fy)))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """``np.asarray(K)``: the five numbers fx, fy, cx, cy, depth_scale, as before the lens
        joined them (code that compares or stores a camera as an array keeps working)."""
        return np.array(self[:5], dtype=dtype or np.float64)

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], np.float64
        )


# Published calibrations, depth 5000 per metre: TUM RGB-D (vision.in.tum.de, "file formats")
# and the Bonn RGB-D Dynamic Dataset (Palazzolo et al., IROS 2019; TUM layout, one camera).
PRESETS: dict[str, Intrinsics] = {
    "tum_fr1": Intrinsics(517.3, 516.5, 318.6, 255.3, 5000.0),
    "tum_fr2": Intrinsics(520.9, 521.0, 325.1, 249.7, 5000.0),
    "tum_fr3": Intrinsics(535.4, 539.2, 320.1, 247.6, 5000.0),
    "bonn": Intrinsics(542.822841, 542.576870, 315.593520, 237.756098, 5000.0),
    "ros_default": Intrinsics(525.0, 525.0, 319.5, 239.5, 5000.0),
}


# Other names of these models: librealsense's and OpenCV's calibration files' words
_MODEL_NAMES = {"brown_conrady": "plumb_bob", "opencv": "plumb_bob", "radtan": "plumb_bob"}

# TUM RGB-D's own calibration of the fr1 / fr2 colour cameras (vision.in.tum.de, "intrinsic
# camera calibration"), OpenCV's k1 k2 p1 p2 k3; fr3's images were undistorted by the
# recording driver (its coefficients are 0). The presets tum_fr1 / tum_fr2 leave them out,
# as TUM's own tools do (the depth is registered to the driver's pinhole image);
# tum_fr1_lens / tum_fr2_lens apply them to the tracked points, as ORB-SLAM3 does.
TUM_DISTORTION = {
    "tum_fr1": Distortion("plumb_bob", (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)),
    "tum_fr2": Distortion("plumb_bob", (0.231222, -0.784899, -0.003257, -0.000105, 0.917205)),
}
PRESETS.update({f"{name}_lens": PRESETS[name]._replace(distortion=d)
                for name, d in TUM_DISTORTION.items()})


def distortion(model: str, coeffs, *, where: str = "distortion") -> Distortion | None:
    """The :class:`Distortion` of a model name and its coefficients, or None where every
    coefficient is 0 (a pinhole camera: its points are taken as they are, bit for bit).

    Args:
      model: a name of :data:`DISTORTION_MODELS` (case, spaces and hyphens aside, as
        librealsense writes "Inverse Brown Conrady"), or ``brown_conrady`` / ``opencv``
        (plumb_bob); ``none`` with all-zero coefficients.
      coeffs: the coefficients in the model's order; plumb_bob takes ``k1 k2 p1 p2`` too
        (``k3`` 0), as OpenCV does.
      where: what to name in the message (the file, the topic).
    Raises:
      InputError: an unknown model, a coefficient count the model does not take, or a
        coefficient that is not a finite number.
    """
    name = re.sub(r"[\s-]+", "_", str(model).strip().lower())
    name = _MODEL_NAMES.get(name, name)
    try:
        values = [float(c) for c in coeffs]
    except (TypeError, ValueError):
        raise InputError(f"{where}: distortion coefficients must be numbers, got "
                         f"{list(coeffs)!r}") from None
    if not all(np.isfinite(values)):
        raise InputError(f"{where}: distortion coefficients must be finite, got {values}")
    if not any(values) and (name in DISTORTION_MODELS or name in ("none", "")):
        return None
    if name not in DISTORTION_MODELS:
        raise InputError(f"{where}: jaxvo does not undo {model!r} distortion; it takes "
                         f"{', '.join(DISTORTION_MODELS)} (or images already undistorted)")
    names = DISTORTION_MODELS[name]
    if name == "plumb_bob" and len(values) == 4:
        values.append(0.0)
    if len(values) != len(names):
        raise InputError(f"{where}: {name} distortion takes {len(names)} coefficients "
                         f"({' '.join(names)}), got {len(values)}")
    return Distortion(name, tuple(values))


def describe_distortion(K: Intrinsics) -> str:
    """What a run does with the lens, in words, for its summary."""
    if K.distortion is None:
        return "images taken as pinhole (no distortion given)"
    return f"distortion: {K.distortion.describe()} (undone at the tracked points)"


def preset(name: str) -> Intrinsics:
    """A named calibration from :data:`PRESETS`."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown camera preset {name!r}; choose one of {', '.join(sorted(PRESETS))}"
        ) from None


# The keys of a camera.txt; depth_scale is optional (TUM's 5000 raw units per metre).
CAMERA_KEYS = ("fx", "fy", "cx", "cy", "depth_scale")
# "fx 585", "fx: 585", "fx = 585": people write all three (and YAML-minded tools the second).
_CAMERA_LINE = re.compile(r"([A-Za-z_][A-Za-z0-9_.-]*)\s*[:=]?\s*(\S+)")
# A focal length giving a field of view outside 10-170 degrees is no RGB-D camera's: such a
# value is a typo or a file of another camera model (the widest RGB-D sensors see ~120).
_MIN_FOV_DEG, _MAX_FOV_DEG = 10.0, 170.0


def read_camera_file(path: str | Path) -> Intrinsics:
    """Read a ``camera.txt``: one ``key value`` a line (``key: value`` and ``key = value``
    too), keys ``fx fy cx cy`` in pixels and optionally ``depth_scale`` (raw depth units
    per metre, default 5000); ``#`` starts a comment.

    Args:
      path: the file.
    Returns:
      the :class:`Intrinsics`.
    Raises:
      InputError: naming the file (and line) for a file that cannot be read, a line that is
        not ``key value``, an unknown or repeated key, a value that is not a number, a
        missing key, or values no camera has (see :func:`check_intrinsics`).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"camera file not found: {path}")
    if not path.is_file():
        raise InputError(f"{path}: not a file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or "not a text file"
        raise InputError(f"{path}: cannot read ({why})") from None
    if path.suffix.lower() in OPENCV_SUFFIXES:
        return read_opencv_calibration(path)
    values: dict[str, float] = {}
    lens = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        words = line.replace(":", " ", 1).replace("=", " ", 1).split()
        if words[0] == "distortion":
            if lens is not None:
                raise InputError(f"{path}:{lineno}: distortion given twice")
            lens = _distortion_line(words[1:], where=f"{path}:{lineno}")
            continue
        m = _CAMERA_LINE.fullmatch(line)
        if m is None:
            raise InputError(f"{path}:{lineno}: expected 'key value', got {raw.strip()!r}")
        key, value = m.groups()
        if key not in CAMERA_KEYS:
            raise InputError(
                f"{path}:{lineno}: unknown key {key!r}; the keys are {', '.join(CAMERA_KEYS)} "
                "and a line 'distortion [MODEL] k1 k2 p1 p2 k3'"
            )
        if key in values:
            raise InputError(f"{path}:{lineno}: {key} given twice")
        try:
            values[key] = float(value)
        except ValueError:
            raise InputError(f"{path}:{lineno}: {value!r} is not a number") from None
    missing = [k for k in CAMERA_KEYS[:4] if k not in values]
    if missing:
        raise InputError(f"{path}: missing {', '.join(missing)}")
    K = Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"],
                   values.get("depth_scale", 5000.0), lens)
    check_intrinsics(K, where=str(path))
    return K


def _distortion_line(words: list[str], *, where: str) -> Distortion | None:
    """A camera.txt's ``distortion [MODEL] c1 c2 ...``: without a model, 4 or 5 numbers are
    OpenCV's ``k1 k2 p1 p2 [k3]`` (plumb_bob), 8 its rational model."""
    model = None
    if words and not re.fullmatch(r"[-+.\deE]+", words[0]):
        model, words = words[0], words[1:]
    if model is None:
        model = "rational_polynomial" if len(words) == 8 else "plumb_bob"
    try:
        coeffs = [float(w) for w in words]
    except ValueError:
        raise InputError(f"{where}: expected 'distortion [MODEL] k1 k2 p1 p2 k3', got "
                         f"{' '.join(words)!r}") from None
    return distortion(model, coeffs, where=where)


# cv::FileStorage's formats, read by cv2.FileStorage
OPENCV_SUFFIXES = (".yaml", ".yml", ".xml")


def read_opencv_calibration(path: str | Path, *, depth_scale: float = 5000.0) -> Intrinsics:
    """Read an OpenCV calibration file (``cv::FileStorage`` YAML or XML, as
    ``calibrateCamera`` samples and ROS's camera_calibration write it): ``camera_matrix``
    and ``distortion_coefficients`` (OpenCV's order: 4 or 5 plumb_bob, 8 the rational
    model), an optional ``distortion_model`` (ROS's names) and ``depth_scale``.

    Raises:
      InputError: naming the file for a file cv2 cannot parse, a missing or malformed
        camera matrix, coefficients no model takes, or values no camera has.
    """
    import cv2  # only for this format: camera.py loads without OpenCV

    path = Path(path)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        why = (str(exc).strip() or "not a cv::FileStorage file").splitlines()[-1]
        raise InputError(f"{path}: cannot read as an OpenCV calibration ({why})") from None
    if not fs.isOpened():
        raise InputError(f"{path}: cannot read as an OpenCV calibration")
    try:
        K = _opencv_matrix(fs.getNode("camera_matrix"))
        if K is None or K.size != 9:
            raise InputError(f"{path}: no 3x3 camera_matrix")
        D = _opencv_matrix(fs.getNode("distortion_coefficients"))
        model_node = fs.getNode("distortion_model")
        model = model_node.string() if model_node.isString() else ""
        scale_node = fs.getNode("depth_scale")
        scale = scale_node.real() if scale_node.isReal() or scale_node.isInt() else depth_scale
    finally:
        fs.release()
    coeffs = [] if D is None else D.ravel().tolist()
    if not model:
        model = "rational_polynomial" if len(coeffs) == 8 else "plumb_bob"
    try:
        camera = as_intrinsics(K.reshape(3, 3), where=str(path))
    except ValueError as exc:
        raise InputError(str(exc)) from None
    camera = Intrinsics(*(float(v) for v in camera[:4]), float(scale),
                        distortion(model, coeffs, where=str(path)))
    check_intrinsics(camera, where=str(path))
    return camera


def _opencv_matrix(node) -> np.ndarray | None:
    """A FileStorage node's numbers: an ``!!opencv-matrix`` or ROS's ``{rows, cols, data}``."""
    if node.empty():
        return None
    if node.isMap() and not node.getNode("data").empty():
        node = node.getNode("data")
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())], np.float64)
    mat = node.mat()
    return None if mat is None else np.asarray(mat, np.float64).ravel()


def read_calibration_file(path: str | Path) -> Intrinsics:
    """Read an ETH3D SLAM ``calibration.txt``: one line ``fx fy cx cy`` in pixels (depth
    5000 raw units per metre, as ETH3D's depth PNGs).

    Raises:
      InputError: naming the file for a file that is not four finite numbers (a fifth, which
        could be meant as the depth scale, is refused, not guessed), or values no camera has
        (:func:`check_intrinsics`).
    """
    path = Path(path)
    try:
        lines = [ln.split("#", 1)[0].split() for ln in path.read_text().splitlines()]
    except (OSError, UnicodeDecodeError) as exc:
        why = getattr(exc, "strerror", None) or "not a text file"
        raise InputError(f"{path}: cannot read ({why})") from None
    values = [v for ln in lines for v in ln]
    if len(values) == 5:
        raise InputError(f"{path}: ETH3D's calibration is 4 numbers 'fx fy cx cy', got 5 "
                         f"({' '.join(values)}); give a depth scale with --depth-scale or a "
                         "camera.txt (ETH3D's depth: 5000 per metre)")
    try:
        K = as_intrinsics([float(v) for v in values], where=str(path))
    except (ValueError, TypeError):
        raise InputError(f"{path}: expected one line 'fx fy cx cy' (pixels), got "
                         f"{' '.join(values)!r}") from None
    check_intrinsics(K, where=str(path))
    return K


def as_intrinsics(camera, *, where: str = "intrinsics") -> Intrinsics:
    """The :class:`Intrinsics` of what users pass for a camera.

    Args:
      camera: an :class:`Intrinsics`; a preset name (:data:`PRESETS`); ``(fx, fy, cx, cy)``
        or ``(fx, fy, cx, cy, depth_scale)``; a dict with keys ``fx fy cx cy`` and
        optionally ``depth_scale``; or a 3x3 camera matrix K (depth_scale 5000).
      where: how the message names it.
    Returns:
      the intrinsics (not range-checked: :func:`check_intrinsics`).
    Raises:
      ValueError: anything else, saying what is expected.
    """
    if isinstance(camera, Intrinsics):
        return camera
    if isinstance(camera, str):
        return preset(camera)
    expected = (f"{where} must be an Intrinsics, a preset name, (fx, fy, cx, cy[, "
                "depth_scale]) in pixels, a dict of those keys or a 3x3 camera matrix")
    if isinstance(camera, dict):
        unknown = set(camera) - set(Intrinsics._fields[:5])
        missing = [k for k in Intrinsics._fields[:4] if k not in camera]
        if unknown or missing:
            raise ValueError(f"{expected}; got keys {sorted(camera)}")
        camera = [camera[k] for k in Intrinsics._fields[:5] if k in camera]
    try:
        a = np.asarray(camera, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{expected}; got {type(camera).__name__}") from None
    if a.shape == (3, 3):
        if not np.allclose([a[0, 1], a[1, 0], a[2, 0], a[2, 1]], 0) or a[2, 2] != 1:
            raise ValueError(f"{where}: a camera matrix is [[fx, 0, cx], [0, fy, cy], "
                             f"[0, 0, 1]], got {a.tolist()}")
        return Intrinsics(a[0, 0], a[1, 1], a[0, 2], a[1, 2])
    if a.shape in ((4,), (5,)):
        return Intrinsics(*(float(v) for v in a))
    raise ValueError(f"{expected}; got shape {a.shape}")


def camera_info_intrinsics(msg, depth_scale: float) -> Intrinsics | str:
    """Pinhole intrinsics (pixels) from a ROS ``sensor_msgs/CameraInfo`` (ROS 1 ``K``, ROS 2
    ``k``) with ``depth_scale``, or why it holds none, in words (an all-zero K: an
    uncalibrated camera)."""
    K = np.asarray(msg.K if hasattr(msg, "K") else msg.k, np.float64)
    if K.size != 9:
        return f"its K has {K.size} values, not 9"
    if not np.any(K[[0, 2, 4, 5]]):
        return "its K is all zero (the camera driver had no calibration)"
    if not (np.all(np.isfinite(K)) and K[0] > 0 and K[4] > 0):
        return f"its K has fx {K[0]:g}, fy {K[4]:g} (no calibration)"
    return Intrinsics(float(K[0]), float(K[4]), float(K[2]), float(K[5]), float(depth_scale))


def camera_info_distortion(msg, *, where: str) -> tuple[Distortion | None, str | None]:
    """The lens distortion of a ROS ``sensor_msgs/CameraInfo`` (``distortion_model`` and
    ROS 1 ``D`` / ROS 2 ``d``; librealsense's recordings name its models) and a warning
    for a model jaxvo does not undo (a fisheye's: its images are then taken as pinhole).

    Raises:
      InputError: coefficients a model jaxvo undoes does not take (:func:`distortion`).
    """
    D = np.asarray(msg.D if hasattr(msg, "D") else msg.d, np.float64).ravel()
    model = str(getattr(msg, "distortion_model", "") or "")
    name = re.sub(r"[\s-]+", "_", model.strip().lower())
    if (_MODEL_NAMES.get(name, name) not in DISTORTION_MODELS and name not in ("none", "")
            and np.any(D != 0)):
        return None, (f"{where}: {model} distortion ({', '.join(f'{v:g}' for v in D)}) is "
                      f"not undone; jaxvo undoes {', '.join(DISTORTION_MODELS)} and takes "
                      "these images as pinhole")
    return distortion(model or "plumb_bob", D, where=where), None


# Median depth of a frame, metres, outside which no RGB-D sensor reads (host.readers.io's
# check_depth_scale); a depth scale that puts every 16-bit reading (1 to 65535 raw units)
# outside it is no sensor's either.
DEPTH_HARD_M = (0.1, 15.0)
_UINT16_MAX = 65535


def check_depth_scale_value(scale: float, *, name: str) -> None:
    """Raise :class:`~jaxvo.errors.InputError` for a depth scale (raw units per metre) that
    is not a positive number, or that puts every 16-bit reading nearer than 0.1 m or beyond
    15 m (``--depth-scale 1e-300`` made every depth infinite, ``1e300`` every depth 0).

    Args:
      scale: raw units per metre.
      name: what to call it in the message (``--depth-scale``, ``FILE: depth_scale``).
    """
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"{name} must be a positive number of raw units per metre, got "
                         f"{scale:g}")
    near, far = 1.0 / scale, _UINT16_MAX / scale
    if far < DEPTH_HARD_M[0] or near > DEPTH_HARD_M[1]:
        where_to = (f"nearer than {DEPTH_HARD_M[0]:g} m" if far < DEPTH_HARD_M[0]
                    else f"beyond {DEPTH_HARD_M[1]:g} m")
        raise InputError(
            f"{name} {scale:g} raw units per metre puts every 16-bit depth "
            f"reading (1 to {_UINT16_MAX} units: {near:.3g} to {far:.3g} m) {where_to}, where "
            "no RGB-D sensor reads; TUM's scale is 5000 per metre, millimetres 1000")


def intrinsics_option(text: str, *, where: str = "--intrinsics") -> Intrinsics:
    """The camera an ``--intrinsics fx,fy,cx,cy`` option gives (pixels; a negative fy: a
    camera whose y axis points up), checked as :func:`check_intrinsics` does without an
    image size.

    Raises:
      InputError: not four numbers, or no camera has them.
    """
    want = f"{where} must be four numbers fx,fy,cx,cy in pixels, got {text!r}"
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(want) from None
    if len(values) != 4:
        raise InputError(want)
    camera = as_intrinsics(values, where=where)
    check_intrinsics(camera, where=where)
    return camera


# The principal point of a real camera lies near the image centre: beyond a quarter of
# the image side from it, the intrinsics are another image size's (a 640x480 camera.txt
# kept beside images resized to 320x240 puts it at the image corner).
_CENTRE_SPAN = 0.25


def check_intrinsics(
    K: Intrinsics, *, where: str, width: int | None = None, height: int | None = None
) -> None:
    """Raise :class:`~jaxvo.errors.InputError` for intrinsics no camera has.

    Every value must be finite, ``fx`` and the depth scale positive and ``fy`` not 0 (a
    negative ``fy`` is a camera whose y axis points up, as ICL-NUIM's TUM-style
    calibration: its image rows run against y, and the poses are in that camera's axes);
    with the image size, the principal point must lie within a quarter of the image side
    of its centre and the focal lengths give a field of view of 10 to 170 degrees.

    Args:
      K: the intrinsics, pixels (depth_scale raw units per metre).
      where: what to name in the message (the file, or the preset).
      width, height: the image size, pixels, when known.
    """
    for name, value in zip(Intrinsics._fields[:5], K[:5]):
        if not np.isfinite(value):
            raise InputError(f"{where}: {name} is {value}, not a finite number")
    if K.fx <= 0:
        raise InputError(f"{where}: fx must be positive, got {K.fx:g}")
    check_depth_scale_value(K.depth_scale, name=f"{where}: depth_scale")
    if K.fy == 0:
        raise InputError(f"{where}: fy must not be 0 (negative: a camera whose y axis points up)")
    if width is None or height is None:
        return
    if not (0 <= K.cx <= width and 0 <= K.cy <= height):
        raise InputError(
            f"{where}: principal point ({K.cx:g}, {K.cy:g}) lies outside the "
            f"{width}x{height} image"
        )
    if (abs(K.cx - (width - 1) / 2) > _CENTRE_SPAN * width
            or abs(K.cy - (height - 1) / 2) > _CENTRE_SPAN * height):
        raise InputError(
            f"{where}: principal point ({K.cx:g}, {K.cy:g}) is far from the centre of the "
            f"{width}x{height} image, as in intrinsics for about {2 * K.cx + 1:.0f}x"
            f"{2 * K.cy + 1:.0f} images: scale fx fy cx cy to the image size"
        )
    for name, f, side in (("fx", K.fx, width), ("fy", abs(K.fy), height)):
        fov = float(np.degrees(2 * np.arctan2(side / 2, f)))
        if not _MIN_FOV_DEG <= fov <= _MAX_FOV_DEG:
            raise InputError(
                f"{where}: {name} {f:g} gives a {fov:.1f} degree field of view over "
                f"{side} pixels; RGB-D cameras see {_MIN_FOV_DEG:g} to {_MAX_FOV_DEG:g}"
            )


def write_camera_file(path: str | Path, K: Intrinsics, *, comment: str = "") -> None:
    lines = [f"# {comment}"] if comment else []
    lines += [f"fx {K.fx:.6g}", f"fy {K.fy:.6g}", f"cx {K.cx:.6g}", f"cy {K.cy:.6g}"]
    lines.append(f"depth_scale {K.depth_scale:.6g}")
    if K.distortion is not None:
        lines.append(" ".join(["distortion", K.distortion.model]
                              + [f"{v:.9g}" for v in K.distortion.coeffs]))
    from jaxvo.host.writers.outputs import write_text  # host.outputs imports nothing of this module

    write_text(path, "\n".join(lines) + "\n")


def depth_metres(depth: np.ndarray, K: Intrinsics) -> np.ndarray:
    """A depth image in metres, float32, 0 (or NaN) = no reading.

    ``uint16`` images are raw sensor units, divided by ``K.depth_scale`` (what
    ``cv2.imread(path, cv2.IMREAD_UNCHANGED)`` gives for TUM, Bonn or RealSense PNGs, and
    what Open3D scales by its ``depth_scale``); float images are metres already, and a value
    that is not finite (infinite: a sensor's "too far") or beyond float32 is no reading (0).

    Args:
      depth: (H, W) uint16 raw units or float metres.
      K: intrinsics, for ``depth_scale`` (raw units per metre).
    Returns:
      (H, W) float32 metres.
    Raises:
      ValueError: not a 2-D array, or of another dtype.
    """
    if not isinstance(depth, np.ndarray) or depth.ndim != 2:
        shape = getattr(depth, "shape", type(depth).__name__)
        raise ValueError(f"depth must be an (H, W) image, got {shape}")
    if depth.dtype == np.uint16:
        # 0 stays 0 (no reading) under the division
        return depth.astype(np.float32) / np.float32(K.depth_scale)
    if np.issubdtype(depth.dtype, np.floating):
        with np.errstate(over="ignore"):  # float64 beyond float32's range: no reading
            d = depth.astype(np.float32, copy=False)
        if np.isinf(d).any():  # a pass over the image; copied only where it holds one
            d = np.where(np.isinf(d), np.float32(0), d)
        return d
    raise ValueError(
        f"depth must be uint16 raw units (divided by depth_scale {K.depth_scale:g}) or "
        f"float metres, got {depth.dtype}"
    )


def backproject(uv: np.ndarray, z: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Pixels ``(..., 2)`` (x right, y down) with depth ``(...)`` metres -> ``(..., 3)`` points.

    With ``K.distortion`` each pixel is first undistorted to the ray it was seen along
    (:func:`jaxvo.host.frontend.distortion.undistort`), the depth being the reading at the pixel
    itself (a registered depth image holds each colour pixel's depth where that pixel is).
    """
    if K.distortion is not None:
        xn = undistort(uv, K)
        return (np.concatenate([xn, np.ones_like(xn[..., :1])], axis=-1)
                * np.asarray(z, np.float64)[..., None])
    x = (uv[..., 0] - K.cx) / K.fx * z
    y = (uv[..., 1] - K.cy) / K.fy * z
    return np.stack([x, y, z], axis=-1)


def project(points: np.ndarray, K: Intrinsics) -> np.ndarray:
    """``(..., 3)`` camera points -> ``(..., 2)`` pixels (no check on z > 0)."""
    z = points[..., 2]
    safe = np.where(np.abs(z) > 1e-9, z, 1e-9)
    return np.stack([K.fx * points[..., 0] / safe + K.cx, K.fy * points[..., 1] / safe + K.cy], -1)


def grid_pixels(height: int, width: int, cell: int) -> np.ndarray:
    """Centres of the flow grid's cells, ``(rows * cols, 2)`` float32 (x, y), row-major."""
    rows, cols = height // cell, width // cell
    ys = (np.arange(rows) + 0.5) * cell - 0.5
    xs = (np.arange(cols) + 0.5) * cell - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)
