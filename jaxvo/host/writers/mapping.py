"""The static map: every frame's depth fused into one voxel-filtered point cloud, with the
dynamic pixels left out (host side, numpy).

Each kept frame's depth is back-projected (every ``stride``-th pixel, up to ``max_depth``),
moved into the world by the frame's pose, and the points of all frames are averaged per
voxel (position and colour). The pixels a dynamic mask marks are left out of the static
map, with the pixels within ``grow`` pixels of them, and so are the cubes (``vote_voxel``)
where more than ``vote_share`` of the readings were so marked: jaxvo's masks are cell-sized
and catch part of a person in each frame, so a place a person passed through is left out
whole. ``edge`` leaves out the pixels at a depth discontinuity (a neighbour nearer or
farther by that fraction of the depth; off by default: it did not pay on the TUM clip,
``bench/bench_map.py``). The same frames fused with nothing left out give the map beside
it, where the movers leave smeared ghosts.

Why voxel averaging, not a TSDF: the map only has to show (and count) what is static, and
a voxel average of back-projected points keeps every surface seen, thin ones included, with
no volume to size beforehand and no dependency; a TSDF (Open3D's) smooths surfaces better
but needs a bounded volume and a truncation distance per scene, and Open3D is a large
optional install.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.errors import warn as warn_user
from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.host.writers.outputs import OutputFile
from jaxvo.trajectory import Trajectory

# OpenCV is imported in the functions that use it: `jaxvo --help` reads the defaults below
# (jaxvo map's options) and must not wait for it

# the picture's colour of the background where no map point falls (BGR)
_BACKGROUND = (40, 40, 40)
# the static map's defaults (chosen on the TUM walking clip, bench/bench_map.py): a
# dynamic mask grown by GROW pixels, and cubes of VOTE_VOXEL metres left out where more
# than VOTE_SHARE of their readings fell in the grown masks
GROW = 8
VOTE_VOXEL = 0.05
VOTE_SHARE = 0.1
# the smallest voxel, metres: a tenth of a millimetre, far below what any RGB-D sensor
# resolves; below it the voxels' keys overflow for a room-sized map
MIN_VOXEL = 1e-4


class PointMap(NamedTuple):
    """A fused point cloud in the world frame."""

    points: np.ndarray  # (m, 3) float32 metres, world frame (the trajectory's)
    colours: np.ndarray  # (m, 3) uint8 RGB
    counts: np.ndarray  # (m,) int32 readings averaged into each point


class FusedMaps(NamedTuple):
    """The static map and the map with nothing left out, from the same frames."""

    static: PointMap  # dynamic pixels left out
    full: PointMap  # nothing left out
    frames: int  # frames fused (a pose and, for the static map, a mask)
    no_mask: int  # frames with a pose but no dynamic mask: left out of the static map


@dataclasses.dataclass(frozen=True)
class MapOptions:
    """A static map's settings: ``jaxvo map``'s options, which ``jaxvo run --map`` takes at
    these defaults (the one place they are written)."""

    voxel: float = 0.02  # the map's voxel side, metres
    max_depth: float = 4.0  # depth readings farther than this are left out, metres
    grow: int = GROW  # pixels around a dynamic pixel also left out
    vote_voxel: float = VOTE_VOXEL  # side of the cubes voted on, metres
    vote_share: float = VOTE_SHARE  # a cube with more of its readings dynamic: left out
    max_diff: float = 0.02  # largest time difference between a pose and its frame, seconds

    def check(self, *, height: int | None = None, width: int | None = None,
              names: dict[str, str] | None = None) -> None:
        """:func:`check_map_settings` of these settings."""
        check_map_settings(voxel=self.voxel, max_depth=self.max_depth, grow=self.grow,
                           vote_voxel=self.vote_voxel, vote_share=self.vote_share,
                           height=height, width=width, names=names)


def check_map_settings(*, voxel: float, max_depth: float, grow: int, vote_voxel: float,
                       vote_share: float, stride: int = 2, edge: float = 0.0,
                       height: int | None = None, width: int | None = None,
                       names: dict[str, str] | None = None) -> None:
    """Refuse fusion settings no map can use (:func:`fuse_maps`'s arguments; ``jaxvo map``'s
    options, named as ``names`` says): sizes that are not positive finite metres (``voxel``
    0 made a map of one point after NumPy's warnings), a share outside 0..1, and a ``grow``
    wider than the frames (``--grow 100000`` asked for a kernel larger than any machine's
    memory; any grow as wide as the frame already leaves a whole frame out).

    Raises:
      InputError: one line naming the setting and its range.
    """
    import math
    import operator

    def name(field: str) -> str:
        return (names or {}).get(field, field)

    for field, value, least in (("voxel", voxel, MIN_VOXEL), ("max_depth", max_depth, 0.0),
                                ("vote_voxel", vote_voxel, MIN_VOXEL)):
        if not (isinstance(value, int | float | np.integer | np.floating)
                and math.isfinite(value) and value > least):
            raise InputError(f"{name(field)} must be a number of metres above {least:g}, got "
                             f"{value!r}")
    for field, value, least in (("grow", grow, 0), ("stride", stride, 1)):
        try:
            whole = operator.index(value)
        except TypeError:
            raise InputError(f"{name(field)} must be a whole number of pixels, got "
                             f"{value!r}") from None
        if whole < least:
            raise InputError(f"{name(field)} must be {least} or more pixels, got {value}")
    if height is not None and width is not None and grow > max(height, width):
        raise InputError(f"{name('grow')} {grow} is wider than the {width}x{height} frames (at "
                         f"most {max(height, width)} pixels: that already leaves out every "
                         "frame with a dynamic pixel)")
    for field, value in (("vote_share", vote_share), ("edge", edge)):
        if not (isinstance(value, int | float | np.integer | np.floating)
                and math.isfinite(value) and 0 <= value <= 1):
            raise InputError(f"{name(field)} must be from 0 to 1, got {value!r}")


def frame_points(bgr: np.ndarray, depth: np.ndarray, K: Intrinsics, T_w_c: np.ndarray, *,
                 stride: int = 2, max_depth: float = 4.0, edge: float = 0.0):
    """A frame's depth as world points with their colours.

    Args:
      bgr: (H, W, 3) uint8 colour image (BGR).
      depth: (H, W) float32 metres, 0 = no reading.
      K: the camera.
      T_w_c: (4, 4) camera-to-world pose.
      stride: every ``stride``-th pixel in x and y.
      max_depth: readings farther than this (metres) are left out.
      edge: > 0: leave out pixels with a 3x3 neighbour whose depth differs by more than
        ``edge`` times their own (or that has no reading).
    Returns:
      ``(points (m, 3) float32 world, colours (m, 3) uint8 RGB, pixels (m, 2) int (x, y))``.
    """
    import cv2

    z = depth[::stride, ::stride]
    ok = (z > 0) & (z <= max_depth) & np.isfinite(z)
    if edge > 0:
        zf = np.where(np.isfinite(depth), depth, 0).astype(np.float32)
        near = cv2.erode(zf, np.ones((3, 3), np.uint8))[::stride, ::stride]
        far = cv2.dilate(zf, np.ones((3, 3), np.uint8))[::stride, ::stride]
        ok &= (near >= z * (1 - edge)) & (far <= z * (1 + edge))
    ys, xs = np.nonzero(ok)
    ys, xs, zz = ys * stride, xs * stride, z[ok]
    cam = np.stack([(xs - K.cx) / K.fx * zz, (ys - K.cy) / K.fy * zz, zz], axis=-1)
    T = np.asarray(T_w_c, np.float64)
    world = (cam @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    rgb = bgr[ys, xs][:, ::-1] if bgr.ndim == 3 else np.repeat(bgr[ys, xs][:, None], 3, 1)
    return world, np.ascontiguousarray(rgb, np.uint8), np.stack([xs, ys], axis=-1)


def voxel_filter(points: np.ndarray, colours: np.ndarray, voxel: float) -> PointMap:
    """Points averaged per cube of side ``voxel`` metres (position and colour).

    Args:
      points: (m, 3) float metres.
      colours: (m, 3) uint8.
      voxel: the cube's side, metres (> 0).
    Returns:
      :class:`PointMap`, one point per occupied voxel.
    """
    if len(points) == 0:
        return PointMap(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8),
                        np.zeros(0, np.int32))
    inverse, counts = _voxel_index(points, voxel)
    mean = np.stack([np.bincount(inverse, points[:, i], len(counts)) for i in range(3)], -1)
    col = np.stack([np.bincount(inverse, colours[:, i], len(counts)) for i in range(3)], -1)
    return PointMap((mean / counts[:, None]).astype(np.float32),
                    np.clip(np.rint(col / counts[:, None]), 0, 255).astype(np.uint8),
                    counts.astype(np.int32))


def _voxel_index(points: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Each point's voxel (an index into the occupied voxels) and each voxel's count."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    if float(np.prod((hi - lo) / voxel + 1)) >= 2.0**62:  # the key below would overflow
        raise InputError(f"voxel {voxel:g} m is too small for a map {np.ptp(points, 0).max():.3g} "
                         "m across")
    cells = np.floor(points / voxel).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    return inverse.ravel(), counts


def matched_poses(seq, traj: Trajectory, *, where: str, max_diff: float = 0.02,
                  frames: int | None = None) -> list[tuple[int, np.ndarray]]:
    """``(frame index, T_w_c)`` for every pose of ``traj``, each matched to the frame of
    ``seq`` nearest in time.

    Raises:
      InputError: a pose with no frame within ``max_diff`` (a trajectory of another
        sequence, or of another clock), or an empty trajectory.
    """
    stamps = np.asarray(seq.timestamps, np.float64)[:frames]
    if len(traj) == 0:
        raise InputError(f"{where}: no pose")
    if len(stamps) == 0:
        raise InputError(f"{seq.name}: no frame")
    j = np.clip(np.searchsorted(stamps, traj.timestamps), 1, len(stamps) - 1)
    j = np.where(np.abs(stamps[j - 1] - traj.timestamps) <= np.abs(stamps[j] - traj.timestamps),
                 j - 1, j) if len(stamps) > 1 else np.zeros(len(traj), int)
    off = np.abs(stamps[j] - traj.timestamps) > max_diff
    if off.any():
        k = int(np.argmax(off))
        raise InputError(
            f"{where}: {int(off.sum())} of {len(traj)} poses have no frame of {seq.name} within "
            f"{max_diff:g} s (the first at {traj.timestamps[k]:.6f} s; frames "
            f"{stamps[0]:.6f} .. {stamps[-1]:.6f} s): a trajectory of another sequence?")
    if len(np.unique(j)) < len(j):
        raise InputError(
            f"{where}: {len(j) - len(np.unique(j))} of its {len(traj)} poses fall on a frame "
            f"another pose already has (within {max_diff:g} s): a trajectory at another rate "
            f"than the frames of {seq.name} (a ground truth at 100 Hz?)")
    return [(int(i), T) for i, T in zip(j, traj.poses)]


# Where a trajectory claims the camera moved (its motion moves at least MOVED_SHARE of a
# frame's points beyond the depth test), that motion must explain the later frame's depth
# better than standing still does; a trajectory of another sequence explained it worse
# (docs/report/host_decisions.md has the shares measured).
MOVED_SHARE = 0.5
# a reading agrees with another frame's when their depths differ by less than this share of
# the depth plus DEPTH_TOL_M (the sensors' noise at 4 m, with the tracker's pixel)
DEPTH_SHARE = 0.03
DEPTH_TOL_M = 0.01


def trajectory_fit(seq, poses: list[tuple[int, np.ndarray]], *, stride: int = 8,
                   pairs: int = 4) -> str | None:
    """Whether the trajectory's motion fits the depth it is to fuse: a warning, or None.

    For the frame pairs first-last and ``pairs`` consecutive stretches of the trajectory,
    each pair's first frame's readings (every ``stride``-th pixel) are moved into the second
    frame by the trajectory's motion and by none, and counted where they land on a reading
    of the same depth (:data:`DEPTH_SHARE`, :data:`DEPTH_TOL_M`). Where the trajectory
    claims the camera moved (it moves :data:`MOVED_SHARE` of the readings beyond that
    test) but explains fewer readings than standing still, it is likely of another sequence
    or another clock, or the depth is read at another scale than the run read it.
    A fixed camera, or motion too small to tell, passes.

    Args:
      seq: the sequence; poses: ``(frame index, T_w_c)`` (:func:`matched_poses`).
    Returns:
      a one-line warning naming the frames, or None.
    """
    if len(poses) < 2:
        return None
    ends = np.unique(np.linspace(0, len(poses) - 1, pairs + 1).round().astype(int))
    checked = [(0, len(poses) - 1)] + list(itertools.pairwise(ends))
    K = seq.intrinsics
    for a, b in dict.fromkeys(checked):
        (ia, Ta), (ib, Tb) = poses[a], poses[b]
        za, zb = seq[ia].depth, seq[ib].depth
        ys, xs = np.nonzero(np.isfinite(za[::stride, ::stride]) & (za[::stride, ::stride] > 0))
        z = za[ys * stride, xs * stride].astype(np.float64)
        pa = np.stack([(xs * stride - K.cx) / K.fx * z, (ys * stride - K.cy) / K.fy * z, z], -1)
        T = np.linalg.inv(np.asarray(Tb, np.float64)) @ np.asarray(Ta, np.float64)
        moved_pts = pa @ T[:3, :3].T + T[:3, 3]
        tol = DEPTH_SHARE * z + DEPTH_TOL_M
        if np.mean(np.linalg.norm(moved_pts - pa, axis=1) > tol) < MOVED_SHARE:
            continue  # no motion claimed that the depth could tell
        agree = [_agreeing(q, zb, K, tol) for q in (moved_pts, pa)]
        if min(n for _, n in agree) >= 100 and agree[0][0] < agree[1][0]:
            (got, _), (still, _) = agree
            return (f"the trajectory's motion from the frame at {seq.timestamps[ia]:.6f} s to "
                    f"the one at {seq.timestamps[ib]:.6f} s fits the depth worse than no "
                    f"motion ({100 * got:.0f} % of the readings agree, against "
                    f"{100 * still:.0f} %): a trajectory of another sequence, or depth read "
                    "at another scale than the run read it? The map may be smeared")
    return None


def _agreeing(points: np.ndarray, depth: np.ndarray, K: Intrinsics,
              tol: np.ndarray) -> tuple[float, int]:
    """The share of ``points`` (camera frame, metres) that land on a reading of ``depth``
    within ``tol`` of their own depth, and how many land on a reading."""
    h, w = depth.shape
    z = points[:, 2]
    front = z > 1e-3
    safe = np.where(front, z, 1.0)
    u = np.rint(K.fx * points[:, 0] / safe + K.cx)
    v = np.rint(K.fy * points[:, 1] / safe + K.cy)
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    seen = np.zeros(len(points))
    seen[inside] = depth[v[inside].astype(int), u[inside].astype(int)]
    inside &= np.isfinite(seen) & (seen > 0)
    n = int(inside.sum())
    return (float(np.mean(np.abs(seen[inside] - z[inside]) < tol[inside])) if n else 0.0), n


def fuse_maps(seq, poses: list[tuple[int, np.ndarray]],
              dynamic: Callable[[int, float], np.ndarray | None] | None, *,
              voxel: float = 0.02, stride: int = 2, max_depth: float = 4.0,
              grow: int = GROW, vote_voxel: float = VOTE_VOXEL, vote_share: float = VOTE_SHARE,
              edge: float = 0.0) -> FusedMaps:
    """The static map and the map with nothing left out, over the frames of ``poses``.

    A reading the dynamic mask marks (grown by ``grow`` pixels) is left out of the static
    map, and so is every reading in a cube of side ``vote_voxel`` where more than
    ``vote_share`` of the readings were marked: a mover's mask covers only part of it in
    each frame, so the place a mover passed through is left out whole, not only where the
    mask caught it.

    Args:
      seq: a sequence (docs/architecture.md): frames read by index.
      poses: ``(frame index, (4, 4) T_w_c)`` pairs (:func:`matched_poses`).
      dynamic: ``dynamic(index, timestamp)`` -> the frame's (H, W) bool dynamic mask (the
        frame's size), or None where it has none (that frame is left out of the static map); None: no masks
        (the static map is the full map).
      voxel: the map's voxel side, metres.
      stride, max_depth, edge: see :func:`frame_points` (``edge`` applies to both maps).
      grow: pixels around a dynamic pixel also left out.
      vote_voxel, vote_share: the cubes (metres) and the share of marked readings above
        which a cube is left out (``vote_share`` >= 1: no vote).
    Returns:
      :class:`FusedMaps`.
    Raises:
      InputError: settings no map can use (:func:`check_map_settings`), or a mask of
        another size than its frame.
    """
    import cv2

    check_map_settings(voxel=voxel, max_depth=max_depth, grow=grow, vote_voxel=vote_voxel,
                       vote_share=vote_share, stride=stride, edge=edge, height=seq.height,
                       width=seq.width)
    pts, col, marked = [], [], []
    no_mask = 0
    for index, T in poses:
        frame = seq[index]
        p, c, px = frame_points(frame.bgr, frame.depth, seq.intrinsics, T, stride=stride,
                                max_depth=max_depth, edge=edge)
        mask = dynamic(index, frame.timestamp) if dynamic is not None else None
        if dynamic is not None and mask is None:
            no_mask += 1
            dyn = np.ones(len(p), bool)  # unknown: not in the static map, no vote
        elif mask is None:
            dyn = np.zeros(len(p), bool)
        else:
            mask = np.asarray(mask)
            if mask.shape != frame.depth.shape:
                raise InputError(
                    f"the dynamic mask of the frame at {frame.timestamp:.6f} s is "
                    f"{mask.shape[-1] if mask.ndim else 0}x{mask.shape[0] if mask.ndim else 0}"
                    f", the frames {frame.depth.shape[1]}x{frame.depth.shape[0]}: masks of "
                    "another sequence, or resized?")
            if grow > 0 and mask.any():
                mask = cv2.dilate(mask.astype(np.uint8),
                                  np.ones((2 * grow + 1, 2 * grow + 1), np.uint8)).astype(bool)
            dyn = mask[px[:, 1], px[:, 0]]
        pts.append(p)
        col.append(c)
        marked.append(dyn)
    pts, col, marked = np.concatenate(pts), np.concatenate(col), np.concatenate(marked)
    full = voxel_filter(pts, col, voxel)
    if dynamic is None:
        return FusedMaps(full, full, len(poses), 0)
    keep = ~marked
    if vote_share < 1 and len(pts):
        inverse, counts = _voxel_index(pts, vote_voxel)
        share = np.bincount(inverse, marked, len(counts)) / counts
        keep &= share[inverse] <= vote_share
    return FusedMaps(voxel_filter(pts[keep], col[keep], voxel), full, len(poses), no_mask)


def mask_reader(folder: str | Path, *, shape: tuple[int, int] | None = None
                ) -> Callable[[int, float], np.ndarray | None]:
    """``dynamic(index, timestamp)`` reading ``folder/<timestamp>.png`` (as ``jaxvo run
    --dynamic-masks`` names them; nonzero = dynamic), None where there is no such file; a
    mask of another size than ``shape`` (H, W) is refused naming the file."""
    import cv2

    folder = Path(folder)

    def dynamic(index: int, timestamp: float) -> np.ndarray | None:
        path = folder / f"{timestamp:.6f}.png"
        if not path.is_file():
            return None
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{path}: not a readable PNG mask")
        if shape is not None and img.shape != tuple(shape):
            raise InputError(f"{path}: the mask is {img.shape[1]}x{img.shape[0]}, the frames "
                             f"{shape[1]}x{shape[0]}: masks of another sequence, or resized?")
        return img > 0

    return dynamic


def write_ply(path: str | Path, pmap: PointMap) -> None:
    """The map as a binary little-endian PLY (x y z float, red green blue uchar), the
    layout Open3D, MeshLab and CloudCompare read."""
    rows = np.empty(len(pmap.points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                              ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, axis in enumerate("xyz"):
        rows[axis] = pmap.points[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        rows[c] = pmap.colours[:, i]
    header = ("ply\nformat binary_little_endian 1.0\ncomment jaxvo map\n"
              f"element vertex {len(rows)}\nproperty float x\nproperty float y\n"
              "property float z\nproperty uchar red\nproperty uchar green\n"
              "property uchar blue\nend_header\n")
    with OutputFile(path) as fh:  # whole or not at all, errors name the file
        fh.write(header.encode("ascii"))
        fh.write(rows.tobytes())


def _splat(shape, u, v, order, colours, radius: int) -> np.ndarray:
    """Points drawn as squares of side ``2 * radius + 1`` in ``order`` (the last on top)."""
    img = np.empty((*shape, 3), np.uint8)
    img[:] = _BACKGROUND
    u, v, c = u[order], v[order], colours[order][:, ::-1]  # RGB -> BGR
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            x, y = u + dx, v + dy
            ok = (x >= 0) & (x < shape[1]) & (y >= 0) & (y < shape[0])
            img[y[ok], x[ok]] = c[ok]
    return img


def view_from_above(pmap: PointMap, T_w_c0: np.ndarray, *, size: int = 400) -> np.ndarray:
    """The map seen from above, orthographic: "up" is the first camera's up (-y), the first
    camera looks to the top of the picture. (size, size, 3) uint8 BGR."""
    R = np.asarray(T_w_c0, np.float64)[:3, :3]
    p = pmap.points.astype(np.float64) - T_w_c0[:3, 3]
    right, up, ahead = p @ R[:, 0], -(p @ R[:, 1]), p @ R[:, 2]
    if len(p) == 0:
        return _splat((size, size), np.zeros(0, int), np.zeros(0, int), np.zeros(0, int),
                      pmap.colours, 0)
    lo = np.percentile(np.stack([right, ahead], -1), 1, axis=0)
    hi = np.percentile(np.stack([right, ahead], -1), 99, axis=0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-3) * 1.05
    scale = (size / 2) / half
    u = np.rint((right - centre[0]) * scale + size / 2).astype(int)
    v = np.rint(size / 2 - (ahead - centre[1]) * scale).astype(int)
    return _splat((size, size), u, v, np.argsort(up), pmap.colours, 1)


def view_from_camera(pmap: PointMap, K: Intrinsics, T_w_c: np.ndarray, height: int, width: int,
                     *, scale: float = 0.5) -> np.ndarray:
    """The map seen by the camera at ``T_w_c`` (perspective, nearest point on top), at
    ``scale`` times the image size. (H * scale, W * scale, 3) uint8 BGR."""
    T = np.linalg.inv(np.asarray(T_w_c, np.float64))
    cam = pmap.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    front = cam[:, 2] > 0.05
    cam, colours = cam[front], pmap.colours[front]
    u = np.rint((K.fx * cam[:, 0] / cam[:, 2] + K.cx) * scale).astype(int)
    v = np.rint((K.fy * cam[:, 1] / cam[:, 2] + K.cy) * scale).astype(int)
    shape = (round(height * scale), round(width * scale))
    return _splat(shape, u, v, np.argsort(-cam[:, 2]), colours, 1)


def _titled(img: np.ndarray, title: str) -> np.ndarray:
    """``img`` under a strip with ``title`` written in it."""
    import cv2

    strip = np.full((26, img.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([strip, img])


def map_picture(maps: FusedMaps, K: Intrinsics, T_w_c0: np.ndarray, height: int,
                width: int) -> np.ndarray:
    """The two maps side by side (static left, nothing left out right), each from above and
    from the first camera. uint8 BGR."""

    cols = []
    for name, pmap in (("dynamic pixels left out", maps.static),
                       ("nothing left out", maps.full)):
        cam = view_from_camera(pmap, K, T_w_c0, height, width)
        top = view_from_above(pmap, T_w_c0, size=cam.shape[1])
        cols.append(np.vstack([_titled(cam, f"{name}: first camera"),
                               _titled(top, f"{name}: from above")]))
    gap = np.full((cols[0].shape[0], 6, 3), 255, np.uint8)
    return np.hstack([cols[0], gap, cols[1]])


def map_outputs(path: str | Path) -> dict[str, Path]:
    """The files a map writes: ``{option: path}`` for the static map (``path``), the map
    with nothing left out (``<stem>_all.ply``) and the picture (``<stem>.png``)."""
    p = Path(path)
    return {"map": p, "map (nothing left out)": p.with_name(p.stem + "_all.ply"),
            "map picture": p.with_suffix(".png")}


def make_maps(seq, traj: Trajectory, dynamic, options: MapOptions, outputs: dict[str, Path],
              *, where: str, frames: int | None = None, logger=None, on_static=None,
              warn: Callable[[str], None] = warn_user) -> dict:
    """Fuse, write the maps and their picture (and into ``logger``, and the static map to
    ``on_static``: ``jaxvo run --out-bag``); the summary's part. Each file is written whole
    or not at all; a failure leaves the earlier maps as they were, all three.

    Args:
      seq: the sequence; traj: its trajectory; dynamic: ``(index, timestamp) -> (H, W)``
        bool dynamic pixels or None (:func:`mask_reader`), or None for no static map.
      options: the fusion's settings.
      outputs: :func:`map_outputs` (without the map with nothing left out: no masks).
      where: the trajectory, for messages; frames: the first frames only (a run's).
      warn: what is done with a warning line (default: printed to standard error).
    """
    from jaxvo.host.writers.outputs import write_image

    poses = matched_poses(seq, traj, where=where, max_diff=options.max_diff, frames=frames)
    fit = trajectory_fit(seq, poses)
    if fit is not None:
        warn(f"{where}: {fit}")
    maps = fuse_maps(seq, poses, dynamic, voxel=options.voxel, max_depth=options.max_depth,
                     grow=options.grow, vote_voxel=options.vote_voxel,
                     vote_share=options.vote_share)
    if not len(maps.full.points):  # an empty map is no map: the earlier files stay
        raise InputError(f"none of the {len(poses)} frames with a pose has a depth reading "
                         f"within --max-depth {options.max_depth:g} m: no map written")
    if dynamic is not None and not len(maps.static.points):
        warn("the static map is empty: every reading lies in a dynamic mask (grown by --grow "
             f"{options.grow}) or a frame without one")
    picture = map_picture(maps, seq.intrinsics, poses[0][1], seq.height, seq.width)
    write_ply(outputs["map"], maps.static)
    summary = {"map": str(outputs["map"]), "map_points": len(maps.static.points),
               "masks": dynamic is not None, "frames_fused": maps.frames,
               "frames_in_sequence": len(seq), "frames_without_mask": maps.no_mask,
               "trajectory_fit": fit}
    if dynamic is not None:
        full = outputs["map (nothing left out)"]
        write_ply(full, maps.full)
        summary.update(map_all=str(full), map_all_points=len(maps.full.points))
    write_image(outputs["map picture"], picture)
    summary["map_picture"] = str(outputs["map picture"])
    if logger is not None:
        logger.log_map("static", maps.static)
        if dynamic is not None:
            logger.log_map("full", maps.full)
    if on_static is not None:
        on_static(maps.static)
    return summary
