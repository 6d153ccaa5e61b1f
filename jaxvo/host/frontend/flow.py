"""Grid-based 3D optical flow, the host front end (thesis section 2.2).

A fixed grid of points (the centres of ``cfg.cell``-pixel cells) is tracked from the previous
to the current image with pyramidal Lucas-Kanade. A track is kept only if

* LK converged both ways and the point stays inside the image,
* the forward-backward (bi-directional) error is at most ``cfg.fb_max`` pixels,
* the correlation coefficient of the ``cfg.patch``-pixel patches around the original and the
  tracked point is at least ``cfg.min_similarity``,
* both ends have a trustworthy depth after refinement (see :func:`refine_depth`).

Kept tracks are back-projected into previous and current 3D points (metres). Shapes are
fixed: ``n = rows * cols`` points whatever passes, invalid ones zeroed.

The pyramid follows the motion: when the last pair's median track is longer than
``cfg.lk_fast_px``, the next pair's LK uses one level more (``cfg.lk_levels + 1``), as the
thesis's LK did always; a third level on every pair cost the synthetic fixed-camera scene
some of its slow object (see ``Config.lk_fast_px``).

Speed (LK per point and direction is most of the time per pair):

* the checks run cheapest first, each on the points that passed the ones before: no depth
  at the grid point, then forward LK, then the image bounds and similarity, then depth at
  the tracked point together with backward LK, then the forward-backward error. LK tracks
  each point on its own, so the flow is the same as checking every point (tests compare bit
  for bit);
* depth is refined only at the pixels the bilinear lookups read (:func:`depth_at`), with
  the same values as refining the whole image (:func:`refine_depth`);
* each frame is converted to grey and its depth looked up at the grid once; the tracker
  keeps that for the next pair;
* depth runs beside LK: the new frame's grid depth (needed by the next pair only) while this
  pair's forward LK runs, and the tracked points' depth while backward LK runs, on one
  helper thread (numpy and OpenCV's LK both release the GIL). On 2 cores that takes time
  off every pair, with the same flow (docs/report/host_decisions.md). With
  ``cv2.setNumThreads(1)`` (or 0) the tracker stays on the calling thread.

OpenCV 5.0's Python binding still takes no pyramid from ``cv2.buildOpticalFlowPyramid``
in ``cv2.calcOpticalFlowPyrLK`` (images only: opencv/opencv#4777), so each LK call
rebuilds both pyramids; its LK runs on the calling thread whatever
``cv2.setNumThreads`` says.

Host only: numpy and OpenCV, never traced.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import NamedTuple

import cv2
import numpy as np

from jaxvo.config import Config, FlowOptions, Params, grid_shape
from jaxvo.core.inputs import (
    GridFlow,
    KeyframeFlow,
    invalid_flow,
    invalid_keyframe_flow,
    stack_flows,
)
from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics, backproject, grid_pixels
from jaxvo.host.frontend.depth import (  # noqa: F401  (bilinear_depth, refine_depth: the flow's API)
    _depth_at,
    _depth_slope_at,
    _lookup,
    bilinear_depth,
    bilinear_slope,
    depth_at,
    refine_depth,
    smooth_depth,
)
from jaxvo.host.frontend.keyframes import KeyframeTracker
from jaxvo.host.frontend.patches import lk_converged, similar
from jaxvo.host.frontend.prefetch import READ_AHEAD, read_ahead
from jaxvo.status import Status

DEFAULT_CONFIG = Config()

_helper: ThreadPoolExecutor | None = None


def _forget_helper() -> None:
    global _helper
    _helper = None  # a forked child has no helper thread: it starts its own


os.register_at_fork(after_in_child=_forget_helper)


def _beside(fn, *args) -> Future:
    """``fn(*args)`` on the helper thread, to run beside the caller's next steps; inline
    (already done) when OpenCV is told to use one thread. The caller takes ``.result()``."""
    global _helper
    if cv2.getNumThreads() <= 1:
        done: Future = Future()
        done.set_result(fn(*args))
        return done
    if _helper is None:
        _helper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxvo-flow")
    return _helper.submit(fn, *args)


def flow_options(cfg: Config | FlowOptions) -> FlowOptions:
    """The flow's options: ``cfg`` itself, or a :class:`~jaxvo.config.Config`'s ``flow``."""
    return cfg if isinstance(cfg, FlowOptions) else cfg.flow


def camera_row(K: Intrinsics) -> np.ndarray:
    """(4,) float32 ``fx, fy, cx, cy`` of ``K``, as :class:`GridFlow` carries them."""
    return np.array([K.fx, K.fy, K.cx, K.cy], np.float32)


# ----------------------------------------------------------------------------- front end


# A cell's point moves off its centre only to a pixel whose minimum eigenvalue reaches this
# fraction of the image's largest (the texture test of OpenCV's goodFeaturesToTrack, its
# qualityLevel, at the value the issue measured the cells with)
TEXTURE_FRACTION = 0.01


def textured_points(grey: np.ndarray, depth: np.ndarray, centres: np.ndarray,
                    grid: tuple[int, int], cell: int, depth_jump: float) -> np.ndarray:
    """(n, 2) float32 one point per grid cell: its most trackable pixel on a surface.

    The minimum eigenvalue of the gradient structure tensor (``cv2.cornerMinEigenVal``,
    3 x 3) on the half-size image (a quarter of the pixels; a cell of 16 pixels is 8 there)
    scores each pixel; pixels without depth, or on a depth edge (:func:`smooth_depth`: an
    object's outline is textured, but its depth belongs to neither surface), score nothing.
    A cell whose best score is under :data:`TEXTURE_FRACTION` of the image's best keeps its
    ``centres`` point.

    Args:
        grey: (H, W) uint8; depth: (H, W) float metres (0 = no reading).
        centres: (n, 2) the cells' centres (:func:`jaxvo.host.frontend.camera.grid_pixels`).
        grid: ``(rows, cols)``; cell: the cell's side, pixels (even).
        depth_jump: the largest depth change on one surface, a fraction of the depth
            (``Config.depth_jump``).
    """
    rows, cols = grid
    half = cell // 2
    small = cv2.pyrDown(grey)
    score = cv2.cornerMinEigenVal(small, 3)[:rows * half, :cols * half]
    z = np.ascontiguousarray(depth[:rows * cell:2, :cols * cell:2], np.float32)
    score = np.where(smooth_depth(z, depth_jump), score, 0.0)
    blocks = score.reshape(rows, half, cols, half).transpose(0, 2, 1, 3).reshape(rows * cols, -1)
    best = np.argmax(blocks, axis=1)
    top = blocks[np.arange(len(best)), best]
    r, c = np.divmod(np.arange(rows * cols), cols)
    uv = np.stack([2.0 * (c * half + best % half), 2.0 * (r * half + best // half)], axis=1)
    textured = top >= TEXTURE_FRACTION * max(float(score.max()), 1e-12)
    h, w = grey.shape
    uv = np.clip(uv, 1.0, [w - 2.0, h - 2.0])
    return np.where(textured[:, None], uv, centres).astype(np.float32)


class _Frame(NamedTuple):
    """What the tracker keeps of a frame so that it is processed once."""

    grey: np.ndarray  # (H, W) uint8, for LK
    grey_f: np.ndarray  # (H, W) float32, for the similarity patches
    z_grid: np.ndarray  # (n,) float32 metres at the grid points (0 = none)
    z_grid_ok: np.ndarray  # (n,) bool
    uv: np.ndarray  # (n, 2) float32 the grid points of this image (grid_points), pixels


def _as_grey(bgr, height: int, width: int) -> np.ndarray | None:
    if not isinstance(bgr, np.ndarray) or bgr.dtype != np.uint8:
        return None
    if bgr.shape == (height, width, 3):
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    if bgr.shape == (height, width):
        return bgr
    return None


def _as_depth(depth, height: int, width: int) -> np.ndarray | None:
    if not isinstance(depth, np.ndarray) or depth.shape != (height, width):
        return None
    if not np.issubdtype(depth.dtype, np.floating):
        return None  # raw sensor units would need a scale: the contract is float metres
    return depth


class GridFlowTracker:
    """Streaming grid flow: feed frames in order, get the flow of each consecutive pair.

    Each frame is converted to grey and its refined depth looked up at the grid once; the
    tracker keeps that as the previous frame. A frame that is unreadable or of the wrong
    size yields an all-invalid ``BAD_INPUT`` flow and is skipped: the previous frame stays,
    so the next pair spans the gap (consistent with a pose carried over the skipped frame).

    Args:
        K: intrinsics of the (depth-registered) camera, pixels.
        cfg: settings: a :class:`~jaxvo.config.Config`, of which the tracker keeps and reads
            only its :class:`~jaxvo.config.FlowOptions` (``cfg.flow``), or those themselves.
        height, width: image size, pixels; sets the grid and so ``n``.
    """

    def __init__(self, K: Intrinsics, cfg: Config | FlowOptions = DEFAULT_CONFIG, *,
                 height: int, width: int):
        self.K = K
        self.cfg = cfg = flow_options(cfg)
        self.height, self.width = int(height), int(width)
        self.grid = grid_shape(self.height, self.width, cfg.cell)
        self.uv_grid = grid_pixels(self.height, self.width, cfg.cell)  # (n, 2) float32
        self.n = self.uv_grid.shape[0]
        self._grid_lookup = _lookup(self.uv_grid, self.height, self.width, cfg)
        # Float grey images for the patches. A fresh image-sized array per frame cost page
        # faults on every pair (the heap is trimmed and regrown each time); instead two
        # buffers take turns, the previous frame holding the other one.
        self._grey_f = tuple(np.empty((self.height, self.width), np.float32) for _ in range(2))
        self._win = (cfg.lk_window, cfg.lk_window)
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.lk_iters, cfg.lk_eps)
        self._prev: _Frame | None = None
        self._levels = cfg.lk_levels  # pyramid levels of the next pair's LK
        self._before: tuple[_Frame | None, int] = (None, cfg.lk_levels)  # see drop_last

    @property
    def has_previous(self) -> bool:
        return self._prev is not None

    @property
    def last(self) -> _Frame | None:
        """What the tracker keeps of the frame last pushed (None before the first)."""
        return self._prev

    def lk_seeded(self, src: np.ndarray, dst: np.ndarray, pts: np.ndarray, seed: np.ndarray,
                  levels: int):
        """LK positions in ``dst`` (H, W) uint8 of ``pts`` (m, 2) in ``src``, each search
        started at ``seed`` (m, 2) on ``levels`` pyramid levels above the finest, and LK's
        status (m, 1): the tracker's window and stopping rule."""
        if len(pts) == 0:
            return pts, np.zeros((0, 1), np.uint8)
        found, st, _ = cv2.calcOpticalFlowPyrLK(
            src, dst, pts, seed.copy(), winSize=self._win, maxLevel=levels,
            criteria=self._criteria,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW | cv2.OPTFLOW_LK_GET_MIN_EIGENVALS,
        )  # fmt: skip
        return found, st

    def reset(self) -> None:
        """Forget the previous frame (the next frame starts a new pair chain)."""
        self._prev = None
        self._levels = self.cfg.lk_levels

    def drop_last(self) -> None:
        """Forget the frame last pushed: the next frame pairs with the one before it, as
        if the dropped frame had never come (see :class:`FrameChain`)."""
        self._prev, self._levels = self._before

    def push(self, bgr, depth) -> GridFlow | None:
        """Add the next frame; the flow from the previous frame to it.

        Args:
            bgr: (H, W, 3) uint8 BGR (or (H, W) uint8 grey).
            depth: (H, W) float32 metres, 0 = no reading.

        Returns:
            The pair's :class:`GridFlow`; ``None`` if there was no previous frame (this
            frame is kept as the previous one); an all-invalid flow with ``BAD_INPUT`` if this
            frame is unreadable or of another size.
        """
        grey = _as_grey(bgr, self.height, self.width)
        d = _as_depth(depth, self.height, self.width)
        if grey is None or d is None:
            return invalid_flow(self.uv_grid, Status.BAD_INPUT, focal=self.K.focal,
                                camera=camera_row(self.K))
        # this frame's grid points and their depth are read by the next pair only: beside LK
        grid_depth = _beside(self._grid_points, grey, d)
        prev = self._prev
        self._before = (prev, self._levels)
        held = prev.grey_f if prev is not None else None
        grey_f = self._grey_f[1] if held is self._grey_f[0] else self._grey_f[0]
        np.copyto(grey_f, grey)
        flow = None if prev is None else self._track(prev, grey, grey_f, d)
        self._prev = _Frame(grey, grey_f, *grid_depth.result())
        return flow

    def _grid_points(self, grey: np.ndarray, depth: np.ndarray):
        """This image's grid points and their refined depth: ``(z (n,), ok (n,), uv (n, 2))``.

        With ``cfg.textured_points`` each cell's point is its most trackable pixel with a
        depth reading (the largest minimum eigenvalue of the image's gradient structure,
        Shi and Tomasi's measure, on the half-size image) where that reaches
        :data:`TEXTURE_FRACTION` of the image's largest, else the cell's centre: a cell
        centre on a textureless wall or floor gives LK nothing to follow, while a textured
        pixel elsewhere in the same cell does. One point per cell keeps the grid and its
        model as they are."""
        if not self.cfg.textured_points:
            return (*_depth_at(depth, self._grid_lookup, self.cfg), self.uv_grid)
        uv = textured_points(grey, depth, self.uv_grid, self.grid, self.cfg.cell,
                             self.cfg.depth_jump)
        look = _lookup(uv, self.height, self.width, self.cfg)
        return (*_depth_at(depth, look, self.cfg), uv)

    def _lk(self, src: np.ndarray, dst: np.ndarray, pts: np.ndarray):
        """LK positions in ``dst`` of ``pts`` (m, 2) in ``src``, and LK's status (m, 1)."""
        if len(pts) == 0:
            return pts, np.zeros((0, 1), np.uint8)
        # The flag makes LK report the minimum eigenvalue it has already computed as the
        # error, instead of a last pass over each window for a residual nobody reads: less
        # time, the same positions and status.
        found, st, _ = cv2.calcOpticalFlowPyrLK(
            src, dst, pts, None,
            winSize=self._win, maxLevel=self._levels, criteria=self._criteria,
            flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS,
        )  # fmt: skip
        return found, st

    def _track(
        self, prev: _Frame, grey: np.ndarray, grey_f: np.ndarray, depth: np.ndarray
    ) -> GridFlow:
        """The checks of the module docstring, cheapest first, each on the survivors of the
        last: LK per point and direction is most of the time per pair, and
        tracks each point on its own, so following only the points that can still pass
        gives the same flow as checking every point. ``grey``, ``grey_f`` and ``depth`` are
        the current frame's."""
        cfg = self.cfg
        uv0 = prev.uv
        idx = np.flatnonzero(prev.z_grid_ok)  # no depth at the start: never a valid track

        uv1, st = self._lk(prev.grey, grey, uv0[idx])
        ok = lk_converged(uv1, st, width=self.width, height=self.height)
        idx, uv1 = idx[ok], uv1[ok]

        # the similarity rejects more than the depth check, for less
        ok = similar(prev.grey_f, uv0[idx], grey_f, uv1, side=cfg.patch, least=cfg.min_similarity)
        idx, uv1 = idx[ok], uv1[ok]

        # depth at the tracked points beside backward LK (which then also tracks the few
        # points the depth check drops: the two take about as long)
        tracked_depth = _beside(_depth_slope_at, depth,
                                _lookup(uv1, self.height, self.width, cfg), cfg)
        uv_back, st = self._lk(grey, prev.grey, uv1)
        fb = np.hypot(*(uv_back - uv0[idx]).T).astype(np.float32)
        ok = (st[:, 0] == 1) & (fb <= cfg.fb_max)  # NaN fails
        z1, has_depth, slope1 = tracked_depth.result()
        ok &= has_depth
        idx, uv1, z1, fb, slope1 = idx[ok], uv1[ok], z1[ok], fb[ok], slope1[ok]

        valid = np.zeros(self.n, bool)
        valid[idx] = True
        # fast motion: the next pair's LK gets one pyramid level more
        fast = len(idx) > 0 and np.median(np.hypot(*(uv1 - uv0[idx]).T)) > cfg.lk_fast_px
        self._levels = cfg.lk_levels + int(fast)
        pts_prev = np.zeros((self.n, 3), np.float32)
        pts_cur = np.zeros((self.n, 3), np.float32)
        pts_prev[idx] = backproject(uv0[idx], prev.z_grid[idx], self.K)
        pts_cur[idx] = backproject(uv1, z1, self.K)
        uv_cur = uv0.copy()
        uv_cur[idx] = uv1
        fb_error = np.zeros(self.n, np.float32)
        fb_error[idx] = fb
        depth_slope = np.zeros(self.n, np.float32)
        depth_slope[idx] = slope1
        return GridFlow(
            pts_prev=pts_prev,
            pts_cur=pts_cur,
            uv_prev=uv0.copy(),
            uv_cur=uv_cur,
            valid=valid,
            status=np.int32(Status.OK),
            focal=np.float32(self.K.focal),
            depth_prev=np.where(prev.z_grid_ok, prev.z_grid, 0.0).astype(np.float32),
            camera=camera_row(self.K),
            fb_error=fb_error,
            depth_slope=depth_slope,
        )


def _frame_size(*arrays) -> tuple[int, int] | None:
    for a in arrays:
        if isinstance(a, np.ndarray) and a.ndim >= 2:
            return int(a.shape[0]), int(a.shape[1])
    return None


def grid_flow(
    prev_bgr: np.ndarray,
    prev_depth: np.ndarray,
    cur_bgr: np.ndarray,
    cur_depth: np.ndarray,
    K: Intrinsics,
    cfg: Config = DEFAULT_CONFIG,
    *,
    image_size: tuple[int, int] | None = None,
) -> GridFlow:
    """Grid flow of one image pair (thesis 2.2).

    Args:
        prev_bgr, cur_bgr: (H, W, 3) uint8 BGR.
        prev_depth, cur_depth: (H, W) float32 metres, 0 = no reading.
        K: intrinsics, pixels.
        cfg: settings.
        image_size: ``(H, W)`` that sets the grid; default the previous image's size. Only
            needed when neither image is an array at all.

    Returns:
        :class:`GridFlow` with ``n = rows * cols`` points; ``BAD_INPUT`` and all invalid if
        the frames differ in size or one is unreadable.

    Raises:
        InputError: no image size can be told (neither image is an array, no ``image_size``).
    """
    size = image_size or _frame_size(prev_bgr, cur_bgr, prev_depth, cur_depth)
    if size is None:
        raise InputError("grid_flow: neither frame is an image and no image_size was given")
    tracker = GridFlowTracker(K, cfg, height=size[0], width=size[1])
    first = tracker.push(prev_bgr, prev_depth)
    if first is not None:  # the previous frame itself is unreadable
        return first
    return tracker.push(cur_bgr, cur_depth)


_READ_ERRORS = (OSError, ValueError)

# Frames dropped in a row before the chain starts again from the current frame: after that
# many the camera has likely moved too far from the last good frame for LK to find it
# again (at 30 Hz, 1/6 s), and the device's skip is the better answer.
MAX_DROPPED = 5


def min_valid_flow(cfg: Config = DEFAULT_CONFIG, *, params: Params | None = None) -> int:
    """Fewest valid flow vectors a pair needs: below this the spatial stage reports
    ``TOO_FEW_FLOW`` (``spatial.segment``: a minimal sample of ``cfg.sample_size`` points,
    and more than ``params.min_segment_points`` for a segment).

    Args:
      cfg: static settings.
      params: numeric settings (default :class:`Params`); batched fields take their largest.
    Returns:
      the count, grid points.
    """
    p = params if params is not None else Params()
    most = float(np.max(np.asarray(p.min_segment_points)))
    return max(cfg.sample_size, 3, int(np.floor(most)) + 1)


class FrameChain:
    """Pairs each frame with the last good one, and drops the frames that cannot be used.

    A frame is dropped when it cannot be read, its size differs from the first frame's, or
    its flow with the last good frame has fewer than ``min_valid`` valid vectors (a black,
    saturated, noise or badly blurred image). Its pair never reaches the device and the next
    frame pairs with the last good frame, so a useless frame costs its own pose only, not
    the motion of the two pairs it belongs to.

    Two cases keep such a frame, and its pair goes to the device, which skips it: the last
    good frame has not yet been part of a good pair (it may be the useless one itself, e.g.
    a black first frame), or ``max_dropped`` frames in a row were dropped (the camera may
    have moved beyond what LK can track from the last good frame): the chain goes on from
    the current frame.

    Args:
      tracker: the :class:`GridFlowTracker` of the stream (its image size is the stream's).
      min_valid: fewest valid vectors of a usable pair (:func:`min_valid_flow`).
      max_dropped: most frames dropped in a row.
      keyframes: track the keyframe's points too (``cfg.keyframes``): each kept pair's
        :class:`KeyframeFlow` is then ``keyframe_flow`` after :meth:`push`.
    """

    def __init__(self, tracker: GridFlowTracker, *, min_valid: int, max_dropped: int = MAX_DROPPED,
                 keyframes: bool = False):
        self.tracker = tracker
        self.keyframes = KeyframeTracker(tracker) if keyframes else None
        self.keyframe_flow: KeyframeFlow | None = None
        self.min_valid = int(min_valid)
        self.max_dropped = int(max_dropped)
        self._confirmed = False  # the last good frame has been part of a good pair
        self._in_a_row = 0  # frames dropped since the last kept one

    def push(
        self, bgr, depth, *, unreadable: str | None = None
    ) -> tuple[GridFlow | None, str | None]:
        """Add the next frame.

        Args:
          bgr: (H, W, 3) uint8 BGR (or (H, W) grey); ignored when ``unreadable``.
          depth: (H, W) float32 metres, 0 = no reading.
          unreadable: why the frame could not be read, if it could not: it is dropped.
        Returns:
          ``(flow, dropped)``: the pair's :class:`GridFlow` for the device (None for the
          first frame of the chain or a dropped frame), and why the frame was dropped
          (None when it is kept).
        """
        t = self.tracker
        if unreadable is not None:
            return self._drop(f"unreadable frame ({unreadable})")
        sizes = [np.shape(a)[:2] for a in (bgr, depth)]
        if any(size != (t.height, t.width) for size in sizes):
            got = ", ".join(f"{what} {'x'.join(map(str, size[::-1])) or 'none'}"
                            for what, size in zip(("colour", "depth"), sizes))
            return self._drop(f"image size ({got}) differs from the first frame's "
                              f"{t.width}x{t.height}")
        flow = t.push(bgr, depth)
        if flow is None:  # the chain's first frame
            self._confirmed, self._in_a_row = False, 0
            if self.keyframes is not None:
                self.keyframes.start()
            return None, None
        if flow.status != Status.OK:
            return self._drop("frame unreadable (not a uint8 colour image with float depth)")
        n_valid = int(np.count_nonzero(flow.valid))
        if n_valid >= self.min_valid:
            self._confirmed, self._in_a_row = True, 0
            return self._kept(flow, depth)
        if self._confirmed and self._in_a_row < self.max_dropped:
            t.drop_last()
            return self._drop(
                f"too few valid flow vectors with the last good frame (fewer than "
                f"{self.min_valid}: black, saturated, noise or blurred image)"
            )
        self._confirmed, self._in_a_row = False, 0  # the chain goes on from this frame
        return self._kept(flow, depth)

    def _kept(self, flow: GridFlow, depth) -> tuple[GridFlow, None]:
        if self.keyframes is not None:
            self.keyframe_flow = self.keyframes.push(flow, depth)
        return flow, None

    def _drop(self, reason: str) -> tuple[None, str]:
        self._in_a_row += 1
        return None, reason


class SequenceFlows(NamedTuple):
    """The grid flow of a recorded sequence, over the frames kept (see :class:`FrameChain`)."""

    flows: GridFlow  # stacked over the T pairs the device steps
    # (T + 1,) int, indices of the frames kept: pair k is frames[k] -> frames[k + 1]
    frames: np.ndarray
    dropped: dict[int, str]  # index of each dropped frame -> why
    # with cfg.keyframes: pair k's keyframe flow (stacked as flows), else None
    keyframes: KeyframeFlow | None = None


def sequence_flows(
    seq,
    cfg: Config = DEFAULT_CONFIG,
    *,
    params: Params | None = None,
    progress: Callable[[int, int], None] | None = None,
    max_dropped: int = MAX_DROPPED,
    ahead: int = READ_AHEAD,
) -> SequenceFlows:
    """Grid flow of every pair of consecutive kept frames of a sequence, for the scan.

    A frame that cannot be read (``OSError`` / ``ValueError`` from ``seq[i]``), has the
    wrong size, or whose flow with the last good frame is unusable is dropped, and the next
    frame pairs with the last good one (:class:`FrameChain`).

    Args:
        seq: a sequence per docs/architecture.md (``len``, ``seq[i] -> Frame``,
            ``intrinsics``, ``height``, ``width``).
        cfg: settings.
        params: the run's numeric settings (they set :func:`min_valid_flow`).
        progress: called as ``progress(frames_done, frames_total)`` after each frame after
            the first (``frames_total = len(seq) - 1``).
        max_dropped: most frames dropped in a row (:class:`FrameChain`).
        ahead: frames read (decoded, rendered) ahead on other threads while the flow of
            the current pair is computed (:func:`jaxvo.host.frontend.prefetch.read_ahead`); 0 reads
            each frame when its turn comes.

    Returns:
        :class:`SequenceFlows`.
    """
    n_frames = len(seq)
    height, width = getattr(seq, "height", None), getattr(seq, "width", None)
    if height is None or width is None:
        first = seq[0]
        height, width = first.bgr.shape[:2]
    cfg = flow_options(cfg)
    tracker = GridFlowTracker(seq.intrinsics, cfg, height=height, width=width)
    chain = FrameChain(tracker, min_valid=min_valid_flow(cfg, params=params),
                       max_dropped=max_dropped, keyframes=cfg.keyframes)
    flows: list[GridFlow] = []
    kf_flows: list[KeyframeFlow] = []
    frames: list[int] = []
    dropped: dict[int, str] = {}
    for i, read in read_ahead(seq.__getitem__, range(n_frames), ahead=ahead):
        try:
            frame = read.result()
        except _READ_ERRORS as exc:
            flow, why = chain.push(None, None, unreadable=str(exc))
        else:
            flow, why = chain.push(frame.bgr, frame.depth)
        if why is not None:
            dropped[i] = why
        else:
            frames.append(i)
            if flow is not None:
                flows.append(flow)
                if chain.keyframe_flow is not None:
                    kf_flows.append(chain.keyframe_flow)
        if i and progress is not None:
            progress(i, n_frames - 1)
    stacked = stack_flows(flows, invalid_flow(tracker.uv_grid, focal=seq.intrinsics.focal,
                                              camera=camera_row(seq.intrinsics)))
    keyframes = (stack_flows(kf_flows, invalid_keyframe_flow(tracker.n, cfg.keyframe_window)) if cfg.keyframes
                 else None)
    return SequenceFlows(stacked, np.asarray(frames, np.int64), dropped, keyframes)


def flows_for_sequence(
    seq, cfg: Config = DEFAULT_CONFIG, *, progress: Callable[[int, int], None] | None = None
) -> GridFlow:
    """:func:`sequence_flows`'s stacked flow alone: one pair per pair of consecutive kept
    frames (``len(seq) - 1`` pairs when no frame is dropped)."""
    return sequence_flows(seq, cfg, progress=progress).flows
