"""Tests of jaxvo.synth.scenes: determinism, exact ground truth, masks, bad input, file round trip."""

from __future__ import annotations

import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import backproject, project
from jaxvo.host.readers.io import TumSequence, data_root
from jaxvo.synth import scenes as synth
from jaxvo.trajectory import read_trajectory

IDEAL = synth.SensorOptions.ideal()


def _rays(K, uv):
    return np.stack([(uv[:, 0] - K.cx) / K.fx, (uv[:, 1] - K.cy) / K.fy, np.ones(len(uv))], -1)


def _box_hit(T_w_b, half, T_w_c, rays):
    """Depth of the first hit of camera rays (z = 1) on a box from outside, float64, inf = miss."""
    T_b_c = np.linalg.inv(T_w_b) @ T_w_c
    o = T_b_c[:3, 3]
    d = rays @ T_b_c[:3, :3].T
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / d
        t2 = (half - o) / d
    t_in = np.nanmax(np.minimum(t1, t2), axis=1)
    t_out = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((t_out >= t_in) & (t_in > 0), t_in, np.inf)


def test_same_seed_same_bytes_and_different_seeds_differ():
    # Seeds 0 and 1 throughout the tests: each new seed builds a texture atlas (~1 s).
    a = synth.make_sequence("fixed_camera_2", frames=4, seed=1)
    b = synth.make_sequence("fixed_camera_2", frames=4, seed=1)
    c = synth.make_sequence("fixed_camera_2", frames=4, seed=0)
    fa, fb, fc = a[3], b[3], c[3]
    assert fa.bgr.tobytes() == fb.bgr.tobytes()
    assert fa.depth.tobytes() == fb.depth.tobytes()
    assert fa.mask.tobytes() == fb.mask.tobytes()
    np.testing.assert_array_equal(a.groundtruth.poses, b.groundtruth.poses)
    assert fa.bgr.tobytes() != fc.bgr.tobytes()
    assert not np.array_equal(a.object_trajectories[1].poses, c.object_trajectories[1].poses)


def test_frame_contract():
    seq = synth.make_sequence("handheld_slow", frames=3, seed=0)
    assert len(seq) == 3 and (seq.height, seq.width) == (480, 640)
    assert seq.intrinsics.fx == 525.0 and seq.intrinsics.depth_scale == synth.DEPTH_SCALE
    np.testing.assert_allclose(seq.timestamps, np.arange(3) / 30.0, atol=1e-12)
    f = seq[-1]
    assert f.index == 2 and f.bgr.dtype == np.uint8 and f.bgr.shape == (480, 640, 3)
    assert f.depth.dtype == np.float32 and f.mask.dtype == np.uint8
    valid = f.depth > 0
    # Default sensor: readings only within 0.5 - 3.5 m (noise may push a hair beyond).
    assert f.depth[valid].min() >= 0.5 and f.depth[valid].max() <= 3.5
    assert 0.0 < 1 - valid.mean() < 0.5
    assert len(list(seq)) == 3
    with pytest.raises(IndexError):
        seq[3]


def test_static_pixels_reproject_with_true_camera_motion():
    """Static pixels of frame i, moved by the true camera motion, land on frame i+1's surface.

    Tolerance: 0.5 mm in depth (along the ray through the projected sub-pixel position, with
    inverse depth interpolated bilinearly, which is exact on a plane) for 97% of the points;
    the rest are occluded in frame i+1 (predicted behind the observed surface), never in
    front of it by more than 0.5 mm. The same points land within 0.5 px when mapped back.
    """
    seq = synth.make_sequence("handheld_fast", frames=6, seed=1, options=IDEAL)
    K = seq.intrinsics
    f0, f1 = seq[4], seq[5]
    T0, T1 = seq.groundtruth.poses[4], seq.groundtruth.poses[5]
    v, u = np.mgrid[2:478:3, 2:638:3]
    uv = np.stack([u.ravel(), v.ravel()], -1).astype(np.float64)
    z0 = f0.depth[uv[:, 1].astype(int), uv[:, 0].astype(int)].astype(np.float64)
    static = f0.mask[uv[:, 1].astype(int), uv[:, 0].astype(int)] == 0
    P0 = backproject(uv, z0, K)
    T_1_0 = np.linalg.inv(T1) @ T0
    P1 = P0 @ T_1_0[:3, :3].T + T_1_0[:3, 3]
    uv1 = project(P1, K)
    inside = (uv1[:, 0] >= 0) & (uv1[:, 0] < 639) & (uv1[:, 1] >= 0) & (uv1[:, 1] < 479)
    keep = static & inside & (P1[:, 2] > 0.1)
    uv1, P1, uv, z0 = uv1[keep], P1[keep], uv[keep], z0[keep]
    x0 = np.floor(uv1[:, 0]).astype(int)
    y0 = np.floor(uv1[:, 1]).astype(int)
    inv = 1.0 / f1.depth.astype(np.float64)
    i00, i01 = inv[y0, x0], inv[y0, x0 + 1]
    i10, i11 = inv[y0 + 1, x0], inv[y0 + 1, x0 + 1]
    m = f1.mask
    static1 = (m[y0, x0] == 0) & (m[y0, x0 + 1] == 0) & (m[y0 + 1, x0] == 0) & (
        m[y0 + 1, x0 + 1] == 0)
    planar = np.abs(i00 + i11 - i01 - i10) < 1e-5 * i00  # one face under the 2x2 cell
    ok = static1 & planar
    fx, fy = uv1[:, 0] - x0, uv1[:, 1] - y0
    inv_interp = (i00 * (1 - fx) + i01 * fx) * (1 - fy) + (i10 * (1 - fx) + i11 * fx) * fy
    err = P1[:, 2] - 1.0 / inv_interp  # > 0: the point is behind what frame i+1 sees
    err, uv1_ok, uv0_ok = err[ok], uv1[ok], uv[ok]
    assert len(err) > 5000
    close = np.abs(err) < 5e-4
    assert close.mean() > 0.97, f"only {close.mean():.3f} within 0.5 mm"
    assert np.mean(err < -5e-4) < 1e-3  # never seen through a surface
    # Back from frame i+1 to frame i: the interpolated surface point lands on the pixel.
    Q1 = backproject(uv1_ok[close], 1.0 / inv_interp[ok][close], K)
    T_0_1 = np.linalg.inv(T_1_0)
    back = project(Q1 @ T_0_1[:3, :3].T + T_0_1[:3, 3], K)
    assert np.abs(back - uv0_ok[close]).max() < 0.5


def test_mask_is_exactly_where_a_moving_object_is_nearest():
    seq = synth.make_sequence("fixed_camera_2", frames=21, seed=1, options=IDEAL)
    i = 20  # both boxes in view, the near one partly in front of the far one
    f = seq[i]
    s = seq.render(i, objects=False)
    assert s.mask.max() == 0
    bg = f.mask == 0
    assert bg.mean() < 0.99 and f.mask.max() == 2
    # Where nothing moves in front, the frame is the static scene, bit for bit.
    np.testing.assert_array_equal(f.depth[bg], s.depth[bg])
    np.testing.assert_array_equal(f.bgr[bg], s.bgr[bg])
    assert np.all(f.depth[~bg] < s.depth[~bg])
    # Independent reference: float64 ray-box intersection of every object on a pixel grid.
    K = seq.intrinsics
    v, u = np.mgrid[1:480:4, 1:640:4]
    uv = np.stack([u.ravel(), v.ravel()], -1).astype(np.float64)
    rays = _rays(K, uv)
    T_w_c = seq.groundtruth.poses[i]
    hits = [np.full(len(uv), np.inf)]
    hits[0] = s.depth[v.ravel(), u.ravel()].astype(np.float64)
    for k, spec in enumerate(seq.scenario.objects, start=1):
        T_w_o = seq.object_trajectories[k].poses[i]
        hits.append(_box_hit(T_w_o, np.array(spec.size) / 2, T_w_c, rays))
    hits = np.stack(hits)
    expect = np.argmin(hits, axis=0)
    srt = np.sort(hits, axis=0)
    clear = srt[1] - srt[0] > 1e-4  # leave out exact ties along silhouettes
    got = f.mask[v.ravel(), u.ravel()]
    np.testing.assert_array_equal(got[clear], expect[clear])
    near = np.min(hits, axis=0)
    np.testing.assert_allclose(f.depth[v.ravel(), u.ravel()], near, rtol=0, atol=2e-5)


# the scenes built for the failures of issue 18: their objects leave the view by design
_LEAVE_VIEW = {"enter_leave", "three_boxes"}


def test_objects_move_more_than_a_pixel_per_frame_mostly():
    """Every object's centre moves more than a pixel a frame (median over 90 frames) and
    stays in view in more than 80 % of them, but where a scene is made to leave the view:
    ``three_boxes`` keeps each box in view more than half the time, and ``enter_leave``'s
    boxes are in view and out of it in turn."""
    for name, sc in synth.SCENARIOS.items():
        if not sc.objects:
            continue
        seq = synth.make_sequence(name, frames=90, seed=0)
        K = seq.intrinsics
        cams = seq.groundtruth.poses
        for k, traj in seq.object_trajectories.items():
            centres = np.einsum("nij,nj->ni", np.linalg.inv(cams), np.c_[
                traj.poses[:, :3, 3], np.ones(len(cams))])[:, :3]
            px = project(centres, K)
            step = np.linalg.norm(np.diff(px, axis=0), axis=1)
            assert np.median(step) > 1.0, (name, k, np.median(step))
            in_view = (px[:, 0] > 0) & (px[:, 0] < 640) & (px[:, 1] > 0) & (px[:, 1] < 480)
            if name == "enter_leave":
                assert 0.2 < in_view.mean() < 0.9, (name, k, in_view.mean())
            elif name in _LEAVE_VIEW:
                assert in_view.mean() > 0.5, (name, k, in_view.mean())
            else:
                assert in_view.mean() > 0.8, (name, k, in_view.mean())


def test_an_object_stands_still_during_its_stops():
    """``stop_start``'s first box holds its world pose exactly through each stop (1.0-2.3 s
    and 3.3-4.3 s from the first frame) and moves between them; the other box never stops."""
    seq = synth.make_sequence("stop_start", frames=150, seed=0)
    t = seq.timestamps - seq.timestamps[0]
    for k, moves_always in ((1, False), (2, True)):
        poses = seq.object_trajectories[k].poses
        moved = np.abs(np.diff(poses, axis=0)).max(axis=(1, 2)) > 1e-9
        # a step from frame i to i + 1 lies inside a stop when both instants do
        inside = np.zeros(len(t) - 1, bool)
        if not moves_always:
            for a, b in synth.SCENARIOS["stop_start"].objects[0].stops:
                inside |= (t[:-1] >= a) & (t[1:] <= b)
            assert inside.sum() >= 50
        np.testing.assert_array_equal(moved, ~inside, err_msg=str(k))


def test_sensor_effects():
    near = synth.make_sequence("close_approach", frames=61, seed=0)
    f = near[60]  # the box is at its closest: inside the 0.5 m minimum range
    obj = f.mask == 1
    assert obj.mean() > 0.2 and np.mean(f.depth[obj] == 0) > 0.5
    ideal = synth.make_sequence("close_approach", frames=61, seed=0, options=IDEAL)[60]
    valid = f.depth > 0
    rel = np.abs(f.depth[valid] - ideal.depth[valid]) / ideal.depth[valid] ** 2
    assert 2e-4 < np.std(rel) < 5e-3  # sigma = 1.425e-3 z^2
    assert 0.5 < np.std(f.bgr.astype(float) - ideal.bgr) < 4.0  # colour sigma 2 levels
    blur = synth.SensorOptions(
        depth_noise=False, edge_holes=False, depth_range=False, colour_noise=False,
        motion_blur=True, exposure_change=True)
    fb = synth.make_sequence("close_approach", frames=61, seed=0, options=blur)[60]
    assert np.array_equal(fb.depth, ideal.depth) and not np.array_equal(fb.bgr, ideal.bgr)


def test_bad_input_is_one_line_input_error():
    with pytest.raises(InputError, match="fixed_camera_1.*static") as e:
        synth.make_sequence("nope")
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="frames"):
        synth.make_sequence("static", frames=0)
    huge = synth.ObjectSpec((5.0, 5.0, 5.0), (0, 0, 2), (0, 0, 0), (1, 1, 1))
    with pytest.raises(InputError, match="does not fit"):
        synth.make_sequence(synth.Scenario("huge", "", camera="fixed", objects=(huge,)))
    around = synth.ObjectSpec((0.5, 0.5, 0.5), (0, 0, 0.1), (0, 0, 0), (1, 1, 1))
    with pytest.raises(InputError, match="inside object 1"):
        synth.make_sequence(synth.Scenario("around", "", camera="fixed", objects=(around,)),
                            frames=2)


def test_write_sequence_round_trip(tmp_path):
    seq = synth.make_sequence("fixed_camera_1", frames=3, seed=0)
    done = []
    out = synth.write_sequence(seq, tmp_path / "seq", progress=lambda i, n: done.append(i))
    assert done == [1, 2, 3]
    back = TumSequence(out)
    assert len(back) == 3 and back.intrinsics == seq.intrinsics
    for i in range(3):
        a, b = seq[i], back[i]
        np.testing.assert_array_equal(a.bgr, b.bgr)
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_allclose(b.depth, a.depth, atol=0.5 / synth.DEPTH_SCALE + 1e-7)
        assert (b.depth == 0).sum() == (a.depth == 0).sum()
    np.testing.assert_allclose(back.groundtruth.poses, seq.groundtruth.poses, atol=1e-8)
    rows = np.loadtxt(out / "objects.txt")
    assert rows.shape == (3, 9) and np.all(rows[:, 1] == 1)
    np.testing.assert_allclose(rows[:, 2:5], seq.object_trajectories[1].poses[:, :3, 3],
                               atol=1e-8)
    gt = read_trajectory(out / "groundtruth.txt")
    np.testing.assert_allclose(gt.timestamps, seq.timestamps, atol=1e-6)


def test_cli_synth(tmp_path, capsys):
    from jaxvo.cli.main import main
    from jaxvo.cli.synth import SCENARIO_NAMES

    assert SCENARIO_NAMES == tuple(synth.SCENARIOS)

    assert main(["synth", "static", str(tmp_path / "s"), "--frames", "2", "--seed", "1"]) == 0
    assert len(TumSequence(tmp_path / "s")) == 2
    assert main(["synth", "nope", str(tmp_path / "x")]) == 2
    assert "unknown scenario" in capsys.readouterr().err


def test_render_does_not_retrace_across_frames():
    from jaxvo.synth.render import cast

    seq = synth.make_sequence("handheld_slow", frames=4, seed=0)
    seq[0]
    n = cast._cache_size()
    seq[1], seq[2], seq[3]
    assert cast._cache_size() == n


SEVEN = data_root() / "7scenes_static_0000_0299"


@pytest.mark.skipif(not SEVEN.is_dir(), reason=f"real data not found at {SEVEN}")
def test_composite_into_real_sequence():
    seq = synth.composite_sequence(SEVEN, "fixed_camera_1", frames=40, seed=0, options=IDEAL)
    real = TumSequence(SEVEN)
    assert len(seq) == 40 and seq.intrinsics.fx == real.intrinsics.fx
    np.testing.assert_array_equal(seq.groundtruth.poses, real.groundtruth.poses[:40])
    i = 20
    f, r = seq[i], real[i]
    obj = f.mask > 0
    assert 0.01 < obj.mean() < 0.6
    np.testing.assert_array_equal(f.depth[~obj], r.depth[~obj])
    np.testing.assert_array_equal(f.bgr[~obj], r.bgr[~obj])
    assert np.all((r.depth[obj] == 0) | (f.depth[obj] < r.depth[obj]))


def test_a_carried_box_stays_on_its_path_in_the_camera_frame():
    """carried_*: the box's path is in the camera's own frame (follow 0), so however the
    camera moves, the box's centre in the camera stays within its path's amplitude around
    its centre (0.14, 0.04, 0.03 m around (0, 0, 0.7)); a box left where it was would be
    left behind by the camera's 0.3 m over these 2 s."""
    seq = synth.make_sequence("carried_50", frames=60, seed=2)
    T_c = seq.groundtruth.poses
    T_o = seq.object_trajectories[1].poses
    offset = (np.linalg.inv(T_c) @ T_o)[:, :3, 3] - np.array([0.0, 0.0, 0.7])
    assert np.all(np.abs(offset) <= np.array([0.14, 0.04, 0.03]) + 1e-6)
    travelled = np.linalg.norm(T_c[-1, :3, 3] - T_c[0, :3, 3])
    left_behind = (np.linalg.inv(T_c[-1]) @ T_o[0])[:3, 3] - np.array([0.0, 0.0, 0.7])
    assert travelled > 0.1 and np.any(np.abs(left_behind) > np.array([0.14, 0.04, 0.03]))
