"""Reading RGB-D sequences in the TUM RGB-D layout, and writing a run's trajectory pose by
pose (host side); trajectories themselves and their files: :mod:`jaxvo.trajectory`."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import (
    DEPTH_HARD_M,
    PRESETS,
    Intrinsics,
    check_intrinsics,
    depth_metres,
    preset,
    read_calibration_file,
    read_camera_file,
)

# what every sequence reader shares; its names stay importable from here too
from jaxvo.host.frontend.frames import (
    Frame,
    check_frame_size,
    describe,
    frame_index,
    given_camera,
    preset_from_name,
)
from jaxvo.host.readers.rosbag import BagSequence, is_bag

# the output checks, in a module of their own; their names stay importable from here too
from jaxvo.host.writers.outputs import (  # noqa: F401 (re-exported)
    STDOUT,
    OutputFile,
    check_outputs,
    output_file,
    output_folder,
    write_image,
    write_text,
)
from jaxvo.trajectory import (
    Trajectory,
    associate,
    data_lines,
    is_number,
    read_trajectory,
    tum_header,
    tum_lines,
)


def data_root() -> Path:
    """Where the real sequences live: ``$JAXVO_DATA``, else ``../shared/data`` beside the repo."""
    env = os.environ.get("JAXVO_DATA")
    if env:
        return Path(env)
    import jaxvo

    checkout = Path(jaxvo.__file__).resolve().parent.parent  # the folder holding jaxvo/
    return checkout.parent / "shared" / "data"


# --- RGB-D sequences in the TUM layout -------------------------------------------------


def _read_list(path: Path, columns: int, warnings: list[str]) -> tuple[np.ndarray, list[list[str]]]:
    """A TUM list file (``timestamp filename`` or ``t_rgb rgb t_depth depth``) in time order.

    Lines out of time order are sorted, and a line repeating an earlier line's timestamp
    is dropped (the first one stays); each is reported in ``warnings``, as recorders and
    hand edits produce both, and processing them as written sends the trajectory's time
    backwards or repeats a pose.

    Args:
      path: the file.
      columns: 2 or 4.
      warnings: list the warnings are appended to.
    Returns:
      ``(timestamps (N,) float64 seconds, rows)``, rows the split lines, both sorted.
    Raises:
      InputError: a line without the columns, or a timestamp that is not a finite number.
    """
    want = "timestamp filename" if columns == 2 else "timestamp rgb timestamp depth"
    stamps, rows, linenos = [], [], []
    for lineno, parts in data_lines(path):
        if len(parts) < columns or not all(is_number(parts[c]) for c in range(0, columns, 2)):
            raise InputError(f"{path}:{lineno}: expected '{want}', got {' '.join(parts)!r}")
        if not all(np.isfinite(float(parts[c])) for c in range(0, columns, 2)):
            raise InputError(f"{path}:{lineno}: timestamp is not a finite number")
        stamps.append(float(parts[0]))
        rows.append(parts)
        linenos.append(lineno)
    t = np.asarray(stamps, np.float64)
    order = np.argsort(t, kind="stable")
    if np.any(np.diff(t) < 0):
        k = int(np.flatnonzero(np.diff(t) < 0)[0])
        warnings.append(
            f"{path}: lines not in time order (line {linenos[k + 1]} at {t[k + 1]:.6f} s "
            f"follows line {linenos[k]} at {t[k]:.6f} s); sorted by timestamp"
        )
    t = t[order]
    repeat = np.zeros(len(t), bool)
    repeat[1:] = np.diff(t) == 0
    for k in np.flatnonzero(repeat):
        warnings.append(
            f"{path}:{linenos[order[k]]}: timestamp {t[k]:.6f} s repeats an earlier line; "
            "line dropped"
        )
    keep = order[~repeat]
    return t[~repeat], [rows[i] for i in keep]


def _read_image(path: Path, flags: int) -> np.ndarray:
    import cv2  # only where images are read: `jaxvo eval` never pays for OpenCV

    if not path.is_file():
        raise InputError(f"image not found: {path}")
    img = cv2.imread(str(path), flags)
    if img is None:
        raise InputError(f"cannot read image: {path}")
    return img


class TumSequence:
    """An RGB-D sequence in the TUM layout, frames read from disk only when asked for.

    The folder holds ``rgb.txt`` and ``depth.txt`` (``timestamp filename``), optionally
    ``associations.txt`` (``t_rgb rgb t_depth depth``; otherwise colour and depth are
    paired by nearest timestamp within ``max_diff``), ``groundtruth.txt`` (TUM
    trajectory), ``camera.txt`` (see :func:`jaxvo.host.frontend.camera.read_camera_file`) and, for
    synthetic data, ``mask.txt`` (``timestamp filename`` of uint8 object-id images, the
    same timestamps as ``rgb.txt``).

    Lines out of time order are sorted and repeated timestamps dropped; frames that find
    no partner within ``max_diff`` are left out. Each is said in :attr:`warnings`
    (``jaxvo run`` prints them), with the counts in :attr:`frames_listed`.

    Args:
      path: the folder.
      camera: a preset name of :data:`jaxvo.host.frontend.camera.PRESETS` or an :class:`Intrinsics`;
        overrides ``camera.txt`` (a warning says so where the two differ). Without either, a
        folder named as the TUM and Bonn benchmarks name their downloads
        (``..._freiburg3_...``, ``rgbd_bonn_...``) takes that camera's preset; otherwise
        one of the two is required.
      max_diff: largest colour-depth time difference when pairing them, seconds.
      depth_scale: raw depth units per metre, overriding the camera's (``--depth-scale``).

    Depth images are 16-bit PNGs of raw units (divided by the depth scale), or float
    metres: 32-bit float TIFF or ``.npy`` files.

    Attributes:
      warnings: list of one-line warnings about the folder's files (empty when clean).
      frames_listed: colour frames listed (after dropping repeats), associated or not.
      camera_source: where the intrinsics came from, in words.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        camera: str | Intrinsics | None = None,
        max_diff: float = 0.02,
        depth_scale: float | None = None,
    ) -> None:
        root = Path(path)
        if not root.is_dir():
            raise InputError(f"sequence folder not found: {root}")
        if not max_diff >= 0:  # also NaN
            raise InputError(f"max time difference must be >= 0 s, got {max_diff}")
        self.path = root
        self.name = root.resolve().name
        self.warnings: list[str] = []
        self.float_depth = False  # set when a frame is read: float depth is stored metres
        self.intrinsics, self.camera_source = self._intrinsics(root, camera)
        if depth_scale is not None:
            self.intrinsics = self.intrinsics._replace(depth_scale=float(depth_scale))
            self.camera_source += f", depth_scale {float(depth_scale):g} given"
            check_intrinsics(self.intrinsics, where=self.camera_source)

        assoc = root / "associations.txt"
        if assoc.is_file():
            self.timestamps, rows = _read_list(assoc, 4, self.warnings)
            self._rgb = [root / p[1] for p in rows]
            self._depth = [root / p[3] for p in rows]
            self.frames_listed = len(rows)
        else:
            t_rgb, rgb = _read_list(root / "rgb.txt", 2, self.warnings)
            t_depth, depth = _read_list(root / "depth.txt", 2, self.warnings)
            for name, rows in (("rgb.txt", rgb), ("depth.txt", depth)):
                if not rows:
                    raise InputError(f"{root / name}: no images listed")
            ia, ib = associate(
                t_rgb, t_depth, max_diff, names=(str(root / "rgb.txt"), str(root / "depth.txt"))
            )
            self.timestamps = t_rgb[ia]
            self._rgb = [root / rgb[i][1] for i in ia]
            self._depth = [root / depth[j][1] for j in ib]
            self.frames_listed = len(rgb)
            for name, count in (("rgb.txt", len(rgb)), ("depth.txt", len(depth))):
                if count > len(ia):
                    self.warnings.append(
                        f"{root / name}: {count - len(ia)} of {count} images have no "
                        f"{'depth' if name == 'rgb.txt' else 'colour'} image within "
                        f"{max_diff:g} s (--max-diff) and are left out"
                    )
        if len(self.timestamps) == 0:
            raise InputError(f"{root}: no frames listed")

        self._mask: list[Path] | None = None
        mask_list = root / "mask.txt"
        if mask_list.is_file():
            t_mask, rows = _read_list(mask_list, 2, self.warnings)
            # Masks carry the colour image's own stamps: match them to the microsecond.
            ia, ib = associate(self.timestamps, t_mask, 5e-7, names=("frames", str(mask_list)))
            if len(ia) != len(self.timestamps):
                missing = self.timestamps[np.setdiff1d(np.arange(len(self)), ia)[0]]
                raise InputError(f"{mask_list}: no mask for the frame at {missing:.6f} s")
            self._mask = [root / rows[j][1] for j in ib]

        gt = root / "groundtruth.txt"
        self.groundtruth = read_trajectory(gt) if gt.is_file() else None
        if depth_scale is not None and _stored_kind(self._depth[0]) == "f":  # metres: unused
            raise InputError(f"{self._depth[0]}: depth is float metres; --depth-scale is for "
                             "16-bit depth in raw units: leave it out")

        first = _read_image(self._rgb[0], _imread_color())
        self.height, self.width = first.shape[:2]
        check_intrinsics(self.intrinsics, where=self.camera_source, width=self.width,
                         height=self.height)

    def _intrinsics(self, root: Path, camera: str | Intrinsics | None) -> tuple[Intrinsics, str]:
        """The intrinsics and where they came from (said in ``jaxvo run``'s summary): the
        ``camera`` given, else ``camera.txt``, else the folder's name."""
        cam_file = root / "camera.txt"
        given = given_camera(camera)
        if given is not None:
            K, source = given
        elif cam_file.exists():
            return read_camera_file(cam_file), str(cam_file)
        elif (root / "calibration.txt").is_file():  # ETH3D SLAM's layout
            return read_calibration_file(root / "calibration.txt"), str(root / "calibration.txt")
        else:
            # a TUM or Bonn download as it unpacks: no camera.txt, the camera in its name
            guess = preset_from_name(root.resolve().name)
            if guess is None:
                raise InputError(
                    f"{root}: no camera.txt; pass a camera preset ({', '.join(sorted(PRESETS))}) "
                    "or the intrinsics (--intrinsics fx,fy,cx,cy), or write a camera.txt"
                )
            return preset(guess), f"preset {guess}, from the folder name"
        if cam_file.is_file():
            try:
                in_folder = read_camera_file(cam_file)
            except InputError:
                in_folder = None  # overridden anyway; its faults are not this run's
            if in_folder != K:
                self.warnings.append(
                    f"the camera {source} ({describe(K)}) overrides {cam_file} "
                    f"({describe(in_folder) if in_folder else 'unreadable'})"
                )
        return K, source

    def __len__(self) -> int:
        return len(self.timestamps)

    def __getitem__(self, index: int) -> Frame:
        """Read frame ``index`` from disk (negative indices count from the end)."""
        index = frame_index(index, len(self))
        bgr = _read_image(self._rgb[index], _imread_color())
        raw = _read_depth(self._depth[index])
        if raw.shape != bgr.shape[:2]:
            raise InputError(
                f"{self._depth[index]}: depth {raw.shape[1]}x{raw.shape[0]} does not match "
                f"colour {bgr.shape[1]}x{bgr.shape[0]} ({self._rgb[index].name})"
            )
        check_frame_size(str(self._rgb[index]), bgr, self.height, self.width)
        self.float_depth = raw.dtype.kind == "f"  # metres as stored, no depth scale applied
        depth = depth_metres(raw, self.intrinsics)
        mask = self._read_mask(index) if self._mask is not None else None
        return Frame(index, float(self.timestamps[index]), bgr, depth, mask)

    def files(self, frames: int | None = None) -> list[Path]:
        """What no output may overwrite (:func:`jaxvo.host.writers.outputs.check_outputs`): the
        lists, the camera, the ground truth, the images of the first ``frames`` frames
        (default all), and the folders of the images, every file of which is protected (the
        images of frames this run does not read too)."""
        names = ("rgb.txt", "depth.txt", "associations.txt", "groundtruth.txt", "camera.txt",
                 "calibration.txt", "mask.txt")
        out = [self.path / name for name in names if (self.path / name).exists()]
        n = len(self) if frames is None else min(frames, len(self))
        folders: dict[Path, None] = {}
        for paths in (self._rgb, self._depth, self._mask or []):
            out += paths[:n]
            folders.update(dict.fromkeys(p.parent for p in paths if p.parent != self.path))
        return out + [p for p in folders if p.is_dir()]

    def _read_mask(self, index: int) -> np.ndarray:
        path = self._mask[index]
        mask = _read_image(path, _imread_unchanged())
        if mask.ndim != 2 or mask.shape != (self.height, self.width):
            raise InputError(
                f"{path}: mask must be a single-channel {self.width}x{self.height} image, "
                f"got shape {mask.shape}"
            )
        if mask.dtype != np.uint8:
            if not np.issubdtype(mask.dtype, np.integer) or mask.max() > 255:
                raise InputError(f"{path}: mask ids must fit in uint8, got {mask.dtype}")
            mask = mask.astype(np.uint8)
        return mask

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        gt = "with" if self.groundtruth is not None else "without"
        return (
            f"TumSequence({self.name!r}, {len(self)} frames, {self.width}x{self.height}, "
            f"{gt} ground truth)"
        )


def _read_depth(path: Path) -> np.ndarray:
    """A depth image as stored: (H, W) uint16 raw units (PNG) or float metres (32-bit float
    TIFF, ``.npy``).

    Raises:
      InputError: naming the file and why it is no depth image (missing, undecodable,
        8-bit, several channels, another type).
    """
    if path.suffix.lower() == ".npy":
        if not path.is_file():
            raise InputError(f"image not found: {path}")
        try:
            raw = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot read depth {path}: {exc}") from None
    else:
        raw = _read_image(path, _imread_unchanged())
    want = "depth must be 16-bit raw units or float metres, single-channel"
    if raw.ndim != 2:
        raise InputError(f"{path}: depth has {raw.shape[2] if raw.ndim == 3 else raw.ndim} "
                         f"channels (a colour or JPEG image?); {want}")
    if raw.dtype == np.uint8:
        raise InputError(f"{path} is 8-bit; {want}")
    if raw.dtype != np.uint16 and not np.issubdtype(raw.dtype, np.floating):
        raise InputError(f"{path}: depth is {raw.dtype}; {want}")
    return raw


def _stored_kind(path: Path) -> str | None:
    """A depth image's dtype kind as stored; None if unreadable (dropped when reached)."""
    try:
        return _read_depth(path).dtype.kind
    except InputError:
        return None


def _imread_color() -> int:
    import cv2

    return cv2.IMREAD_COLOR


def _imread_unchanged() -> int:
    import cv2

    return cv2.IMREAD_UNCHANGED


def open_sequence(path: str | Path, *, rgb_topic: str | None = None,
                  depth_topic: str | None = None, **kwargs) -> TumSequence:
    """Open the RGB-D sequence at ``path``: a folder in the TUM layout, or a ROS bag (a
    ``.bag`` file or a ROS 2 bag folder, :class:`jaxvo.host.readers.rosbag.BagSequence`, whose image
    topics ``rgb_topic`` / ``depth_topic`` choose); ``kwargs`` go to the reader."""
    if is_bag(path):
        return BagSequence(path, rgb_topic=rgb_topic, depth_topic=depth_topic, **kwargs)
    if rgb_topic or depth_topic:
        raise InputError(f"{path}: not a ROS bag; --rgb-topic and --depth-topic are for bags")
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"sequence folder not found: {root}")
    if not (root / "associations.txt").is_file() and not (root / "rgb.txt").is_file():
        raise InputError(f"{root}: not a TUM RGB-D sequence (no rgb.txt or associations.txt)")
    return TumSequence(root, **kwargs)


def write_trajectory(path: str | Path, traj: Trajectory, *, comment: str = "") -> None:
    """Write a TUM trajectory file (:func:`jaxvo.trajectory.tum_lines`: timestamps ``%.6f``
    s, translation and quaternion ``%.9f``), whole or not at all.

    Args:
      path: the file to write (replaced whole, :class:`jaxvo.host.writers.outputs.OutputFile`).
      traj: timestamps (N,) seconds, poses (N, 4, 4) ``T_w_c``.
      comment: optional first lines (each written after ``# ``).
    """
    text = tum_header(comment) + tum_lines(traj.timestamps, traj.poses)
    write_text(path, text)  # whole or not at all, errors name the file


class TrajectoryWriter:
    """Writes a TUM trajectory one pose at a time (as :func:`write_trajectory`; ``"-"``:
    standard output), whole at every
    moment a reader can see: the poses go to a temporary file beside it, flushed pose by
    pose, which replaces the file on :meth:`close` (also
    after Ctrl-C, with the poses computed so far; after a second Ctrl-C as flushed,
    :func:`jaxvo.host.writers.outputs.abort_pending`). A failed run leaves the earlier file as it
    was (:class:`jaxvo.host.writers.outputs.OutputFile`); a failed write (a full disk) raises
    ``OSError`` naming the file.

    Example::

        with TrajectoryWriter("traj.txt") as w:
            for t, T in poses:
                w.write(t, T)
    """

    def __init__(self, path: str | Path, *, comment: str = ""):
        import sys

        self.path = Path(path)
        self.timestamps: list[float] = []  # what was written, as given
        self.poses: list[np.ndarray] = []
        self._stdout = str(path) == STDOUT
        if self._stdout:
            self._out = None
        else:
            if self.path.parent and not self.path.parent.exists():
                raise InputError(f"folder of the output trajectory does not exist: "
                                 f"{self.path.parent}")
            self._out = OutputFile(self.path, text=True, keep_on_abort=True)
        self._fh = sys.stdout if self._stdout else self._out.handle
        self._text: list[str] = []  # what the file holds
        self._header = tum_header(comment)
        self._put(self._header)

    def _put(self, text: str) -> None:
        try:
            self._fh.write(text)
            self._fh.flush()
        except OSError as exc:  # write() and flush() errors name no file of their own
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
        self._text.append(text)

    def write(self, timestamp: float, T_w_c: np.ndarray) -> None:
        T = np.asarray(T_w_c, np.float64)
        self._put(tum_lines([timestamp], T[None]))
        self.timestamps.append(float(timestamp))
        self.poses.append(T)

    def revise(self, revised: np.ndarray) -> int:
        """Replace the ``k`` poses written before the last one by ``revised`` (k, 4, 4) (a
        switch of the background redrew them, :attr:`jaxvo.odometry.FrameResult.revised`):
        the file is written again, whole at every moment as before. Standard output, a pipe
        or a device cannot take back what was printed: there the poses stay as they were
        and the count of those left unrevised is returned (0 where the file holds them)."""
        k = len(revised)
        if k == 0:
            return 0
        if self._stdout or self._out.temporary is None:
            return k
        self.poses[-1 - k:-1] = [np.asarray(T, np.float64) for T in revised]
        # the whole text in one write after the truncation: an abrupt end can only find the
        # file empty of poses for the time of that one write
        text = self._header + tum_lines(np.asarray(self.timestamps), np.asarray(self.poses))
        self._text = []
        try:
            self._fh.seek(0)
            self._fh.truncate()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
        self._put(text)
        return 0

    def written(self) -> Trajectory:
        """The poses as the file holds them (rounded as printed), read from what this writer
        wrote, not from the file, which another run may have replaced since; standard
        output's: :attr:`trajectory`."""
        if self._stdout:
            return self.trajectory
        return read_trajectory(self.path, text="".join(self._text))

    @property
    def trajectory(self) -> Trajectory:
        """The poses written so far, as given (before the file's rounding)."""
        return Trajectory(np.asarray(self.timestamps, np.float64),
                          np.asarray(self.poses, np.float64).reshape(-1, 4, 4))

    def close(self) -> None:
        """Put the file in place with every pose written (idempotent)."""
        if self._out is not None:
            self._out.commit()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        # Ctrl-C (KeyboardInterrupt) keeps the poses computed; an error keeps the old file
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        elif self._out is not None:
            self._out.discard()


# Median depth of a frame, metres: outside the hard band no RGB-D sensor reads (the depth
# scale is wrong, e.g. 1000 for millimetres against TUM's 5000, or float depth that is not
# metres); outside the soft band it is possible but unusual for the structured-light and
# time-of-flight cameras of these datasets (0.5 m: the nearest range of the Kinect and
# Xtion sensors of TUM, Bonn and ICL-style data), so it is said but run.
_DEPTH_HARD_M = DEPTH_HARD_M
_DEPTH_SOFT_M = (0.5, 8.0)
# The depth scales of the sensors' files: TUM, Bonn, ETH3D 5000 per metre; millimetres 1000.
# A wrong one of these is the usual mistake, and it can stay inside the soft band (a room
# 2-4 m deep in millimetres read at 5000 per metre: median 0.4-0.6 m). So where the view's
# depths lie is also compared with the typical indoor depth, the soft band's geometric
# centre (2 m): when another common scale puts it nearer (in ratio), that scale is the
# likelier one. Where the depths lie is the middle, in ratio, of the span the view reads
# (_SPAN_PERCENTILES), not the median: an object filling most of the view near the camera
# moves the median to itself, while the span still reaches the room behind it, and a wrong
# scale moves the whole span (docs/report/host_decisions.md).
_COMMON_SCALES = (5000.0, 1000.0)
_TYPICAL_M = float(np.sqrt(_DEPTH_SOFT_M[0] * _DEPTH_SOFT_M[1]))
_SPAN_PERCENTILES = (1.0, 99.0)


class DepthScaleWarning(UserWarning):
    """A frame's depth is possible but unusual for an RGB-D sensor (see
    :func:`check_depth_scale`): the depth scale may be wrong."""


def check_depth_scale(depth: np.ndarray, K, *, where: str, raw_units: bool = True) -> str | None:
    """Check the median of a frame's valid depth readings against what RGB-D sensors see.

    Args:
      depth: (H, W) float metres, 0 = no reading.
      K: the intrinsics whose ``depth_scale`` made ``depth`` (named in the messages).
      where: the frame, for the messages.
      raw_units: the depth was raw units divided by ``K.depth_scale`` (else it was given as
        float metres, and the message says so).
    Returns:
      a one-line warning when the frame has no depth reading at all (every value 0, NaN or
      infinite: every pair with it lacks depth), when the median lies outside 0.5 to 8 m,
      or when another common depth scale (5000 or 1000 per metre) puts the middle of the
      depths the view spans (1st to 99th percentile, in ratio) nearer the typical 2 m; else
      None.
    Raises:
      InputError: the median lies outside 0.1 to 15 m.
    """
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return (f"{where}: no depth reading (every value is 0, negative, NaN or infinite): "
                "frame pairs without depth give no motion; check the depth images")
    med = float(np.median(valid))
    likelier = []
    if raw_units:
        at = {s: med * K.depth_scale / s for s in _COMMON_SCALES if s != K.depth_scale}
        centre = float(np.sqrt(np.prod(np.percentile(valid, _SPAN_PERCENTILES))))
        likelier = [s for s in at if abs(np.log(centre * K.depth_scale / s / _TYPICAL_M))
                    < abs(np.log(centre / _TYPICAL_M))]
        hint = (f"median depth is {med:.3g} m with depth_scale {K.depth_scale:g} ("
                + ", ".join(f"{m:.3g} m at {s:g}" for s, m in at.items())
                + "; TUM uses 5000 per metre, millimetre sensors 1000)")
    else:
        hint = (f"median of the float depth is {med:.3g}, read as metres (millimetres or "
                "raw units? give float depth in metres, or uint16 raw units with the "
                "intrinsics' depth_scale)")
    if not _DEPTH_HARD_M[0] <= med <= _DEPTH_HARD_M[1]:
        raise InputError(f"{where}: {hint}: the depth scale looks wrong")
    if likelier:
        return (f"{where}: {hint}: depth_scale {likelier[0]:g} is likelier (--depth-scale): "
                "check the depth scale")
    if not _DEPTH_SOFT_M[0] <= med <= _DEPTH_SOFT_M[1]:
        return f"{where}: {hint}: check the depth scale"
    return None


def first_readable(reads, *, where: str, total: int):
    """The first frame that can be read, and the reads taken to find it.

    Args:
      reads: ``(index, get)`` pairs in frame order, ``get()`` returning the frame or
        raising :class:`InputError` (a read-ahead future's ``result``, or a read).
      where: the sequence, for the message.
      total: how many frames ``reads`` holds, for the message.
    Returns:
      ``(frame, taken)``: ``taken`` the pairs consumed (the unreadable ones, then the
      frame's), for a loop over all frames to go through again.
    Raises:
      InputError: no frame can be read, naming the first one's file and why.
    """
    taken, first_error = [], None
    for i, get in reads:
        taken.append((i, get))
        try:
            return get(), taken
        except InputError as exc:
            first_error = first_error or exc
    raise InputError(f"{where}: none of the {total} frames can be read (first: {first_error})")


def first_pose(seq) -> np.ndarray:
    """(4, 4) float64 pose of a sequence's first camera: its first ground-truth pose when it
    has one a frame (estimated and true trajectories then share a frame without
    alignment), else the identity."""
    gt = getattr(seq, "groundtruth", None)
    if gt is not None and len(gt) == len(seq):
        return np.asarray(gt.poses[0], np.float64)
    return np.eye(4)


def groundtruth_of_frames(seq, idx: np.ndarray) -> Trajectory | None:
    """The ground truth of frames ``idx`` of ``seq``: the same poses when it has one a
    frame, else the trajectory as it is (the metrics associate it by timestamp)."""
    gt = getattr(seq, "groundtruth", None)
    if gt is not None and len(gt) == len(seq):
        return Trajectory(np.asarray(gt.timestamps)[idx], np.asarray(gt.poses)[idx])
    return gt


class InMemorySequence:
    """``frames`` frames of a sequence from ``start`` on, read (or rendered) once and kept in
    memory.

    With ``step`` k, every k-th frame (start, start + k, ...): the same images with k times
    the motion between frames, a fast-motion test with the sequence's own ground truth.

    jaxvo and every peer then read the same frames, and rendering a synthetic frame (about
    0.1 s) is paid once instead of once per method.
    """

    def __init__(self, seq, frames: int | None = None, *, step: int = 1, start: int = 0):
        if int(step) < 1:
            raise InputError(f"frame step must be at least 1, got {step}")
        if int(start) < 0:
            raise InputError(f"start frame must be 0 or more, got {start}")
        idx = np.arange(int(start), len(seq), int(step))
        idx = idx if frames is None else idx[: max(int(frames), 0)]
        self.name = seq.name if step == 1 else f"{seq.name}_every{int(step)}"
        self.intrinsics = seq.intrinsics
        self.height, self.width = seq.height, seq.width
        self.timestamps = np.asarray(seq.timestamps, np.float64)[idx]
        self._frames = [seq[int(i)] for i in idx]
        self.groundtruth = groundtruth_of_frames(seq, idx)
        self.has_masks = self._frames[0].mask is not None
        # a synthetic sequence's moving objects, on the frames kept
        self.scenario = getattr(seq, "scenario", None)
        self.object_trajectories = {
            k: Trajectory(np.asarray(t.timestamps)[idx], np.asarray(t.poses)[idx])
            for k, t in getattr(seq, "object_trajectories", {}).items()}

    def __len__(self) -> int:
        return len(self._frames)

    def __getitem__(self, index: int):
        return self._frames[index]

    def __iter__(self):
        return iter(self._frames)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return float(self.timestamps[-1] - self.timestamps[0]) if len(self) > 1 else 0.0
