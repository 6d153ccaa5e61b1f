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

Speed: each frame is converted to grey, refined and sampled at the grid once
(:class:`GridFlowTracker` keeps the previous frame). OpenCV's Python binding cannot take the
pyramids of ``cv2.buildOpticalFlowPyramid`` back into ``cv2.calcOpticalFlowPyrLK``
(opencv/opencv#4777), so each LK call rebuilds them; LK itself is most of the time per pair.

Host only: numpy and OpenCV, never traced.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import cv2
import numpy as np

from jaxvo.camera import Intrinsics, backproject, grid_pixels
from jaxvo.config import Config, grid_shape
from jaxvo.errors import InputError
from jaxvo.status import Status

DEFAULT_CONFIG = Config()

# Stand-in for "no reading" when taking a neighbourhood minimum, metres (far beyond any sensor).
_FAR = np.float32(1e6)


class GridFlow(NamedTuple):
    """Grid flow of one image pair (host -> device); see docs/architecture.md."""

    pts_prev: np.ndarray  # (n, 3) float32 metres, previous camera frame (0 where invalid)
    pts_cur: np.ndarray  # (n, 3) float32 metres, current camera frame (0 where invalid)
    uv_prev: np.ndarray  # (n, 2) float32 pixels, grid cell centres in the previous image
    uv_cur: np.ndarray  # (n, 2) float32 pixels, tracked positions (= uv_prev where invalid)
    valid: np.ndarray  # (n,) bool, passed LK, forward-backward, similarity and depth checks
    status: np.ndarray  # () int32 Status code: OK, or BAD_INPUT


def invalid_flow(uv_grid: np.ndarray, status: int = Status.BAD_INPUT) -> GridFlow:
    """An all-invalid :class:`GridFlow` on the grid ``uv_grid`` (n, 2) with ``status``."""
    n = uv_grid.shape[0]
    uv = np.asarray(uv_grid, np.float32)
    return GridFlow(
        pts_prev=np.zeros((n, 3), np.float32),
        pts_cur=np.zeros((n, 3), np.float32),
        uv_prev=uv.copy(),
        uv_cur=uv.copy(),
        valid=np.zeros(n, bool),
        status=np.int32(status),
    )


def stack_flows(flows: list[GridFlow]) -> GridFlow:
    """Stack per-pair flows along a new leading frame axis."""
    return GridFlow(*(np.stack(field) for field in zip(*flows)))


# ----------------------------------------------------------------------------- depth


class _RefineWork:
    """Scratch buffers of :func:`refine_depth`, reused frame after frame.

    Fresh (H, W) arrays cost page faults on every call (several ms at 640x480 here), more
    than the filtering itself. Two output buffers alternate so that the previous frame's
    refined depth stays intact while the current one is written.
    """

    def __init__(self, height: int, width: int):
        shape = (height, width)
        self.trusted = np.empty(shape, np.uint8)
        self.far, self.total, self.count, self.mean, self.a, self.b = (
            np.empty(shape, np.float32) for _ in range(6)
        )
        self.m1 = np.empty(shape, bool)
        self.m2 = np.empty(shape, bool)
        self._outs = (np.empty(shape, np.float32), np.empty(shape, np.float32))
        self._turn = 0

    def next_out(self) -> np.ndarray:
        self._turn ^= 1
        return self._outs[self._turn]


def refine_depth(
    depth: np.ndarray, cfg: Config = DEFAULT_CONFIG, *, work: _RefineWork | None = None
) -> np.ndarray:
    """Refined depth image: holes filled from similar neighbours, flying pixels dropped.

    Works on the whole image with OpenCV box / morphology filters, once per frame (the
    tracker keeps the result and reuses its buffers): a few whole-image passes cost about as
    much as gathering the 8x8 neighbourhoods of 2 x n points in numpy, and stay simple.

    1. Readings outside ``[cfg.depth_min, cfg.depth_max]`` or not finite become 0.
    2. A hole is filled with the mean of the valid pixels in its ``(2 r + 1)^2`` window
       (``r = cfg.fill_radius``) if at least ``cfg.fill_min_valid`` are valid and they agree:
       their range is at most ``cfg.depth_jump`` times their mean (no filling across edges).
       With ``cfg.depth_smooth`` a valid pixel whose window agrees takes the mean too: the
       frame-to-frame depth noise of the sensor (which grows with z^2 and is several times
       the per-frame motion of a slow object at 2-3 m) shrinks by about the window's side,
       while windows across an edge, which do not agree, keep their raw readings.
    3. A pixel whose 3x3 neighbourhood spans more than ``cfg.depth_jump`` times its depth is
       dropped: depth discontinuities and the flying pixels between the two sides.

    Args:
        depth: (H, W) float metres, 0 = no reading.
        cfg: thresholds (flow section of :class:`Config`).
        work: scratch buffers from a tracker (the result is then one of its buffers).

    Returns:
        (H, W) float32 metres, 0 = no trustworthy depth.
    """
    d = np.asarray(depth, np.float32)
    w = work if work is not None else _RefineWork(*d.shape)
    out = w.next_out()
    jump = np.float32(cfg.depth_jump)
    cv2.inRange(d, cfg.depth_min, cfg.depth_max, dst=w.trusted)  # 255 / 0; NaN fails
    out.fill(0)
    cv2.copyTo(d, w.trusted, out)
    w.far.fill(_FAR)  # the same depths, holes far away, so a minimum filter skips them
    cv2.copyTo(d, w.trusted, w.far)

    k = 2 * cfg.fill_radius + 1
    box = np.ones((k, k), np.uint8)
    border = cv2.BORDER_CONSTANT
    cv2.boxFilter(out, -1, (k, k), dst=w.total, normalize=False, borderType=border)
    # 255 per valid neighbour
    cv2.boxFilter(w.trusted, cv2.CV_32F, (k, k), dst=w.count, normalize=False, borderType=border)
    np.maximum(w.count, np.float32(1), out=w.mean)
    np.divide(w.total, w.mean, out=w.mean)
    w.mean *= np.float32(255)
    cv2.dilate(out, box, dst=w.a)
    cv2.erode(w.far, box, dst=w.b)
    np.subtract(w.a, w.b, out=w.a)  # range of the valid neighbours
    np.multiply(w.mean, jump, out=w.b)
    np.less_equal(w.a, w.b, out=w.m1)
    np.greater_equal(w.count, np.float32(255 * cfg.fill_min_valid), out=w.m2)
    w.m1 &= w.m2
    if not cfg.depth_smooth:
        np.equal(w.trusted, 0, out=w.m2)
        w.m1 &= w.m2
    np.copyto(out, w.mean, where=w.m1)
    np.copyto(w.far, w.mean, where=w.m1)

    three = np.ones((3, 3), np.uint8)
    cv2.dilate(out, three, dst=w.a)
    cv2.erode(w.far, three, dst=w.b)
    np.subtract(w.a, w.b, out=w.a)
    np.multiply(out, jump, out=w.b)
    np.greater(w.a, w.b, out=w.m1)  # also true at holes next to readings: they stay 0
    np.copyto(out, np.float32(0), where=w.m1)
    return out


def bilinear_depth(
    depth: np.ndarray, uv: np.ndarray, cfg: Config = DEFAULT_CONFIG
) -> tuple[np.ndarray, np.ndarray]:
    """Depth at sub-pixel points by bilinear interpolation of a refined depth image.

    A tap is valid only if its 4 neighbours lie in the image, all hold a reading, and their
    range is at most ``cfg.depth_jump`` times the smallest (no blending across an edge).

    Args:
        depth: (H, W) float32 metres from :func:`refine_depth`, 0 = none.
        uv: (n, 2) pixels (x, y).
        cfg: thresholds.

    Returns:
        ``(z, ok)``: (n,) float32 metres (0 where not ok) and (n,) bool.
    """
    h, w = depth.shape
    x = uv[:, 0].astype(np.float32)
    y = uv[:, 1].astype(np.float32)
    finite = np.isfinite(x) & np.isfinite(y)
    x = np.where(finite, x, -1.0)
    y = np.where(finite, y, -1.0)
    x0 = np.floor(x)
    y0 = np.floor(y)
    inside = finite & (x0 >= 0) & (y0 >= 0) & (x0 <= w - 2) & (y0 <= h - 2)
    xi = np.where(inside, x0, 0).astype(np.intp)
    yi = np.where(inside, y0, 0).astype(np.intp)
    ax = (x - x0).astype(np.float32)
    ay = (y - y0).astype(np.float32)
    d00 = depth[yi, xi]
    d01 = depth[yi, xi + 1]
    d10 = depth[yi + 1, xi]
    d11 = depth[yi + 1, xi + 1]
    taps = np.stack([d00, d01, d10, d11])
    lo = taps.min(axis=0)
    hi = taps.max(axis=0)
    ok = inside & (lo > 0) & (hi - lo <= cfg.depth_jump * lo)
    z = (1 - ay) * ((1 - ax) * d00 + ax * d01) + ay * ((1 - ax) * d10 + ax * d11)
    return np.where(ok, z, np.float32(0)).astype(np.float32), ok


# ----------------------------------------------------------------------------- patches


def _patch_offsets(side: int) -> tuple[np.ndarray, np.ndarray]:
    r = (side - 1) / 2.0
    o = np.arange(side, dtype=np.float32) - np.float32(r)
    oy, ox = np.meshgrid(o, o, indexing="ij")
    return ox.ravel(), oy.ravel()


def sample_patches(grey: np.ndarray, uv: np.ndarray, side: int) -> np.ndarray:
    """Bilinear ``side`` x ``side`` patches centred on ``uv`` (n, 2), one ``cv2.remap``.

    Returns:
        (n, side * side) float32 grey values (borders replicated).
    """
    ox, oy = _patch_offsets(side)
    map_x = (uv[:, 0:1] + ox[None, :]).astype(np.float32)
    map_y = (uv[:, 1:2] + oy[None, :]).astype(np.float32)
    src = grey if grey.dtype == np.float32 else grey.astype(np.float32)
    return cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def patch_correlation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Correlation coefficient of matching rows of (n, m) patches; 0 for a flat patch."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    num = np.einsum("ij,ij->i", a, b)
    den2 = np.einsum("ij,ij->i", a, a) * np.einsum("ij,ij->i", b, b)
    # A flat patch (std < ~0.1 grey level) carries no evidence: similarity 0, never NaN.
    flat = den2 <= np.float32(1e-2) ** 2 * a.shape[1] ** 2
    return np.where(flat, 0.0, num / np.sqrt(np.where(flat, 1.0, den2))).astype(np.float32)


# ----------------------------------------------------------------------------- front end


class _Frame(NamedTuple):
    """What the tracker keeps of a frame so that it is processed once."""

    grey: np.ndarray  # (H, W) uint8
    depth: np.ndarray  # (H, W) float32 metres, refined
    z_grid: np.ndarray  # (n,) float32 metres at the grid centres (0 = none)
    z_grid_ok: np.ndarray  # (n,) bool
    patches_grid: np.ndarray  # (n, patch^2) float32 grey patches at the grid centres


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

    Each frame is converted to grey, its depth refined and sampled at the grid once; the
    tracker keeps that as the previous frame. A frame that is unreadable or of the wrong
    size yields an all-invalid ``BAD_INPUT`` flow and is skipped: the previous frame stays,
    so the next pair spans the gap (consistent with a pose carried over the skipped frame).

    Args:
        K: intrinsics of the (depth-registered) camera, pixels.
        cfg: settings (flow section).
        height, width: image size, pixels; sets the grid and so ``n``.
    """

    def __init__(self, K: Intrinsics, cfg: Config = DEFAULT_CONFIG, *, height: int, width: int):
        self.K = K
        self.cfg = cfg
        self.height, self.width = int(height), int(width)
        self.grid = grid_shape(self.height, self.width, cfg.cell)
        self.uv_grid = grid_pixels(self.height, self.width, cfg.cell)  # (n, 2) float32
        self.n = self.uv_grid.shape[0]
        self._win = (cfg.lk_window, cfg.lk_window)
        self._criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.lk_iters, cfg.lk_eps)
        self._prev: _Frame | None = None
        self._work = _RefineWork(self.height, self.width)

    @property
    def has_previous(self) -> bool:
        return self._prev is not None

    def reset(self) -> None:
        """Forget the previous frame (the next frame starts a new pair chain)."""
        self._prev = None

    def _ingest(self, bgr, depth) -> _Frame | None:
        grey = _as_grey(bgr, self.height, self.width)
        d = _as_depth(depth, self.height, self.width)
        if grey is None or d is None:
            return None
        refined = refine_depth(d, self.cfg, work=self._work)
        z, ok = bilinear_depth(refined, self.uv_grid, self.cfg)
        patches = sample_patches(grey, self.uv_grid, self.cfg.patch)
        return _Frame(grey, refined, z, ok, patches)

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
        cur = self._ingest(bgr, depth)
        if cur is None:
            return invalid_flow(self.uv_grid, Status.BAD_INPUT)
        prev, self._prev = self._prev, cur
        if prev is None:
            return None
        return self._track(prev, cur)

    def _track(self, prev: _Frame, cur: _Frame) -> GridFlow:
        cfg = self.cfg
        uv0 = self.uv_grid
        uv1, st1, _ = cv2.calcOpticalFlowPyrLK(
            prev.grey, cur.grey, uv0, None,
            winSize=self._win, maxLevel=cfg.lk_levels, criteria=self._criteria,
        )  # fmt: skip
        uv_back, st0, _ = cv2.calcOpticalFlowPyrLK(
            cur.grey, prev.grey, uv1, None,
            winSize=self._win, maxLevel=cfg.lk_levels, criteria=self._criteria,
        )  # fmt: skip
        ok = (st1[:, 0] == 1) & (st0[:, 0] == 1) & np.isfinite(uv1).all(axis=1)
        uv1 = np.where(ok[:, None], uv1, uv0)
        uv_back = np.where(ok[:, None], uv_back, uv0)
        inside = (
            (uv1[:, 0] >= 0) & (uv1[:, 1] >= 0)
            & (uv1[:, 0] <= self.width - 1) & (uv1[:, 1] <= self.height - 1)
        )  # fmt: skip
        fb = np.hypot(*(uv_back - uv0).T)
        ok &= inside & (fb <= cfg.fb_max)

        sim = patch_correlation(prev.patches_grid, sample_patches(cur.grey, uv1, cfg.patch))
        ok &= sim >= cfg.min_similarity

        z1, z1_ok = bilinear_depth(cur.depth, uv1, cfg)
        ok &= prev.z_grid_ok & z1_ok

        p0 = backproject(uv0, prev.z_grid, self.K).astype(np.float32)
        p1 = backproject(uv1, z1, self.K).astype(np.float32)
        keep = ok[:, None]
        return GridFlow(
            pts_prev=np.where(keep, p0, np.float32(0)),
            pts_cur=np.where(keep, p1, np.float32(0)),
            uv_prev=uv0.copy(),
            uv_cur=np.where(keep, uv1, uv0).astype(np.float32),
            valid=ok,
            status=np.int32(Status.OK),
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


def flows_for_sequence(
    seq, cfg: Config = DEFAULT_CONFIG, *, progress: Callable[[int, int], None] | None = None
) -> GridFlow:
    """Grid flow of every consecutive pair of a sequence, stacked for the whole-sequence scan.

    A frame that cannot be read (``OSError`` / ``ValueError`` from ``seq[i]``) or has the
    wrong size gives its pair ``BAD_INPUT``; the next pair then starts from the last good
    frame (see :class:`GridFlowTracker`).

    Args:
        seq: a sequence per docs/architecture.md (``len``, ``seq[i] -> Frame``,
            ``intrinsics``, ``height``, ``width``).
        cfg: settings.
        progress: called as ``progress(pairs_done, pairs_total)`` after each pair.

    Returns:
        :class:`GridFlow` whose fields have a leading axis of ``len(seq) - 1`` pairs.
    """
    n_frames = len(seq)
    height, width = getattr(seq, "height", None), getattr(seq, "width", None)
    if height is None or width is None:
        first = seq[0]
        height, width = first.bgr.shape[:2]
    tracker = GridFlowTracker(seq.intrinsics, cfg, height=height, width=width)
    total = max(n_frames - 1, 0)
    flows: list[GridFlow] = []
    for i in range(n_frames):
        try:
            frame = seq[i]
            bgr, depth = frame.bgr, frame.depth
        except _READ_ERRORS:
            bgr = depth = None
        flow = tracker.push(bgr, depth)
        if i == 0:
            continue  # the first frame only starts the chain (a bad one leaves it empty)
        if flow is None:
            # no good frame before this one: the pair has nothing to track from
            flow = invalid_flow(tracker.uv_grid, Status.BAD_INPUT)
        flows.append(flow)
        if progress is not None:
            progress(len(flows), total)
    if not flows:
        empty = invalid_flow(tracker.uv_grid)
        return GridFlow(*(np.zeros((0, *np.shape(f)), np.asarray(f).dtype) for f in empty))
    return stack_flows(flows)
