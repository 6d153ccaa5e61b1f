"""A synthetic scene rendered frame by frame with exact ground truth (host).

:class:`SyntheticSequence` lays out a textured room with furniture (or a real sequence's
frames, for a composite), moves the camera and ``K`` rigid textured boxes on their seeded
paths, and ray-casts each frame on demand with :mod:`jaxvo.synth.render`; nothing is cached.
Conventions: OpenCV camera frame (x right, y down, z forward); the synthetic world frame is
the camera frame at rest (y points down, to the floor).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from jaxvo.errors import InputError, check_seed
from jaxvo.host.frontend.camera import PRESETS, Distortion, Intrinsics
from jaxvo.host.readers.io import Frame, TumSequence
from jaxvo.synth.scenario import ObjectSpec, Scenario, SensorOptions
from jaxvo.trajectory import Trajectory

DEPTH_SCALE = 5000.0  # raw 16-bit units per metre in written depth PNGs (as TUM)

# The room, in the world frame (metres; y down: the floor is at y = +1.1, the ceiling at
# y = -1.3, the camera at rest at the origin looking along +z).
ROOM_CENTRE = (0.0, -0.1, 0.95)
ROOM_HALF = (2.2, 1.2, 2.45)

# Atlas layout: 24 textures of 512 x 512 texels, 6 per row, each padded by one texel.
# Room faces use textures 0-5, furniture 6-15, moving objects 16-23 (see _build).
_N_TEX, _TILE, _COLS = 24, 512, 6
_ROOM_DENSITY = 150.0  # texels per metre: one tile spans 3.4 m on the walls
_FURNITURE_DENSITY = 260.0
_OBJECT_DENSITY = 420.0  # small faces, finer texture: no visible repeat on an object
_PAD_BOXES = 10  # room + 5 furniture + up to 4 objects render with one compiled program
_MARGIN = 0.05  # metres: the camera must stay this far outside every box


# ------------------------------------------------------------------------------- the room


def _furniture(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Static boxes standing on the floor: (T_w_b, half extents); small seeded jitter."""
    floor = ROOM_CENTRE[1] + ROOM_HALF[1]
    layout = [  # centre x, z; half extents
        ((-1.55, 2.85), (0.5, 0.55, 0.4)),  # cabinet, back left
        ((1.35, 2.45), (0.6, 0.36, 0.45)),  # low table, right
        ((1.9, 0.35), (0.25, 1.0, 0.55)),  # tall shelf, right wall
        ((-1.75, 0.75), (0.3, 0.25, 0.35)),  # crate, left
        ((0.2, 3.2), (0.7, 0.18, 0.18)),  # bench along the back wall
    ]
    out = []
    for (x, z), half in layout:
        yaw = rng.uniform(-0.15, 0.15)
        c, s = np.cos(yaw), np.sin(yaw)
        T = np.eye(4)
        T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        T[:3, 3] = (x + rng.uniform(-0.05, 0.05), floor - half[1], z + rng.uniform(-0.05, 0.05))
        out.append((T, np.array(half, np.float64)))
    return out


# --------------------------------------------------------------------------- textures


@lru_cache(maxsize=4)
def make_atlas(seed: int) -> np.ndarray:
    """Seeded texture atlas: ``_N_TEX`` tileable textures with structure at every scale.

    Each texture is 1/f^beta colour noise (energy from one texel up to the tile size) with
    a texture-specific pattern on top (rectangles, discs, strokes or speckles), so that
    no surface is flat and no two faces repeat the same periodic pattern.

    Returns:
      (rows * (tile + 2), cols * (tile + 2), 3) uint8 BGR image; tile ``i`` sits at
      row ``i // cols``, column ``i % cols`` with a one-texel wrapped border. Cached per
      seed (treat it as read-only).
    """
    rng = np.random.default_rng([seed, 1])
    n = _TILE
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    f = np.hypot(fx, fy)
    f[0, 0] = 1.0
    rows = -(-_N_TEX // _COLS)
    stride = n + 2
    atlas = np.zeros((rows * stride, _COLS * stride, 3), np.uint8)
    for i in range(_N_TEX):
        beta = rng.uniform(0.8, 1.25)
        amp = f ** -beta
        amp[0, 0] = 0.0
        chans = []
        for _ in range(3):
            # Gaussian white noise shaped by amp: random phases, Rayleigh magnitudes.
            spec = amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape))
            ch = np.fft.irfft2(spec, s=(n, n))
            chans.append(ch / (ch.std() + 1e-12))
        lum = chans[0]
        hsv = np.uint8([[[rng.integers(0, 180), rng.integers(40, 200), rng.integers(90, 190)]]])
        base = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0].astype(np.float64)
        img = base[None, None, :] * (1.0 + 0.28 * lum[..., None])
        img[..., 0] += 14.0 * chans[1]
        img[..., 1] += 14.0 * chans[2]
        img[..., 2] += 14.0 * (chans[1] - chans[2])
        img = _draw_pattern(rng, np.clip(img, 0, 255).astype(np.uint8), i % 4)
        r, c = divmod(i, _COLS)
        atlas[r * stride:(r + 1) * stride, c * stride:(c + 1) * stride] = np.pad(
            img, ((1, 1), (1, 1), (0, 0)), mode="wrap")
    atlas.setflags(write=False)
    return atlas


def _draw_pattern(rng: np.random.Generator, img: np.ndarray, kind: int) -> np.ndarray:
    """Overlay shapes, drawn in all nine wrapped positions so the tile stays seamless."""
    n = img.shape[0]
    over = img.copy()
    count = (24, 30, 40, 400)[kind]
    for _ in range(count):
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y = (int(v) for v in rng.integers(0, n, 2))
        size = int(rng.integers(6, 70)) if kind < 3 else int(rng.integers(1, 5))
        reach = 2 * size + 90  # no shape extends further than this from its anchor
        for dx in (-n, 0, n):
            for dy in (-n, 0, n):
                p = (x + dx, y + dy)
                if not (-reach < p[0] < n + reach and -reach < p[1] < n + reach):
                    continue
                if kind == 0:
                    q = (p[0] + size, p[1] + int(size * rng.uniform(0.3, 1.5)))
                    cv2.rectangle(over, p, q, colour, -1)
                elif kind == 1 or kind == 3:
                    cv2.circle(over, p, size // 2 + 1, colour, -1, cv2.LINE_AA)
                else:
                    q = (p[0] + int(rng.integers(-80, 80)), p[1] + int(rng.integers(-80, 80)))
                    cv2.line(over, p, q, colour, int(rng.integers(1, 6)), cv2.LINE_AA)
    return cv2.addWeighted(img, 0.45, over, 0.55, 0.0)


# ------------------------------------------------------------------------- trajectories


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: rotation by ``angle`` radians about unit ``axis``."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def _look_at(position: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """T_w_c of an OpenCV camera at ``position`` looking at ``target``, world y down."""
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1) @ _rot(np.array([0.0, 0.0, 1.0]), roll)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T


class _CameraPath:
    """A smooth seeded camera path: sums of sines in position, a wandering look-at target."""

    def __init__(self, rng: np.random.Generator, scenario: Scenario) -> None:
        self.fixed = scenario.camera == "fixed"
        self.target = np.array(scenario.look_at, np.float64)
        k = 4
        self.w = 2 * np.pi / rng.uniform(2.5, 6.0, size=(k, 3))  # rad/s per term and axis
        self.phase = rng.uniform(0, 2 * np.pi, size=(k, 3))
        amp = rng.uniform(0.5, 1.0, size=(k, 3)) * np.array([1.0, 0.4, 0.6])
        # Scale to the requested mean speed over the first 5 s (a fixed window, so that the
        # path does not depend on the number of frames asked for; short sequences are the
        # common case and should move as fast as asked).
        t = np.linspace(0, 5, 501)
        vel = np.einsum("kd,kd,tkd->td", amp, self.w,
                        np.cos(self.w[None] * t[:, None, None] + self.phase[None]))
        speed = np.linalg.norm(vel, axis=1).mean()
        self.amp = amp * (scenario.camera_speed / speed) if speed > 0 else amp * 0
        self.amp = self.amp * scenario.camera_wander
        self.speed_scale = 1.0 / scenario.camera_wander if scenario.camera_wander > 0 else 1.0
        self.w = self.w * self.speed_scale  # keep the speed when the extent shrinks
        self.wander_w = 2 * np.pi / rng.uniform(4.0, 9.0, size=3)
        self.wander_phase = rng.uniform(0, 2 * np.pi, size=4)

    def pose(self, t: float) -> np.ndarray:
        if self.fixed:
            return _look_at(np.zeros(3), self.target, 0.0)
        pos = np.sum(self.amp * np.sin(self.w * t + self.phase), axis=0)
        wander = 0.25 * np.sin(self.wander_w * t + self.wander_phase[:3]) * [1.0, 0.4, 0.5]
        roll = 0.06 * np.sin(0.9 * t + self.wander_phase[3])
        return _look_at(pos, self.target + wander, roll)


class _ObjectPath:
    """T_w_o(t) of one moving box (see :class:`ObjectSpec`)."""

    def __init__(self, rng: np.random.Generator, spec: ObjectSpec) -> None:
        self.spec = spec
        self.centre = np.array(spec.centre, np.float64)
        self.amp = np.array(spec.amplitude, np.float64)
        self.w = 2 * np.pi / np.array(spec.period, np.float64)
        drawn = rng.uniform(0, 2 * np.pi, size=3)
        self.phase = drawn if spec.phase is None else np.array(spec.phase, np.float64)
        axis = rng.normal(size=3)
        self.axis = axis / np.linalg.norm(axis)
        a0 = rng.normal(size=3)
        self.R0 = _rot(a0 / np.linalg.norm(a0), rng.uniform(0, 0.5))

    def clock(self, t: float) -> float:
        """The path's own time at ``t`` seconds from the first frame: it stands still during
        each stop."""
        return t - sum(float(np.clip(t, a, b)) - a for a, b in self.spec.stops)

    def pose(self, t: float) -> np.ndarray:
        """``T_w_o`` at the path's own time ``t`` (see :meth:`clock`)."""
        T = np.eye(4)
        T[:3, :3] = self.R0 @ _rot(self.axis, self.spec.spin * t)
        T[:3, 3] = self.centre + self.amp * np.sin(self.w * t + self.phase)
        return T


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """(4, 4) the average of ``poses`` (k, 4, 4): mean position, and the mean of the
    rotation matrices re-orthonormalised (the nearest rotation)."""
    u, _, vt = np.linalg.svd(poses[:, :3, :3].mean(axis=0))
    R = u @ vt
    if np.linalg.det(R) < 0:
        R = u @ np.diag([1, 1, -1]) @ vt
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return out


def smooth_poses(poses: np.ndarray, half_window: int) -> np.ndarray:
    """(N, 4, 4) the moving average (:func:`mean_pose`) of ``poses`` over ``2 half_window +
    1`` frames, shortened at both ends."""
    n = len(poses)
    return np.stack([mean_pose(poses[max(0, i - half_window):min(n, i + half_window + 1)])
                     for i in range(n)]) if n else np.empty_like(poses)


def _inside(T_w_b: np.ndarray, half: np.ndarray, point: np.ndarray, margin: float) -> bool:
    p = T_w_b[:3, :3].T @ (point - T_w_b[:3, 3])
    return bool(np.all(np.abs(p) < half + margin))


# --------------------------------------------------------------------------- sequences


# Where the depth of a surface, remapped through a lens, takes the bilinear blend of its
# pinhole neighbours rather than the nearest one: when the two agree to this fraction (one
# surface); across an edge the nearest reading keeps the edge sharp.
_SAME_SURFACE = 0.02


def _lens_maps(K: Intrinsics, lens: Distortion, height: int, width: int):
    """(map_x, map_y) (H, W) float32: the pinhole pixel each pixel of the image seen
    through ``lens`` shows (``cv2.remap``'s maps)."""
    from jaxvo.host.frontend.distortion import undistort

    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    xn = undistort(np.stack([u, v], axis=-1), K._replace(distortion=lens))
    return ((K.fx * xn[..., 0] + K.cx).astype(np.float32),
            (K.fy * xn[..., 1] + K.cy).astype(np.float32))


def _through_lens(maps, texels, shade, depth, label):
    """A pinhole render's colour, shade, depth and labels as the lens shows them: colour
    bilinear; depth bilinear on one surface, else the nearest reading; shade and labels
    nearest. Pixels whose ray leaves the pinhole view see nothing (depth inf)."""
    map_x, map_y = maps
    near, lin = cv2.INTER_NEAREST, cv2.INTER_LINEAR
    depth = np.asarray(depth, np.float32)
    z_near = cv2.remap(depth, map_x, map_y, near, borderValue=float("inf"))
    with np.errstate(invalid="ignore"):
        z_lin = cv2.remap(depth, map_x, map_y, lin, borderValue=float("inf"))
        z = np.where(np.abs(z_lin - z_near) <= _SAME_SURFACE * z_near, z_lin, z_near)
    return (cv2.remap(texels, map_x, map_y, lin),
            cv2.remap(np.asarray(shade, np.float32), map_x, map_y, near),
            z.astype(np.float32),
            cv2.remap(np.asarray(label, np.int32).astype(np.float32), map_x, map_y,
                      near).astype(np.int32))


@dataclass
class RealBackground:
    """A real sequence to composite into: frames, ground-truth pose per frame."""

    seq: TumSequence
    index: np.ndarray  # (N,) frame indices into ``seq`` that have ground truth
    poses: np.ndarray  # (N, 4, 4) T_w_c
    anchors: np.ndarray  # (N, 4, 4) smoothed camera poses the objects move around
    z_scale: float  # shrinks the preset's distances to fit the real scene


class SyntheticSequence:
    """A seeded dynamic RGB-D sequence with exact ground truth, rendered frame by frame.

    Build one with :func:`make_sequence`. Interface as ``io.TumSequence``: ``name``,
    ``intrinsics``, ``height``, ``width``, ``timestamps`` (N,) s, ``groundtruth``
    (``Trajectory`` of ``T_w_c``), ``len``, indexing and iteration give ``io.Frame`` with
    ``mask`` (uint8 object id, 0 = static). Also ``object_trajectories`` (id ->
    ``Trajectory`` of ``T_w_o``), ``scenario``, ``seed``, ``options``.
    """

    def __init__(self, scenario: Scenario, *, frames: int, seed: int,
                 options: SensorOptions, fps: float,
                 background: RealBackground | None = None, name: str | None = None,
                 lens: Distortion | None = None) -> None:
        self.scenario = scenario
        self.seed = check_seed(seed)
        self.options = options
        self.fps = float(fps)
        self._background = background
        self.name = name or f"synth_{scenario.name}_s{self.seed}"
        if background is None:
            self.intrinsics = PRESETS["ros_default"]._replace(depth_scale=DEPTH_SCALE)
            self.height, self.width = 480, 640
            self.timestamps = np.arange(frames, dtype=np.float64) / self.fps
        else:
            self.intrinsics = background.seq.intrinsics._replace(depth_scale=DEPTH_SCALE)
            self.height, self.width = background.seq.height, background.seq.width
            self.timestamps = background.seq.timestamps[background.index].astype(np.float64)

        self._lens = None if lens is None else _lens_maps(self.intrinsics, lens, self.height,
                                                          self.width)
        if lens is not None:
            if background is not None:
                raise InputError("a composite keeps its real images' lens: no distortion")
            self.intrinsics = self.intrinsics._replace(distortion=lens)
        self._atlas = make_atlas(self.seed)
        self._follow_anchors: dict[float, np.ndarray] = {}  # composites: follow -> anchors
        rng = np.random.default_rng([self.seed, 2])
        self._camera = _CameraPath(rng, scenario)
        self._objects = [_ObjectPath(rng, spec) for spec in scenario.objects]
        if background is not None:
            for path in self._objects:
                path.centre = path.centre * [1.0, 1.0, background.z_scale]
                path.amp = path.amp * [1.0, 1.0, background.z_scale]
        self._furniture = [] if background is not None else _furniture(rng)

        halves = [np.array(s.size, np.float64) / 2 for s in scenario.objects]
        statics: list[tuple[np.ndarray, np.ndarray, bool, int, float, int]] = []
        if background is None:
            room = np.eye(4)
            room[:3, 3] = ROOM_CENTRE
            statics.append((room, np.array(ROOM_HALF), True, 0, _ROOM_DENSITY, 0))
            for j, (T, half) in enumerate(self._furniture):
                statics.append((T, half, False, 6 + 2 * j, _FURNITURE_DENSITY, 0))
        self._static_boxes = statics
        self._halves = halves
        self._check(halves)

        t = self.timestamps
        self.groundtruth = Trajectory(t.copy(), np.stack([self._camera_pose(i) for i in
                                                          range(len(t))]))
        self.object_trajectories = {
            k + 1: Trajectory(t.copy(), np.stack([self._object_pose(k, i, t[i])
                                                  for i in range(len(t))]))
            for k in range(len(self._objects))
        }
        self._build_static_arrays()
        # Render tiles of about 80 x 80 pixels (a grid that divides the image exactly).
        self._grid = tuple(next(g for g in range(max(1, n // 80), 0, -1) if n % g == 0)
                           for n in (self.height, self.width))

    # ---- poses

    def _camera_pose(self, i: int, t: float | None = None) -> np.ndarray:
        if self._background is not None:
            return self._background.poses[i]
        return self._camera.pose(self.timestamps[i] if t is None else t)

    def _object_pose(self, k: int, i: int, t: float) -> np.ndarray:
        # paths run on the time since the first frame (a real sequence's timestamps may be
        # large: sin of 1.3e9 s keeps few significant digits), on the object's own clock
        path = self._objects[k]
        tau = path.clock(t - float(self.timestamps[0]))
        T_local = path.pose(tau)
        follow = path.spec.follow
        if self._background is not None or follow is not None:
            # the anchor follows the object's clock too, so a stop stops the object in the
            # world (and it moves on from there, its anchor as far behind as it stood)
            return self._anchor(tau, follow) @ T_local
        return T_local

    def _anchor(self, tau: float, follow: float | None = None) -> np.ndarray:
        """The camera pose averaged over ``follow`` seconds (None: the composite's 3 s
        anchors) that an object moves around, at ``tau`` seconds from the first frame:
        translation interpolated between frames, rotation of the nearer frame."""
        if self._background is None:  # the synthetic camera path is known at any time
            half = round(follow * self.fps / 2)
            t0 = float(self.timestamps[0])
            return mean_pose(np.stack([self._camera.pose(t0 + tau + j / self.fps)
                                       for j in range(-half, half + 1)]))
        if follow is None:
            anchors = self._background.anchors
        else:
            if follow not in self._follow_anchors:
                self._follow_anchors[follow] = smooth_poses(
                    self._background.poses, round(follow * self.fps / 2))
            anchors = self._follow_anchors[follow]
        since = self.timestamps - self.timestamps[0]
        j = int(np.clip(np.searchsorted(since, tau, side="right") - 1, 0, len(since) - 1))
        j1 = min(j + 1, len(since) - 1)
        span = since[j1] - since[j]
        a = float(np.clip((tau - since[j]) / span, 0.0, 1.0)) if span > 0 else 0.0
        out = anchors[j1 if a >= 0.5 else j].copy()
        out[:3, 3] = (1 - a) * anchors[j][:3, 3] + a * anchors[j1][:3, 3]
        return out

    def _check(self, halves: list[np.ndarray]) -> None:
        room_min = 2 * min(ROOM_HALF)
        for k, h in enumerate(halves, start=1):
            if np.any(h <= 0):
                raise InputError(f"object {k}: size must be positive, got {tuple(2 * h)}")
            if self._background is None and 2 * np.linalg.norm(h) >= room_min:
                raise InputError(
                    f"object {k} of size {tuple(np.round(2 * h, 3))} m does not fit in the "
                    f"room (smallest room dimension {room_min:.2f} m)")
        for i, t in enumerate(self.timestamps):
            c = self._camera_pose(i)[:3, 3]
            for k, h in enumerate(halves):
                if _inside(self._object_pose(k, i, t), h, c, _MARGIN):
                    raise InputError(f"the camera is inside object {k + 1} at frame {i} "
                                     f"(t = {t:.3f} s); move the object or the camera path")
            if self._background is None:
                room = self._static_boxes[0]
                if not _inside(room[0], room[1] - _MARGIN, c, 0.0):
                    raise InputError(f"the camera leaves the room at frame {i} (t = {t:.3f} s)")
                for T, h, *_ in self._static_boxes[1:]:
                    if _inside(T, h, c, _MARGIN):
                        raise InputError(f"the camera is inside the furniture at frame {i} "
                                         f"(t = {t:.3f} s)")

    def _build_static_arrays(self) -> None:
        n_obj = len(self._objects)
        s = self._static_boxes
        self._b_half = np.array([b[1] for b in s] + self._halves, np.float32).reshape(-1, 3)
        self._b_inside = np.array([b[2] for b in s] + [False] * n_obj, bool)
        self._b_tex = np.array([b[3] for b in s] + [16 + 3 * k for k in range(n_obj)], np.int32)
        self._b_dens = np.array([b[4] for b in s] + [_OBJECT_DENSITY] * n_obj, np.float32)
        self._b_label = np.array([0] * len(s) + list(range(1, n_obj + 1)), np.int32)
        # Pad with disabled boxes to a common count, so every preset (and compositing)
        # shares one compiled renderer; disabled boxes cost nothing (skipped by lax.cond).
        pad = max(0, _PAD_BOXES - len(self._b_label))
        self._n_boxes = len(self._b_label)
        self._b_half = np.concatenate([self._b_half, np.full((pad, 3), 0.01, np.float32)])
        self._b_inside = np.concatenate([self._b_inside, np.zeros(pad, bool)])
        self._b_tex = np.concatenate([self._b_tex, np.zeros(pad, np.int32)])
        self._b_dens = np.concatenate([self._b_dens, np.ones(pad, np.float32)])
        self._b_label = np.concatenate([self._b_label, np.zeros(pad, np.int32)])

    # ---- the sequence contract

    def __len__(self) -> int:
        return len(self.timestamps)

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]

    def __getitem__(self, index: int) -> Frame:
        return self.render(index)

    def __repr__(self) -> str:
        return (f"SyntheticSequence({self.name!r}, {len(self)} frames, {self.width}x"
                f"{self.height}, {len(self._objects)} moving objects)")

    # ---- rendering

    def _boxes(self, i: int, t: float, enabled: np.ndarray):
        import jax.numpy as jnp

        from jaxvo.synth.render import Boxes

        T_w_c = self._camera_pose(i, t)
        poses = [b[0] for b in self._static_boxes]
        poses += [self._object_pose(k, i, t) for k in range(len(self._objects))]
        far = np.eye(4)
        far[2, 3] = -1e3  # padding: far behind the camera, and disabled anyway
        poses += [far] * (len(self._b_label) - self._n_boxes)
        T_b_c = np.stack([np.linalg.inv(T) @ T_w_c for T in poses])
        boxes = Boxes(jnp.asarray(T_b_c.astype(np.float32)), jnp.asarray(self._b_half),
                      jnp.asarray(self._b_inside), jnp.asarray(enabled),
                      jnp.asarray(self._b_tex), jnp.asarray(self._b_dens),
                      jnp.asarray(self._b_label))
        return boxes, jnp.asarray(self._tile_overlap(T_b_c))

    def _tile_overlap(self, T_b_c: np.ndarray) -> np.ndarray:
        """(B, gy * gx) bool: the render tiles that each box's projection may touch.

        Conservative (a box can only show inside its tiles), so the tiling changes no
        pixel; it only saves the ray-box work. A box seen from inside (the room) and a box
        reaching behind the camera touch every tile; a box wholly beyond one side of the
        view frustum touches none.
        """
        K = self.intrinsics
        gy, gx = self._grid
        th, tw = self.height // gy, self.width // gx
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T  # (8, 3)
        T_c_b = np.linalg.inv(T_b_c)
        corners = np.einsum("bij,bkj->bki", T_c_b[:, :3, :3],
                            signs[None] * self._b_half[:, None, :]) + T_c_b[:, None, :3, 3]
        x, y, z = corners[..., 0], corners[..., 1], corners[..., 2]
        m = 2.0  # pixels of slack
        left, right = (K.cx + m) / K.fx, (self.width - K.cx + m) / K.fx
        top, bottom = (K.cy + m) / K.fy, (self.height - K.cy + m) / K.fy
        out = np.zeros(len(T_b_c), bool)
        for beyond in (z < 1e-3, x > right * z, -x > left * z, y > bottom * z, -y > top * z):
            out |= np.all(beyond, axis=1)
        out &= ~self._b_inside
        everywhere = self._b_inside | np.any(z < 1e-3, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = K.fx * x / z + K.cx
            v = K.fy * y / z + K.cy
        overlap = np.ones((len(T_b_c), gy, gx), bool)
        ty = np.arange(gy) * th
        tx = np.arange(gx) * tw
        for b in np.flatnonzero(~everywhere):
            u0, u1 = u[b].min() - m, u[b].max() + m
            v0, v1 = v[b].min() - m, v[b].max() + m
            rows = (ty + th > v0) & (ty < v1)
            cols = (tx + tw > u0) & (tx < u1)
            overlap[b] = rows[:, None] & cols[None, :]
        overlap[out] = False
        return overlap.reshape(len(T_b_c), -1)

    def _cast(self, i: int, t: float, enabled: np.ndarray):
        from jaxvo.synth.render import cast

        K = self.intrinsics
        boxes, overlap = self._boxes(i, t, enabled)
        map_x, map_y, shade, depth, label = cast(
            boxes, overlap, height=self.height, width=self.width,
            intr=(float(K.fx), float(K.fy), float(K.cx), float(K.cy)),
            n_tex=_N_TEX, tile=_TILE, cols=_COLS, grid=self._grid)
        texels = cv2.remap(self._atlas, np.asarray(map_x), np.asarray(map_y), cv2.INTER_LINEAR)
        if self._lens is not None:
            return _through_lens(self._lens, texels, shade, depth, label)
        return texels, shade, depth, label

    def render(self, index: int, *, objects: bool = True) -> Frame:
        """Render frame ``index``; ``objects=False`` renders the static scene alone.

        Args:
          index: frame number (negative counts from the end).
          objects: draw the moving objects.

        Returns:
          ``io.Frame`` with bgr (H, W, 3) uint8, depth (H, W) float32 metres (0 = no
          reading) and mask (H, W) uint8 object id (0 = static).
        """
        import jax
        import jax.numpy as jnp

        from jaxvo.synth.render import composite_frame, finish_frame

        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"frame {index} out of range for {n} frames")
        i = int(index) % n
        t = float(self.timestamps[i])
        opts = self.options
        enabled = np.arange(len(self._b_label)) < self._n_boxes
        if not objects:
            enabled[self._b_label > 0] = False
        key = jax.random.fold_in(jax.random.key(self.seed), i)
        gain = 1.0
        if opts.exposure_change:
            gain = 1.0 + opts.exposure_amplitude * np.sin(
                2 * np.pi * (t - self.timestamps[0]) / opts.exposure_period + self.seed)
        texels, shade, depth, label = self._cast(i, t, enabled)
        if opts.motion_blur and opts.blur_samples > 1 and self._background is None:
            offsets = np.linspace(-0.5, 0.5, opts.blur_samples) * opts.exposure / self.fps
            acc = np.zeros(texels.shape, np.float32)
            sh = np.zeros(texels.shape[:2], np.float32)
            for dt in offsets:
                tx, s, _, _ = self._cast(i, t + dt, enabled)
                s = np.asarray(s)
                acc += tx.astype(np.float32) * s[..., None]
                sh += s
            # Average of shaded colours, expressed as texels over the mean shade.
            shade = sh / len(offsets)
            texels = acc / np.maximum(sh, 1e-6)[..., None]
        model = opts._model()
        if self._background is None:
            bgr, z = finish_frame(key, texels, shade, depth, jnp.float32(gain), model=model)
            mask = label
        else:
            real = self._background.seq[int(self._background.index[i])]
            bgr, z, mask = composite_frame(key, texels, shade, depth, label,
                                           jnp.float32(gain), real.bgr, real.depth,
                                           model=model)
        return Frame(i, t, np.asarray(bgr), np.asarray(z, np.float32),
                     np.asarray(mask).astype(np.uint8))
