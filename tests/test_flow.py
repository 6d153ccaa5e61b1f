"""Tests of the grid flow front end (thesis 2.2) against independent references."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import cv2
import numpy as np
import pytest

from jaxvo.config import Config
from jaxvo.host.frontend.camera import Intrinsics, backproject, grid_pixels, read_camera_file
from jaxvo.host.frontend.flow import (
    GridFlow,
    GridFlowTracker,
    bilinear_depth,
    bilinear_slope,
    depth_at,
    flows_for_sequence,
    grid_flow,
    min_valid_flow,
    refine_depth,
    sequence_flows,
)
from jaxvo.host.frontend.patches import patch_correlation, sample_patches
from jaxvo.host.readers.io import data_root
from jaxvo.status import Status

H, W = 480, 640
K = Intrinsics(525.0, 525.0, 319.5, 239.5, 5000.0)
CFG = Config()


def texture(seed: int, h: int = H, w: int = W) -> np.ndarray:
    """Smooth random multi-scale noise, float32 grey in [0, 255] of size (h, w)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.float32)
    for scale, amp in ((4, 1.0), (8, 1.0), (16, 0.8), (32, 0.6)):
        small = rng.standard_normal((h // scale + 2, w // scale + 2)).astype(np.float32)
        img += (
            amp
            * cv2.resize(small, (w + 2 * scale, h + 2 * scale), interpolation=cv2.INTER_CUBIC)[
                scale : scale + h, scale : scale + w
            ]
        )
    img = cv2.GaussianBlur(img, (0, 0), 1.0)
    img = (img - img.min()) / (img.max() - img.min())
    return 20 + 215 * img


def warp(img: np.ndarray, A: np.ndarray) -> np.ndarray:
    """The image seen after moving its content by the 2x3 affine map A (x' = A [x, y, 1])."""
    return cv2.warpAffine(
        img, A, (img.shape[1], img.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )


def bgr(grey: np.ndarray) -> np.ndarray:
    g = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    return cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)


def plane(z: float) -> np.ndarray:
    return np.full((H, W), z, np.float32)


def interior(uv: np.ndarray, margin: float = 24.0) -> np.ndarray:
    return (
        (uv[:, 0] > margin) & (uv[:, 0] < W - 1 - margin)
        & (uv[:, 1] > margin) & (uv[:, 1] < H - 1 - margin)
    )  # fmt: skip


def check_shapes(flow: GridFlow, n: int) -> None:
    assert flow.pts_prev.shape == (n, 3) and flow.pts_prev.dtype == np.float32
    assert flow.pts_cur.shape == (n, 3) and flow.pts_cur.dtype == np.float32
    assert flow.uv_prev.shape == (n, 2) and flow.uv_prev.dtype == np.float32
    assert flow.uv_cur.shape == (n, 2) and flow.uv_cur.dtype == np.float32
    assert flow.valid.shape == (n,) and flow.valid.dtype == bool
    assert np.shape(flow.status) == () and np.asarray(flow.status).dtype == np.int32
    for a in (flow.pts_prev, flow.pts_cur, flow.uv_prev, flow.uv_cur):
        assert np.isfinite(a).all()
    assert not flow.pts_prev[~flow.valid].any() and not flow.pts_cur[~flow.valid].any()


@pytest.fixture(scope="module")
def tex0() -> np.ndarray:
    return texture(0)


# ----------------------------------------------------------------------------- tracking


@pytest.mark.parametrize(
    "A, med_tol, p95_tol",
    [
        # sub-pixel translation; tolerances in pixels (uint8 images, LK eps 0.03 px)
        (np.array([[1, 0, 2.37], [0, 1, -1.61]]), 0.05, 0.15),
        # small rotation (0.6 deg) + 1 % zoom about the centre + shift; tolerances in pixels
        (None, 0.1, 0.25),
    ],
)
def test_tracks_known_warp(tex0, A, med_tol, p95_tol):
    if A is None:
        A = cv2.getRotationMatrix2D((W / 2, H / 2), 0.6, 1.01)
        A[:, 2] += (1.3, 0.7)
    A = A.astype(np.float64)
    cur = warp(tex0, A)
    flow = grid_flow(bgr(tex0), plane(2.0), bgr(cur), plane(2.0), K, CFG)
    n = grid_pixels(H, W, CFG.cell).shape[0]
    check_shapes(flow, n)
    assert flow.status == Status.OK
    expected = flow.uv_prev @ A[:, :2].T + A[:, 2]
    keep = interior(flow.uv_prev)
    assert flow.valid[keep].mean() > 0.9
    err = np.linalg.norm(flow.uv_cur - expected, axis=1)[keep & flow.valid]
    assert np.median(err) < med_tol
    assert np.percentile(err, 95) < p95_tol


def test_constant_depth_plane_backprojects_in_closed_form(tex0):
    A = np.array([[1, 0, -0.8], [0, 1, 1.4]])
    flow = grid_flow(bgr(tex0), plane(1.7), bgr(warp(tex0, A)), plane(1.7), K, CFG)
    v = flow.valid
    assert v.mean() > 0.8
    # closed form x = (u - cx) z / fx, y = (v - cy) z / fy, z; tolerance 1e-5 m (float32)
    u, w = flow.uv_prev[v].astype(np.float64).T
    ref_prev = np.stack(
        [(u - K.cx) * 1.7 / K.fx, (w - K.cy) * 1.7 / K.fy, np.full_like(u, 1.7)], -1
    )
    np.testing.assert_allclose(flow.pts_prev[v], ref_prev, atol=1e-5)
    ref_cur = backproject(flow.uv_cur[v].astype(np.float64), np.full(v.sum(), 1.7), K)
    np.testing.assert_allclose(flow.pts_cur[v], ref_cur, atol=1e-5)


def test_forward_backward_rejects_replaced_region(tex0):
    cur = tex0.copy()
    y0, y1, x0, x1 = 160, 320, 240, 400
    cur[y0:y1, x0:x1] = texture(7)[y0:y1, x0:x1]  # content unrelated to the previous image
    cfg = dataclasses.replace(CFG, min_similarity=-1.0)  # only the forward-backward check
    flow = grid_flow(bgr(tex0), plane(2.0), bgr(cur), plane(2.0), K, cfg)
    uv = flow.uv_prev
    inside = (uv[:, 0] > x0 + 8) & (uv[:, 0] < x1 - 8) & (uv[:, 1] > y0 + 8) & (uv[:, 1] < y1 - 8)
    far = interior(uv) & ~(
        (uv[:, 0] > x0 - 24) & (uv[:, 0] < x1 + 24) & (uv[:, 1] > y0 - 24) & (uv[:, 1] < y1 + 24)
    )
    assert inside.sum() >= 50
    assert flow.valid[inside].mean() < 0.2
    assert flow.valid[far].mean() > 0.95


def test_similarity_rejects_changed_patch(tex0):
    # Invert a 5x5 block at the centre of some grid cells: the rest of each LK window still
    # matches, so LK and the forward-backward check mostly pass, but the patches differ.
    # The grid points stay at the cells' centres (on the blocks).
    centred = dataclasses.replace(CFG, textured_points=False)
    uv = grid_pixels(H, W, CFG.cell)
    changed = np.arange(200, 1000, 37)
    cur = tex0.copy()
    for x, y in uv[changed]:
        xi, yi = int(x + 0.5), int(y + 0.5)
        cur[yi - 2 : yi + 3, xi - 2 : xi + 3] = 255 - cur[yi - 2 : yi + 3, xi - 2 : xi + 3]
    loose = dataclasses.replace(centred, min_similarity=-1.0)
    a = grid_flow(bgr(tex0), plane(2.0), bgr(cur), plane(2.0), K, loose)
    b = grid_flow(bgr(tex0), plane(2.0), bgr(cur), plane(2.0), K, centred)
    others = np.ones(len(uv), bool)
    others[changed] = False
    others &= interior(uv)
    assert a.valid[changed].mean() > 0.3  # what the other checks let through
    assert b.valid[changed].mean() < 0.1
    assert b.valid[others].mean() > 0.95


def test_refine_fills_isolated_hole_and_drops_flying_pixel():
    d = np.full((40, 60), 2.0, np.float32)
    d[:, 30:] = 3.0  # a depth edge
    d[:, 29] = 2.5  # flying pixels between the two sides
    d[10, 10] = 0.0  # isolated hole on a smooth surface
    d[20, 12] = 2.04  # a little sensor noise near the hole stays
    r = refine_depth(d, CFG)
    # hole filled with the mean of its valid 5x5 neighbours; tolerance 1e-6 m (float32)
    nb = d[8:13, 8:13]
    np.testing.assert_allclose(r[10, 10], nb[nb > 0].mean(), atol=1e-6)
    assert (r[:, 29] == 0).all()  # the flying column is dropped
    # a noisy reading on a smooth surface becomes its 5x5 window's mean (depth_smooth)
    np.testing.assert_allclose(r[20, 12], d[18:23, 10:15].mean(), atol=1e-6)
    assert (r[:, 5:25] > 0).all() and (r[:, 35:55] > 0).all()  # away from the edge: all kept
    np.testing.assert_array_equal(r[:, 35:55], 3.0)


def test_refine_smoothing_cuts_frame_to_frame_noise_and_can_be_switched_off():
    rng = np.random.default_rng(0)
    plane = np.full((60, 80), 2.5, np.float32)
    noisy = plane + rng.normal(0, 0.009, plane.shape).astype(np.float32)  # 1.425e-3 z^2
    inner = (slice(5, -5), slice(5, -5))
    smoothed = refine_depth(noisy, CFG)[inner] - plane[inner]
    # averaging 25 readings: the noise std drops about 5x; required at least 3x
    assert smoothed.std() < noisy[inner].std() / 3
    raw = refine_depth(noisy, dataclasses.replace(CFG, depth_smooth=False))
    np.testing.assert_array_equal(raw[inner], noisy[inner])


def test_refine_drops_out_of_range_and_nan_and_keeps_big_holes_empty():
    d = np.full((30, 30), 2.0, np.float32)
    d[5, 5] = np.nan
    d[6, 20] = 50.0  # beyond depth_max
    d[15:25, 10:20] = 0.0  # a big hole: its centre has no valid neighbours
    r = refine_depth(d, CFG)
    assert np.isfinite(r).all()
    np.testing.assert_allclose(r[5, 5], 2.0, atol=1e-6)  # NaN treated as a hole, filled; m
    np.testing.assert_allclose(r[6, 20], 2.0, atol=1e-6)  # out of range, filled; m
    assert r[20, 15] == 0


def test_bilinear_depth_on_planar_ramp():
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    ramp = (1.5 + 0.002 * xs + 0.001 * ys).astype(np.float32)
    rng = np.random.default_rng(5)
    uv = rng.uniform((0, 0), (W - 1.001, H - 1.001), (500, 2)).astype(np.float32)
    z, ok = bilinear_depth(ramp, uv, CFG)
    assert ok.all()
    ref = 1.5 + 0.002 * uv[:, 0].astype(np.float64) + 0.001 * uv[:, 1].astype(np.float64)
    np.testing.assert_allclose(z, ref, atol=1e-5)  # bilinear is exact on a plane; float32, m
    # out of the image, or one tap without depth, or taps across an edge: not ok, z = 0
    bad = ramp.copy()
    bad[100, 101] = 0.0
    bad[200:, 300:] += 1.0
    uv2 = np.array([[-0.5, 10], [W - 0.5, 10], [100.5, 99.5], [299.5, 199.5]], np.float32)
    z2, ok2 = bilinear_depth(bad, uv2, CFG)
    assert not ok2.any() and not z2.any()
    # its slope is the ramp's gradient, 0 where the lookup is not ok
    np.testing.assert_allclose(bilinear_slope(ramp, uv, CFG), np.hypot(0.002, 0.001),
                               rtol=1e-3)  # float32 differences of taps near 2 m
    assert not bilinear_slope(bad, uv2, CFG).any()


def rough_depth(seed: int, h: int = H, w: int = W, holes: int = 20) -> np.ndarray:
    """Depth with what refinement acts on: a step edge, a slanted plane, sensor noise,
    holes (single pixels and blocks), NaN and out-of-range readings, up to the borders."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:h, 0:w]
    d = np.where(xs < w // 3, 1.2, 2.0 + 0.004 * ys).astype(np.float32)
    d += rng.normal(0, 0.01, d.shape).astype(np.float32)
    d[rng.random(d.shape) < 0.05] = 0.0
    d[rng.random(d.shape) < 0.01] = np.nan
    d[rng.random(d.shape) < 0.01] = 25.0  # beyond depth_max
    for y, x in rng.integers(0, (h, w), (holes, 2)):
        d[y : y + rng.integers(2, 40), x : x + rng.integers(2, 40)] = 0.0
    return d


@pytest.mark.parametrize(
    "cfg",
    [CFG, dataclasses.replace(CFG, depth_smooth=False), dataclasses.replace(CFG, fill_radius=1)],
    ids=["default", "no_smoothing", "radius_1"],
)
def test_depth_at_equals_whole_image_refinement(cfg):
    # The tracker refines only the pixels it reads; the reference refines the whole image
    # with OpenCV filters and interpolates. Equal bit for bit (no tolerance), at random
    # points everywhere and at points right at the borders.
    d = rough_depth(6)
    rng = np.random.default_rng(7)
    uv = np.concatenate(
        [
            rng.uniform((-1, -1), (W, H), (20000, 2)),
            [[0, 0], [0.5, H - 2], [W - 2, 3.25], [W - 1.5, H - 1.5], [2.5, 240.0]],
        ]
    ).astype(np.float32)
    z, ok = depth_at(d, uv, cfg)
    z_ref, ok_ref = bilinear_depth(refine_depth(d, cfg), uv, cfg)
    assert ok_ref.mean() > 0.5  # the comparison covers many valid taps
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_array_equal(z, z_ref)
    # points away from the borders take the tracker's fast path; the same values
    inner = (uv[:, 0] > 8) & (uv[:, 0] < W - 8) & (uv[:, 1] > 8) & (uv[:, 1] < H - 8)
    z_in, ok_in = depth_at(d, uv[inner], cfg)
    np.testing.assert_array_equal(z_in, z_ref[inner])
    np.testing.assert_array_equal(ok_in, ok_ref[inner])


# ----------------------------------------------------------------------------- bad input


def test_different_sizes_give_bad_input(tex0):
    small = bgr(tex0)[: H // 2, : W // 2]
    flow = grid_flow(bgr(tex0), plane(2.0), small, np.full((H // 2, W // 2), 2.0, np.float32), K)
    check_shapes(flow, grid_pixels(H, W, CFG.cell).shape[0])
    assert flow.status == Status.BAD_INPUT and not flow.valid.any()
    none = grid_flow(bgr(tex0), plane(2.0), None, None, K)
    assert none.status == Status.BAD_INPUT and not none.valid.any()
    raw = grid_flow(bgr(tex0), plane(2.0), bgr(tex0), np.full((H, W), 10000, np.uint16), K)
    assert raw.status == Status.BAD_INPUT  # integer depth: units unknown, contract is metres


def test_zero_depth_all_invalid_without_nan(tex0):
    A = np.array([[1, 0, 1.0], [0, 1, 0.5]])
    flow = grid_flow(bgr(tex0), plane(0.0), bgr(warp(tex0, A)), plane(0.0), K)
    check_shapes(flow, grid_pixels(H, W, CFG.cell).shape[0])
    assert flow.status == Status.OK and not flow.valid.any()


def test_textureless_frame_mostly_invalid():
    flat = np.full((H, W), 128.0, np.float32)
    flow = grid_flow(bgr(flat), plane(2.0), bgr(flat), plane(2.0), K)
    check_shapes(flow, grid_pixels(H, W, CFG.cell).shape[0])
    assert flow.status == Status.OK and flow.valid.mean() < 0.05


# ----------------------------------------------------------------------------- sequences


class _Frame(NamedTuple):
    index: int
    timestamp: float
    bgr: np.ndarray
    depth: np.ndarray
    mask: None = None


class _Seq:
    """A tiny in-memory sequence: a texture panning right by 1.5 px per frame; frames in
    ``bad`` raise OSError (unreadable), frames in ``black`` are black (readable, useless)."""

    name = "pan"
    intrinsics = K
    height, width = H, W

    def __init__(self, tex, n=4, bad=(), black=()):
        self.tex, self.n, self.bad, self.black = tex, n, bad, black

    def __len__(self):
        return self.n

    def __getitem__(self, i):
        if i in self.bad:
            raise OSError(f"frame {i} unreadable")
        img = warp(self.tex, np.array([[1, 0, 1.5 * i], [0, 1, 0]], np.float64))
        if i in self.black:
            img = np.zeros_like(img)
        return _Frame(i, i / 30, bgr(img), plane(2.0))


def _median_shift(flows, k):
    """Median x displacement (px) of pair k's valid interior tracks."""
    v = flows.valid[k] & interior(flows.uv_prev[k])
    return np.median((flows.uv_cur - flows.uv_prev)[k][v][:, 0])


def test_flows_for_sequence_drops_an_unreadable_frame_and_pairs_across_it(tex0):
    calls = []
    res = sequence_flows(_Seq(tex0, 5, bad=(2,)), CFG, progress=lambda d, t: calls.append((d, t)))
    flows = res.flows
    n = grid_pixels(H, W, CFG.cell).shape[0]
    assert flows.valid.shape == (3, n) and flows.pts_cur.shape == (3, n, 3)
    np.testing.assert_array_equal(res.frames, [0, 1, 3, 4])
    assert list(res.dropped) == [2] and "frame 2 unreadable" in res.dropped[2]
    np.testing.assert_array_equal(flows.status, [0, 0, 0])  # the device sees no bad pair
    assert calls[-1] == (4, 4)
    keep = interior(flows.uv_prev[0])
    # pair 1 spans the unreadable frame 2 (frames 1 -> 3): 3 px; tolerance 0.1 px (median)
    for k, shift in ((0, 1.5), (1, 3.0), (2, 1.5)):
        assert (flows.valid[k] & keep).mean() > 0.5 * keep.mean()
        assert abs(_median_shift(flows, k) - shift) < 0.1
    # the stacked flow alone, as before
    np.testing.assert_array_equal(flows_for_sequence(_Seq(tex0, 5, bad=(2,)), CFG).valid,
                                  flows.valid)
    # frames read ahead on other threads (the default) or each in its turn: the same bits
    inline = sequence_flows(_Seq(tex0, 5, bad=(2,)), CFG, ahead=0)
    assert inline.dropped == res.dropped
    for a, b in zip(inline.flows, flows, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_black_frame_is_dropped_and_the_next_pairs_with_the_last_good_one(tex0):
    res = sequence_flows(_Seq(tex0, 5, black=(2,)), CFG)
    np.testing.assert_array_equal(res.frames, [0, 1, 3, 4])
    assert "too few valid flow vectors" in res.dropped[2]
    assert abs(_median_shift(res.flows, 1) - 3.0) < 0.1  # 1 -> 3; tolerance 0.1 px


def test_a_black_first_frame_starts_no_hole_in_the_chain(tex0):
    """Nothing tells whether the first frame or the second is the useless one: the pair
    goes to the device (which skips it) and the chain goes on from frame 1."""
    res = sequence_flows(_Seq(tex0, 4, black=(0,)), CFG)
    np.testing.assert_array_equal(res.frames, [0, 1, 2, 3])
    assert res.dropped == {}
    assert res.flows.valid[0].sum() < min_valid_flow(CFG) <= res.flows.valid[1].sum()


def test_after_max_dropped_in_a_row_the_chain_goes_on_from_the_current_frame(tex0):
    # frames 2..5 black: 2 and 3 are dropped (max_dropped 2), 4 restarts the chain (its pair
    # with frame 1 goes to the device, which skips it), 5 pairs with 4 (both black: kept, as
    # 4 has not been in a good pair), 6 pairs with 5 (too few vectors: a restart again)
    res = sequence_flows(_Seq(tex0, 8, black=(2, 3, 4, 5)), CFG, max_dropped=2)
    np.testing.assert_array_equal(res.frames, [0, 1, 4, 5, 6, 7])
    assert sorted(res.dropped) == [2, 3]
    assert abs(_median_shift(res.flows, 4) - 1.5) < 0.1  # 6 -> 7; tolerance 0.1 px


def test_tracker_drop_last_pairs_the_next_frame_with_the_one_before(tex0):
    tracker = GridFlowTracker(K, CFG, height=H, width=W)
    frames = [bgr(warp(tex0, np.array([[1, 0, 1.5 * i], [0, 1, 0]], np.float64)))
              for i in range(3)]
    tracker.push(frames[0], plane(2.0))
    tracker.push(frames[1], plane(2.0))
    tracker.drop_last()
    flow = tracker.push(frames[2], plane(2.0))
    direct = grid_flow(frames[0], plane(2.0), frames[2], plane(2.0), K, CFG)
    for x, y in zip(flow, direct):  # the same as tracking frame 0 -> 2 directly
        np.testing.assert_array_equal(x, y)


def test_streaming_matches_function_form(tex0):
    A = np.array([[1, 0, 0.6], [0, 1, -0.4]])
    cur = bgr(warp(tex0, A))
    tracker = GridFlowTracker(K, CFG, height=H, width=W)
    assert tracker.push(bgr(tex0), plane(2.0)) is None
    a = tracker.push(cur, plane(2.0))
    b = grid_flow(bgr(tex0), plane(2.0), cur, plane(2.0), K, CFG)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_helper_thread_gives_the_same_flow_frame_after_frame(tex0):
    """Each frame's grid depth is refined on the helper thread while the pair before it is
    tracked; over a sequence every pair must pair the right frames' depths."""
    frames = []
    for i in range(5):
        A = np.array([[1, 0, 0.7 * i], [0, 1, -0.3 * i]])
        frames.append((bgr(warp(tex0, A)), rough_depth(10 + i, holes=60)))
    flows = {}
    before = cv2.getNumThreads()
    try:
        for threads in (2, 1):
            cv2.setNumThreads(threads)
            tracker = GridFlowTracker(K, CFG, height=H, width=W)
            flows[threads] = [tracker.push(b, d) for b, d in frames][1:]
    finally:
        cv2.setNumThreads(before)
    for a, b in zip(flows[2], flows[1]):
        assert a.valid.mean() > 0.3
        for name, x, y in zip(GridFlow._fields, a, b):
            np.testing.assert_array_equal(x, y, err_msg=name)


@pytest.mark.parametrize("shift, gain", [(2.0, 1.0), (20.0, 2.0)])
def test_fast_motion_takes_one_pyramid_level_more(shift, gain):
    """A pan of 20 px a frame is beyond two pyramid levels with a 9 px window: a third of
    the grid tracked in the first pair; once that pair's median track (20 px) exceeds
    lk_fast_px, the next pairs use a third level and track nearly all. A slow pan keeps
    the configured levels."""
    big = texture(5, H, W + 80)
    tracker = GridFlowTracker(K, CFG, height=H, width=W)
    valid = []
    for i in range(3):
        x = int(60 - i * shift)
        flow = tracker.push(bgr(big[:, x : x + W]), plane(2.0))
        if flow is not None:
            valid.append(int(flow.valid.sum()))
            np.testing.assert_allclose(np.median((flow.uv_cur - flow.uv_prev)[flow.valid, 0]),
                                       shift, atol=0.05)  # tol px: LK eps 0.03
    assert valid[1] >= gain * valid[0], valid
    assert valid[1] > 0.9 * tracker.n


def reference_flow(b0, d0, b1, d1, cam, cfg) -> GridFlow:
    """The checks of thesis 2.2 applied to every grid point, each on the whole image:
    LK both ways on all points, whole-image depth refinement, all patches. The grid points
    are the cells' centres or, with ``cfg.textured_points``, where ``textured_points`` puts
    them on the first image."""
    from jaxvo.host.frontend.flow import textured_points

    g0, g1 = (cv2.cvtColor(b, cv2.COLOR_BGR2GRAY) for b in (b0, b1))
    h, w = g0.shape
    uv0 = grid_pixels(h, w, cfg.cell)
    if cfg.textured_points:
        uv0 = textured_points(g0, d0, uv0, (h // cfg.cell, w // cfg.cell), cfg.cell,
                              cfg.depth_jump)
    lk = {
        "winSize": (cfg.lk_window, cfg.lk_window),
        "maxLevel": cfg.lk_levels,
        "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.lk_iters, cfg.lk_eps),
    }
    uv1, st1, _ = cv2.calcOpticalFlowPyrLK(g0, g1, uv0, None, **lk)
    back, st0, _ = cv2.calcOpticalFlowPyrLK(g1, g0, uv1, None, **lk)
    ok = (st1[:, 0] == 1) & (st0[:, 0] == 1) & np.isfinite(uv1).all(axis=1)
    uv1 = np.where(ok[:, None], uv1, uv0)
    ok &= (uv1 >= 0).all(axis=1) & (uv1[:, 0] <= w - 1) & (uv1[:, 1] <= h - 1)
    fb = np.hypot(*(np.where(ok[:, None], back, uv0) - uv0).T).astype(np.float32)
    ok &= fb <= cfg.fb_max
    sim = patch_correlation(sample_patches(g0, uv0, cfg.patch), sample_patches(g1, uv1, cfg.patch))
    ok &= sim >= cfg.min_similarity
    z0, ok0 = bilinear_depth(refine_depth(d0, cfg), uv0, cfg)
    z1, ok1 = bilinear_depth(refine_depth(d1, cfg), uv1, cfg)
    ok &= ok0 & ok1
    keep = ok[:, None]
    slope1 = bilinear_slope(refine_depth(d1, cfg), uv1, cfg)
    return GridFlow(
        pts_prev=np.where(keep, backproject(uv0, z0, cam), 0).astype(np.float32),
        pts_cur=np.where(keep, backproject(uv1, z1, cam), 0).astype(np.float32),
        uv_prev=uv0,
        uv_cur=np.where(keep, uv1, uv0).astype(np.float32),
        valid=ok,
        status=np.int32(Status.OK),
        focal=np.float32(cam.focal),
        depth_prev=np.where(ok0, z0, 0).astype(np.float32),
        camera=np.array([cam.fx, cam.fy, cam.cx, cam.cy], np.float32),
        fb_error=np.where(ok, fb, 0).astype(np.float32),
        depth_slope=np.where(ok, slope1, 0).astype(np.float32),
    )


@pytest.fixture(params=["helper thread", "one thread"])
def opencv_threads(request):
    """The tracker's depth work beside LK (OpenCV on several threads), or all of it on the
    calling thread (``cv2.setNumThreads(1)``)."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(max(before, 2) if request.param == "helper thread" else 1)
    yield request.param
    cv2.setNumThreads(before)


def test_tracker_equals_checking_every_point(tex0, opencv_threads):
    # The tracker follows only the points that can still pass (LK tracks each point on
    # its own) and refines depth only where it reads it: the same flow bit for bit, with
    # its depth lookups on the helper thread or inline.
    A = cv2.getRotationMatrix2D((W / 2, H / 2), 0.8, 1.01)
    A[:, 2] += (2.1, -1.3)
    cur = warp(tex0, A)
    cur[100:180, 200:300] = texture(9)[100:180, 200:300]  # fails forward-backward
    d0, d1 = rough_depth(1, holes=100), rough_depth(2, holes=100)
    flow = grid_flow(bgr(tex0), d0, bgr(cur), d1, K, CFG)
    ref = reference_flow(bgr(tex0), d0, bgr(cur), d1, K, CFG)
    assert 0.3 < ref.valid.mean() < 0.85  # the checks rejected many points
    for name, a, b in zip(GridFlow._fields, flow, ref):
        np.testing.assert_array_equal(a, b, err_msg=name)


# ----------------------------------------------------------------------------- real data


def _real_pair(name: str, i: int):
    root = data_root() / name
    if not (root / "associations.txt").is_file():
        pytest.skip(f"real data {root} not present (set JAXVO_DATA to the shared data folder)")
    cam = read_camera_file(root / "camera.txt")
    rows = [r.split() for r in (root / "associations.txt").read_text().splitlines()]
    rows = [r for r in rows if r and not r[0].startswith("#")]
    frames = []
    for r in rows[i : i + 2]:
        img = cv2.imread(str(root / r[1]), cv2.IMREAD_COLOR)
        depth = cv2.imread(str(root / r[3]), cv2.IMREAD_UNCHANGED).astype(np.float32)
        frames += [img, depth / np.float32(cam.depth_scale)]
    return cam, frames


@pytest.mark.parametrize(
    "name, min_valid",
    [
        # static scene, good depth: a majority valid
        ("7scenes_static_0000_0299", 0.5),
        # two people walking, motion blur, ~40 % of the depth missing: a fifth still valid
        ("tum_fr3_walking_halfsphere_50", 0.15),
    ],
)
def test_real_pair(name, min_valid):
    cam, (b0, d0, b1, d1) = _real_pair(name, 10)
    flow = grid_flow(b0, d0, b1, d1, cam, CFG)
    check_shapes(flow, grid_pixels(*b0.shape[:2], CFG.cell).shape[0])
    assert flow.status == Status.OK
    assert flow.valid.mean() > min_valid
    v = flow.valid
    assert (flow.pts_prev[v, 2] >= CFG.depth_min).all() and (
        flow.pts_cur[v, 2] <= CFG.depth_max
    ).all()
    # 30 Hz hand-held motion: tracked displacements stay small (tolerance 40 px)
    assert np.abs(flow.uv_cur[v] - flow.uv_prev[v]).max() < 40
    ref = reference_flow(b0, d0, b1, d1, cam, CFG)
    for field, a, b in zip(GridFlow._fields, flow, ref):
        np.testing.assert_array_equal(a, b, err_msg=field)  # as checking every point


def test_textured_points_take_each_cells_most_trackable_pixel_with_depth():
    """One point per cell: on a flat image every cell keeps its centre; a single corner in a
    cell draws that cell's point to within 2 px of it (the half-size image's resolution),
    unless the corner has no depth reading; neighbouring flat cells keep their centres."""
    from jaxvo.host.frontend.flow import textured_points

    cell, grid = 16, (H // 16, W // 16)
    centres = grid_pixels(H, W, cell)
    flat = np.full((H, W), 120, np.uint8)
    depth = np.ones((H, W), np.float32)
    np.testing.assert_array_equal(textured_points(flat, depth, centres, grid, cell, 0.05), centres)

    img = flat.copy()
    img[100:, 200:] = 40  # one corner at (200, 100): cell row 6, column 12
    uv = textured_points(img, depth, centres, grid, cell, 0.05)
    i = 6 * grid[1] + 12
    assert np.hypot(*(uv[i] - [200, 100])) <= 3.0  # pixels: a half-size pixel's diagonal and the blur
    # the cells far from the edges keep their centres
    np.testing.assert_array_equal(uv[:grid[1] * 4], centres[:grid[1] * 4])

    no_depth = depth.copy()
    no_depth[96:112, 192:208] = 0.0  # the corner's cell has no depth reading at all
    uv = textured_points(img, no_depth, centres, grid, cell, 0.05)
    np.testing.assert_array_equal(uv[i], centres[i])


def test_textured_points_give_more_valid_tracks_on_a_half_flat_image(tex0):
    """Cells that are flat but for a textured part: a point on the texture tracks where the
    cell's centre on the flat part does not."""
    img = tex0.copy()
    img[:, ::32] = 128.0  # keep the texture only in alternate 16-px columns of cells
    for c0 in range(0, W, 32):
        img[:, c0:c0 + 12] = 128.0
    A = np.float32([[1, 0, 2.0], [0, 1, 1.0]])
    nxt = warp(img, A)
    depth = np.full((H, W), 2.0, np.float32)
    counts = {}
    for textured in (False, True):
        cfg = dataclasses.replace(CFG, textured_points=textured)
        f = grid_flow(bgr(img), depth, bgr(nxt), depth, K, cfg)
        counts[textured] = int(np.sum(f.valid))
        d = (f.uv_cur - f.uv_prev)[f.valid]
        np.testing.assert_allclose(np.median(d, axis=0), [2.0, 1.0], atol=0.1)  # pixels
    assert counts[True] >= 1.5 * counts[False]
