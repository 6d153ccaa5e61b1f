"""The keyframe tracks' error by age (``bench/keyframe_track_noise.py``): each pair's keyframe
image follows the renewals, and a track that follows the true motion has no error while one
displaced by k pixels has k."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def noise():
    return bench_module("keyframe_track_noise")


def test_each_pair_reads_the_keyframe_taken_after_the_last_renewal(noise):
    renew = np.array([False, False, True, False, True, True, False])
    # image 0 first; a renewal at pair k makes image k + 1 the keyframe from pair k + 1 on
    assert noise.keyframe_images(renew).tolist() == [0, 0, 0, 3, 3, 5, 6]


def test_a_track_displaced_across_the_view_errs_by_its_displacement(noise):
    rng = np.random.default_rng(0)
    src = np.column_stack([rng.uniform(-1, 1, (50, 2)), rng.uniform(1.5, 3.0, 50)])
    T = np.eye(4)
    T[:3, 3] = [0.05, -0.02, 0.1]
    dst = src + T[:3, 3]
    lateral, depth = noise.track_errors(src, dst, T, focal=500.0)
    np.testing.assert_allclose(lateral, 0.0, atol=1e-9)
    np.testing.assert_allclose(depth, 0.0, atol=1e-12)
    shifted = dst.copy()
    shifted[:, 0] += 3.0 * shifted[:, 2] / 500.0  # 3 pixels to the right at every depth
    lateral, _ = noise.track_errors(src, shifted, T, focal=500.0)
    np.testing.assert_allclose(lateral, 3.0, rtol=1e-9)


def test_the_displacement_table_bins_each_kind_of_track_by_how_far_it_moved(noise):
    # pair tracks that moved 1 px and err 0.5; keyframe tracks (ages 1 and 3) that moved 30
    # px and err 2; too few tracks in a bin leave its median out
    n = noise.MIN_TRACKS
    errors = {"pair": (np.full(n, 0.5), np.zeros(n), np.full(n, 1.0)),
              1: (np.full(n, 2.0), np.zeros(n), np.full(n, 30.0)),
              3: (np.full(5, 9.0), np.zeros(5), np.full(5, 100.0))}
    rows = {row[0]: row[1:] for row in noise.by_displacement(errors)}
    assert rows["0-2"] == (f"0.50 ({n})", "- (0)")
    assert rows["20-40"] == ("- (0)", f"2.00 ({n})")
    assert rows["80+"] == ("- (0)", "- (5)")
    assert len(rows) == len(noise.DISPLACEMENT_BINS)


def test_image_distance_is_the_pixels_between_two_projections(noise):
    a = np.array([[0.0, 0.0, 2.0], [0.2, 0.0, 1.0]])
    b = np.array([[0.04, 0.03, 2.0], [0.2, 0.0, 4.0]])
    np.testing.assert_allclose(noise.image_distance(a, b, 500.0), [12.5, 75.0])
