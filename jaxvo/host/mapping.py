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

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.camera import Intrinsics
from jaxvo.host.io import Trajectory

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
    return [(int(i), T) for i, T in zip(j, traj.poses)]


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
      dynamic: ``dynamic(index, timestamp)`` -> the frame's (H, W) bool dynamic mask, or
        None where it has none (that frame is left out of the static map); None: no masks
        (the static map is the full map).
      voxel: the map's voxel side, metres.
      stride, max_depth, edge: see :func:`frame_points` (``edge`` applies to both maps).
      grow: pixels around a dynamic pixel also left out.
      vote_voxel, vote_share: the cubes (metres) and the share of marked readings above
        which a cube is left out (``vote_share`` >= 1: no vote).
    Returns:
      :class:`FusedMaps`.
    """
    import cv2

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


def mask_reader(folder: str | Path) -> Callable[[int, float], np.ndarray | None]:
    """``dynamic(index, timestamp)`` reading ``folder/<timestamp>.png`` (as ``jaxvo run
    --dynamic-masks`` names them; nonzero = dynamic), None where there is no such file."""
    import cv2

    folder = Path(folder)

    def dynamic(index: int, timestamp: float) -> np.ndarray | None:
        path = folder / f"{timestamp:.6f}.png"
        if not path.is_file():
            return None
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{path}: not a readable PNG mask")
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
    with open(path, "wb") as fh:
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
