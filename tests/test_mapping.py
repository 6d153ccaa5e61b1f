"""The static map (`jaxvo.host.writers.mapping`): voxel averaging against a plain-Python reference,
back-projection against the pinhole model, the masks leaving the movers out (exact masks
of a synthetic scene), poses matched to frames, and the PLY file read back."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.host.writers.mapping import (
    frame_points,
    fuse_maps,
    map_picture,
    matched_poses,
    voxel_filter,
    write_ply,
)
from jaxvo.synth.scenes import make_sequence
from jaxvo.trajectory import Trajectory

K = Intrinsics(500.0, 500.0, 31.5, 23.5, 5000.0)


def test_voxel_filter_averages_each_cube_as_a_plain_loop_does():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.3, 0.3, (2000, 3)).astype(np.float32)
    col = rng.integers(0, 256, (2000, 3)).astype(np.uint8)
    got = voxel_filter(pts, col, 0.1)
    groups = defaultdict(list)
    for i, p in enumerate(pts.astype(np.float64)):
        groups[tuple(np.floor(p / 0.1).astype(int))].append(i)
    assert len(got.points) == len(groups)
    ref = {k: (pts[v].astype(np.float64).mean(0), col[v].mean(0), len(v))
           for k, v in groups.items()}
    for p, c, n in zip(got.points, got.colours, got.counts):
        rp, rc, rn = min(ref.values(), key=lambda r: np.abs(r[0] - p).sum())
        np.testing.assert_allclose(p, rp, atol=1e-6)
        np.testing.assert_allclose(c, rc, atol=0.5)  # rounded to uint8
        assert n == rn


def test_frame_points_back_project_a_plane_through_the_pose():
    depth = np.full((48, 64), 2.0, np.float32)
    depth[:, :8] = 0  # no reading
    depth[:, 60:] = 9.0  # beyond max_depth
    bgr = np.zeros((48, 64, 3), np.uint8)
    bgr[..., 2] = 200  # red in BGR
    T = np.eye(4)
    T[:3, 3] = [1.0, -2.0, 0.5]
    pts, col, px = frame_points(bgr, depth, K, T, stride=2, max_depth=4.0)
    assert len(pts) == 24 * (32 - 4 - 2)  # every other pixel, less the holes and the far strip
    np.testing.assert_allclose(pts[:, 2], 2.5, atol=1e-6)
    np.testing.assert_allclose(pts[:, 0], (px[:, 0] - K.cx) / K.fx * 2.0 + 1.0, atol=1e-5)
    np.testing.assert_allclose(pts[:, 1], (px[:, 1] - K.cy) / K.fy * 2.0 - 2.0, atol=1e-5)
    assert np.all(col == [200, 0, 0])  # RGB


def test_depth_edges_are_left_out_when_asked():
    depth = np.full((48, 64), 2.0, np.float32)
    depth[:, 32:] = 3.0  # a step
    bgr = np.zeros((48, 64, 3), np.uint8)
    all_px = frame_points(bgr, depth, K, np.eye(4), stride=1)[2]
    kept = frame_points(bgr, depth, K, np.eye(4), stride=1, edge=0.05)[2]
    assert len(all_px) == 48 * 64
    assert set(np.unique(kept[:, 0])) == set(range(64)) - {31, 32}  # the two columns at the step


def _on_objects(pmap, seq, poses, tol=0.03):
    """Map points that lie on a moving object's surface in some frame (exact masks)."""
    hit = np.zeros(len(pmap.points), bool)
    K = seq.intrinsics
    for i, T in poses:
        f = seq[i]
        Ti = np.linalg.inv(T)
        c = pmap.points @ Ti[:3, :3].T + Ti[:3, 3]
        z = np.where(c[:, 2] > 0.05, c[:, 2], np.inf)
        u = np.rint(K.fx * c[:, 0] / z + K.cx).astype(int)
        v = np.rint(K.fy * c[:, 1] / z + K.cy).astype(int)
        idx = np.nonzero((u >= 0) & (u < seq.width) & (v >= 0) & (v < seq.height))[0]
        on = (f.mask[v[idx], u[idx]] > 0) & (np.abs(f.depth[v[idx], u[idx]] - z[idx]) < tol)
        hit[idx[on]] = True
    return int(hit.sum())


def test_the_static_map_leaves_the_movers_out_with_exact_masks():
    seq = make_sequence("fixed_camera_1", frames=6, seed=0)
    gt = seq.groundtruth
    poses = matched_poses(seq, gt, where="gt")
    maps = fuse_maps(seq, poses, lambda i, t: seq[i].mask > 0, grow=0, vote_share=1.0)
    full, static = _on_objects(maps.full, seq, poses), _on_objects(maps.static, seq, poses)
    # the objects leave points in the map with nothing left out (1736 measured), none in
    # the static map (0 measured; a voxel at an object's outline averaged with the
    # background behind it could land on the object's surface, hence the 1 % bound)
    assert full > 500
    assert static <= 0.01 * full, (static, full)
    assert len(maps.static.points) < len(maps.full.points) and maps.no_mask == 0
    # no masks at all: both maps are the same
    same = fuse_maps(seq, poses, None)
    assert same.static is same.full
    np.testing.assert_allclose(same.full.points, maps.full.points, atol=0)


def test_a_frame_without_a_mask_stays_out_of_the_static_map():
    seq = make_sequence("fixed_camera_1", frames=3, seed=0)
    poses = matched_poses(seq, seq.groundtruth, where="gt")
    maps = fuse_maps(seq, poses, lambda i, t: None if i == 1 else seq[i].mask > 0)
    assert maps.no_mask == 1 and maps.frames == 3


def test_poses_of_another_sequence_are_refused():
    seq = make_sequence("static", frames=4, seed=0)
    gt = seq.groundtruth
    assert [i for i, _ in matched_poses(seq, gt, where="--traj t.txt")] == [0, 1, 2, 3]
    other = Trajectory(gt.timestamps + 1000.0, gt.poses)
    with pytest.raises(InputError, match=r"--traj t.txt: 4 of 4 poses .* another sequence"):
        matched_poses(seq, other, where="--traj t.txt")


def test_ply_reads_back_and_the_picture_has_both_maps(tmp_path):
    seq = make_sequence("fixed_camera_1", frames=2, seed=0)
    poses = matched_poses(seq, seq.groundtruth, where="gt")
    maps = fuse_maps(seq, poses, lambda i, t: seq[i].mask > 0)
    write_ply(tmp_path / "m.ply", maps.static)
    raw = (tmp_path / "m.ply").read_bytes()
    head, body = raw.split(b"end_header\n", 1)
    assert f"element vertex {len(maps.static.points)}".encode() in head
    rows = np.frombuffer(body, dtype=[("xyz", "<f4", 3), ("rgb", "u1", 3)])
    np.testing.assert_allclose(rows["xyz"], maps.static.points, atol=0)
    assert np.array_equal(rows["rgb"], maps.static.colours)
    img = map_picture(maps, seq.intrinsics, poses[0][1], seq.height, seq.width)
    assert img.dtype == np.uint8 and img.shape[1] == 2 * (seq.width // 2) + 6
    left, right = img[:, : seq.width // 2], img[:, -(seq.width // 2):]
    assert (left != 40).any(axis=-1).mean() > 0.1 and (right != 40).any(axis=-1).mean() > 0.1
