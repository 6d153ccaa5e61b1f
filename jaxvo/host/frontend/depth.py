"""Depth for the grid flow: refinement of a raw depth image and bilinear lookups at points
(host side, numpy and OpenCV, never traced).

Raw RGB-D depth has holes, flying pixels at object edges and frame-to-frame noise.
:func:`refine_depth` drops what no sensor reads, fills isolated holes from their
neighbourhood and smooths over agreeing windows; :func:`depth_at` gives the same values at
given points while refining only the pixels their bilinear lookups read (a quarter of a
640x480 image for the 1200 grid points), and :func:`bilinear_slope` the slope of that
surface there (the depth noise of a point that LK places a fraction of a pixel off).
:func:`smooth_depth` says which pixels lie on one surface, not on a depth edge.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from jaxvo.config import Config

DEFAULT_CONFIG = Config()

# Stand-in for "no reading" when taking a neighbourhood minimum, metres (far beyond any sensor).
_FAR = np.float32(1e6)


def refine_depth(depth: np.ndarray, cfg: Config = DEFAULT_CONFIG) -> np.ndarray:
    """Refined depth image: holes filled from similar neighbours, flying pixels dropped.

    The definition, on the whole image with OpenCV box / morphology filters. The tracker
    needs it only at the pixels that its bilinear lookups read and computes just those with
    :func:`depth_at`, which gives the same values.

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

    Returns:
        (H, W) float32 metres, 0 = no trustworthy depth.
    """
    d = np.asarray(depth, np.float32)
    jump = np.float32(cfg.depth_jump)
    trusted = cv2.inRange(d, cfg.depth_min, cfg.depth_max)  # 255 / 0; NaN fails
    out = np.zeros_like(d)
    cv2.copyTo(d, trusted, out)
    far = np.full_like(d, _FAR)  # the same depths, holes far away, so a minimum filter skips them
    cv2.copyTo(d, trusted, far)

    k = 2 * cfg.fill_radius + 1
    box = np.ones((k, k), np.uint8)
    border = cv2.BORDER_CONSTANT
    total = cv2.boxFilter(out, -1, (k, k), normalize=False, borderType=border)
    # 255 per valid neighbour
    count = cv2.boxFilter(trusted, cv2.CV_32F, (k, k), normalize=False, borderType=border)
    mean = total / np.maximum(count, np.float32(1)) * np.float32(255)
    spread = cv2.dilate(out, box) - cv2.erode(far, box)  # range of the valid neighbours
    fill = (spread <= mean * jump) & (count >= np.float32(255 * cfg.fill_min_valid))
    if not cfg.depth_smooth:
        fill &= trusted == 0
    np.copyto(out, mean, where=fill)
    np.copyto(far, mean, where=fill)

    three = np.ones((3, 3), np.uint8)
    spread = cv2.dilate(out, three) - cv2.erode(far, three)
    out[spread > out * jump] = 0  # also true at holes next to readings: they stay 0
    return out


def _window_1d(a: np.ndarray, k: int, op: np.ufunc, axis: int, dtype=None) -> np.ndarray:
    """``op`` over every run of ``k`` entries along ``axis`` (0 or 1), computed in ``dtype``.

    Runs of 1, 2, 4, ... entries are combined by doubling and the binary digits of ``k``
    picked from them: 3 operations for k = 5 instead of 4.
    """
    m = a.shape[axis] - k + 1

    def part(x: np.ndarray, start: int, stop: int) -> np.ndarray:
        return x[start:stop] if axis == 0 else x[:, start:stop]

    runs, span, offset, out = a, 1, 0, None  # runs[i] = op over a[i : i + span]
    while True:
        if k & span:
            piece = part(runs, offset, offset + m)
            out = piece if out is None else op(out, piece)
            offset += span
        if offset == k:
            return out
        runs = op(part(runs, 0, runs.shape[axis] - span), part(runs, span, None), dtype=dtype)
        span *= 2


def _windows(a: np.ndarray, k: int, op: np.ufunc, dtype=None) -> np.ndarray:
    """``op`` over every k x k window of the leading two axes: (s, s, ...) -> (s-k+1, s-k+1, ...)."""
    return _window_1d(_window_1d(a, k, op, 0, dtype), k, op, 1, dtype)


def _refine_blocks(raw: np.ndarray, inside: np.ndarray | None, cfg: Config) -> np.ndarray:
    """:func:`refine_depth` at the central 2x2 pixels of raw depth blocks.

    A refined pixel depends on the step-2 values of its 3x3 neighbourhood, and each of
    those on its ``(2 r + 1)^2`` window of raw readings, so a 2x2 block needs the
    ``s = 2 + 2 (r + 1)`` square of raw pixels around it. The operations and their float32
    rounding are those of :func:`refine_depth`; the window sums are exact in float64 (as in
    OpenCV's box filter), so the results are equal bit for bit. Selections are written as
    arithmetic: ``np.where`` costs several times more on these arrays.

    Args:
        raw: (s, s, n) raw depth, metres; the point axis last keeps the slices contiguous.
        inside: (s, s, n) bool, the pixel lies in the image (pixels outside count as the
            image border does in :func:`refine_depth`); ``None`` if all do.
        cfg: thresholds.

    Returns:
        (2, 2, n) float32 refined depth, 0 = none.
    """
    r = cfg.fill_radius
    jump = np.float32(cfg.depth_jump)
    d = raw.astype(np.float32, copy=False)
    trusted = (d >= np.float32(cfg.depth_min)) & (d <= np.float32(cfg.depth_max))  # NaN fails
    if inside is not None:
        trusted &= inside
    out = d * trusted
    out[np.isnan(out)] = 0  # NaN and inf readings (untrusted, times 0)
    far = out + _FAR * ~trusted  # holes far away, so a minimum filter skips them

    k = 2 * r + 1
    total = _windows(out.astype(np.float64), k, np.add).astype(np.float32)
    count = _windows(trusted, k, np.add, np.uint16) * np.float32(255)
    mean = total / np.maximum(count, np.float32(1)) * np.float32(255)
    spread = _windows(out, k, np.maximum) - _windows(far, k, np.minimum)
    fill = (spread <= mean * jump) & (count >= np.float32(255 * cfg.fill_min_valid))
    inner = (slice(r, -r), slice(r, -r))
    if inside is not None:
        fill &= inside[inner]  # outside the image there is no pixel to fill
    if not cfg.depth_smooth:
        fill &= ~trusted[inner]
    out = np.where(fill, mean, out[inner])
    far = np.where(fill, mean, far[inner])

    spread = _windows(out, 3, np.maximum) - _windows(far, 3, np.minimum)
    centre = out[1:-1, 1:-1]
    return centre * ~(spread > centre * jump)


class _Lookup(NamedTuple):
    """Where a bilinear depth lookup at points ``uv`` reads, set up once per point set."""

    ax: np.ndarray  # (n,) float32 bilinear weight of the right-hand column
    ay: np.ndarray  # (n,) float32 bilinear weight of the lower row
    inside: np.ndarray  # (n,) bool, the 2x2 footprint lies in the image
    x0: np.ndarray  # (n,) intp top-left pixel of the footprint (0 where not inside)
    y0: np.ndarray  # (n,) intp
    raw_index: np.ndarray  # (s, s, n) intp flat indices of the raw pixels refinement reads
    raw_inside: np.ndarray | None  # (s, s, n) bool, that raw pixel lies in the image; None: all


def _lookup(uv: np.ndarray, height: int, width: int, cfg: Config) -> _Lookup:
    x = uv[:, 0].astype(np.float32)
    y = uv[:, 1].astype(np.float32)
    finite = np.isfinite(x) & np.isfinite(y)
    x = np.where(finite, x, -1.0)
    y = np.where(finite, y, -1.0)
    x0 = np.floor(x)
    y0 = np.floor(y)
    inside = finite & (x0 >= 0) & (y0 >= 0) & (x0 <= width - 2) & (y0 <= height - 2)
    xi = np.where(inside, x0, 0).astype(np.intp)
    yi = np.where(inside, y0, 0).astype(np.intp)

    reach = cfg.fill_radius + 1
    offsets = np.arange(2 + 2 * reach) - reach
    # Usually every block lies in the image: one broadcast add. Points without a footprint
    # read some block in the image; their values are never used.
    bx = np.where(inside, xi, reach)
    by = np.where(inside, yi, reach)
    if ((bx >= reach) & (bx <= width - 2 - reach)).all() and (
        (by >= reach) & (by <= height - 2 - reach)
    ).all():
        raw_index = (by * width + bx) + (offsets[:, None, None] * width + offsets[None, :, None])
        raw_inside = None
    else:
        ys, xs = yi + offsets[:, None], xi + offsets[:, None]  # (s, n)
        raw_inside = ((ys >= 0) & (ys < height))[:, None] & ((xs >= 0) & (xs < width))[None]
        raw_index = np.clip(ys, 0, height - 1)[:, None] * width + np.clip(xs, 0, width - 1)[None]
    return _Lookup(
        ax=(x - x0).astype(np.float32),
        ay=(y - y0).astype(np.float32),
        inside=inside,
        x0=xi,
        y0=yi,
        raw_index=raw_index,
        raw_inside=raw_inside,
    )


def _slope(taps: np.ndarray, look: _Lookup, ok: np.ndarray) -> np.ndarray:
    """Gradient length of the bilinear surface of (2, 2, n) taps at the lookup points, m/px
    (0 where not ``ok``)."""
    d00, d01, d10, d11 = taps[0, 0], taps[0, 1], taps[1, 0], taps[1, 1]
    ax, ay = look.ax, look.ay
    gx = (1 - ay) * (d01 - d00) + ay * (d11 - d10)
    gy = (1 - ax) * (d10 - d00) + ax * (d11 - d01)
    return np.where(ok, np.hypot(gx, gy), np.float32(0)).astype(np.float32)


def _bilinear(taps: np.ndarray, look: _Lookup, cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear depth from (2, 2, n) refined taps, valid where they agree (see bilinear_depth)."""
    d00, d01, d10, d11 = taps[0, 0], taps[0, 1], taps[1, 0], taps[1, 1]
    ax, ay = look.ax, look.ay
    lo = np.minimum(np.minimum(d00, d01), np.minimum(d10, d11))
    hi = np.maximum(np.maximum(d00, d01), np.maximum(d10, d11))
    ok = look.inside & (lo > 0) & (hi - lo <= cfg.depth_jump * lo)
    z = (1 - ay) * ((1 - ax) * d00 + ax * d01) + ay * ((1 - ax) * d10 + ax * d11)
    return np.where(ok, z, np.float32(0)).astype(np.float32), ok


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
    return _bilinear(*_taps(depth, uv, cfg), cfg)


def _taps(depth: np.ndarray, uv: np.ndarray, cfg: Config) -> tuple[np.ndarray, _Lookup]:
    """The (2, 2, n) taps of a refined depth image around ``uv`` (n, 2), and the lookup."""
    look = _lookup(uv, *depth.shape, cfg)
    rows = look.y0 + np.arange(2)[:, None, None]
    cols = look.x0 + np.arange(2)[None, :, None]
    return depth[rows, cols], look


def bilinear_slope(depth: np.ndarray, uv: np.ndarray, cfg: Config = DEFAULT_CONFIG) -> np.ndarray:
    """Slope of the surface :func:`bilinear_depth` interpolates, at ``uv`` (n, 2): the length
    of its gradient, (n,) float32 metres per pixel (0 where the lookup is not valid)."""
    taps, look = _taps(depth, uv, cfg)
    return _slope(taps, look, _bilinear(taps, look, cfg)[1])


def _depth_at(depth: np.ndarray, look: _Lookup, cfg: Config) -> tuple[np.ndarray, np.ndarray]:
    raw = np.asarray(depth).reshape(-1).take(look.raw_index)
    return _bilinear(_refine_blocks(raw, look.raw_inside, cfg), look, cfg)


def _depth_slope_at(depth: np.ndarray, look: _Lookup, cfg: Config):
    """:func:`_depth_at` and the surface's slope there (:func:`bilinear_slope`)."""
    raw = np.asarray(depth).reshape(-1).take(look.raw_index)
    taps = _refine_blocks(raw, look.raw_inside, cfg)
    z, ok = _bilinear(taps, look, cfg)
    return z, ok, _slope(taps, look, ok)


def depth_at(
    depth: np.ndarray, uv: np.ndarray, cfg: Config = DEFAULT_CONFIG
) -> tuple[np.ndarray, np.ndarray]:
    """``bilinear_depth(refine_depth(depth), uv)``, refining only the pixels it reads.

    Each point reads the refined 2x2 pixels around it, which depend on the
    ``(2 + 2 (r + 1))^2`` raw pixels around those (8x8 for ``r = cfg.fill_radius = 2``):
    for the 1200 grid points that is about a quarter of a 640x480 image, gathered and
    refined in a few numpy operations instead of whole-image filters.

    Args:
        depth: (H, W) float metres, raw (0 = no reading).
        uv: (n, 2) pixels (x, y).
        cfg: thresholds.

    Returns:
        ``(z, ok)``: (n,) float32 metres (0 where not ok) and (n,) bool.
    """
    return _depth_at(depth, _lookup(uv, *np.shape(depth), cfg), cfg)


def smooth_depth(z: np.ndarray, depth_jump: float) -> np.ndarray:
    """(h, w) bool pixels of ``z`` (metres, 0 = none) whose 3 x 3 neighbourhood all has depth
    within ``depth_jump`` of its nearest: on one surface, not on a depth edge (where a
    pixel's depth is either surface's, or between them)."""
    kernel = np.ones((3, 3), np.uint8)
    near = cv2.erode(z, kernel, borderType=cv2.BORDER_REPLICATE)
    far = cv2.dilate(z, kernel, borderType=cv2.BORDER_REPLICATE)
    return (near > 0) & (far - near <= depth_jump * near)
