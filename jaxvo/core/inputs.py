"""What the host hands the per-frame step: the types of the host/device boundary.

The host computes them with numpy and OpenCV (:mod:`jaxvo.host.frontend.flow`,
:mod:`jaxvo.host.frontend.keyframes`); the step (:func:`jaxvo.core.pipeline.step`) reads them as
device arrays. Defined here, on the device side, so that the step's arguments carry their
type and neither the core nor a study imports OpenCV to name them. Numpy only: no JAX, no
OpenCV. Shapes are fixed (``n = rows * cols`` grid points), invalid entries zeroed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxvo.status import Status


class GridFlow(NamedTuple):
    """Grid flow of one image pair (host -> device): numpy arrays from
    :class:`jaxvo.host.frontend.flow.GridFlowTracker`, the same fields as JAX arrays inside the step;
    see docs/architecture.md."""

    pts_prev: np.ndarray  # (n, 3) float32 metres, previous camera frame (0 where invalid)
    pts_cur: np.ndarray  # (n, 3) float32 metres, current camera frame (0 where invalid)
    uv_prev: np.ndarray  # (n, 2) float32 pixels, grid cell centres in the previous image
    uv_cur: np.ndarray  # (n, 2) float32 pixels, tracked positions (= uv_prev where invalid)
    valid: np.ndarray  # (n,) bool, passed LK, forward-backward, similarity and depth checks
    status: np.ndarray  # () int32 Status code: OK, or BAD_INPUT
    focal: np.ndarray  # () float32 pixels, the camera's mean focal length (jaxvo.core.noise)
    # (n,) float32 metres, the previous image's refined depth at each grid point (0: no
    # reading, the cell is hidden from the sensor: nearer or farther than its range, or a
    # hole), tracked or not: what the occlusion memory compares (jaxvo.core.occlusion)
    depth_prev: np.ndarray
    camera: np.ndarray  # (4,) float32 pixels, fx, fy, cx, cy of the (depth-registered) camera
    # The tracker's own quality of each valid point (0 where invalid), which the noise
    # model adds to its sequence-wide scales (jaxvo.core.noise.point_noise):
    fb_error: np.ndarray  # (n,) float32 pixels, forward-backward error of the track
    # (n,) float32 metres per pixel, the slope of the depth surface at the tracked point in
    # the current image (gradient of the bilinear lookup): a pixel of tracking error moves
    # the depth reading by this much along the ray
    depth_slope: np.ndarray


class KeyframeFlow(NamedTuple):
    """The keyframes' grid points tracked into the current image (host -> device), from
    :class:`jaxvo.host.frontend.keyframes.KeyframeTracker` (``Config.keyframes``)."""

    pts_kf: np.ndarray  # (n, 3) float32 metres, the latest keyframe's points (0 where invalid)
    pts_cur: np.ndarray  # (n, 3) float32 metres, the same in the current camera frame
    valid: np.ndarray  # (n,) bool, passed LK, similarity and depth checks
    renew: np.ndarray  # () bool, the current frame becomes the keyframe after this pair
    # where renew (with cfg.keyframe_track_window, every pair): each window keyframe's
    # points (slot 0 the oldest, W - 1 the latest) in the current camera (the device holds
    # them in their own), and which passed the checks; W is cfg.keyframe_window - 1; all
    # False where the keyframe is kept
    win_cur: np.ndarray  # (W, n, 3) float32 metres
    win_valid: np.ndarray  # (W, n) bool
    new_kf: np.ndarray  # (n, 3) float32 metres, where renew: the new keyframe's points
    # (n,) int32 the grid cell of the pair's previous image each latest keyframe point lay
    # in (its segment and evidence are that cell's), -1 where unknown
    cell_prev: np.ndarray
    # (W, n) int32 the same for each window keyframe's points (with
    # cfg.keyframe_track_window; -1 elsewhere)
    win_cell_prev: np.ndarray


def invalid_flow(uv_grid: np.ndarray, status: int = Status.BAD_INPUT, *,
                 focal: float = 1.0, camera: np.ndarray | None = None) -> GridFlow:
    """An all-invalid :class:`GridFlow` on the grid ``uv_grid`` (n, 2) with ``status``
    (``camera`` (4,), default a camera of focal length ``focal`` centred on the grid)."""
    n = uv_grid.shape[0]
    uv = np.asarray(uv_grid, np.float32)
    return GridFlow(
        pts_prev=np.zeros((n, 3), np.float32),
        pts_cur=np.zeros((n, 3), np.float32),
        uv_prev=uv.copy(),
        uv_cur=uv.copy(),
        valid=np.zeros(n, bool),
        status=np.int32(status),
        focal=np.float32(focal),
        depth_prev=np.zeros(n, np.float32),
        camera=(np.asarray(camera, np.float32) if camera is not None else np.array(
            [focal, focal, *(uv.max(axis=0) + uv.min(axis=0)) / 2], np.float32)),
        fb_error=np.zeros(n, np.float32),
        depth_slope=np.zeros(n, np.float32),
    )


def stack_flows(flows: list, empty=None):
    """Stack per-pair flows (a :class:`GridFlow` or :class:`KeyframeFlow` each) along a new
    leading frame axis; with none, ``empty`` (one pair's flow) gives the fields' shapes and
    types for a stack of length 0."""
    if not flows:
        return type(empty)(*(np.zeros((0, *np.shape(f)), np.asarray(f).dtype) for f in empty))
    return type(flows[0])(*(np.stack(field) for field in zip(*flows)))


def invalid_keyframe_flow(n: int, window: int) -> KeyframeFlow:
    """An all-invalid :class:`KeyframeFlow` of ``n`` points that renews the keyframe (the
    shapes of an empty stack, :func:`stack_flows`), for a window of
    ``window`` keyframes."""
    W = max(int(window) - 1, 0)
    z = np.zeros((n, 3), np.float32)
    return KeyframeFlow(z, z.copy(), np.zeros(n, bool), np.bool_(True),
                        np.zeros((W, n, 3), np.float32), np.zeros((W, n), bool), z.copy(),
                        np.full(n, -1, np.int32), np.full((W, n), -1, np.int32))


def keyframe_grid(grid: tuple[int, int], stride: int) -> tuple[int, int]:
    """``(rows, cols)`` of the keyframe's points (:func:`keyframe_index`) as a grid of
    their own: every ``stride``-th row and column of ``grid``."""
    return len(range(0, grid[0], stride)), len(range(0, grid[1], stride))


def keyframe_index(grid: tuple[int, int], stride: int) -> np.ndarray:
    """The grid points (row-major indices) a keyframe offers: every ``stride``-th row and
    column of the ``(rows, cols)`` grid. The one rule of both sides: the host's
    :class:`jaxvo.host.frontend.keyframes.KeyframeTracker` tracks these points, the step reads them
    (:mod:`jaxvo.core.keyframe`)."""
    rows, cols = grid
    r, c = np.meshgrid(np.arange(0, rows, stride), np.arange(0, cols, stride), indexing="ij")
    return (r * cols + c).ravel().astype(np.int32)
