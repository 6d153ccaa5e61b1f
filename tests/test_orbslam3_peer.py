"""ORB-SLAM3 as a peer (bench/orbslam3_peer.py): its settings file, the masking of its
input, jaxvo's masks frame by frame, and a short run where pyorbslam3 is installed.

pyorbslam3 is GPL-3.0 and optional: the run is skipped, with the reason, where it or its
runtime libraries are missing; everything else needs neither.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

_BENCH = Path(__file__).resolve().parent.parent / "bench"
_spec = importlib.util.spec_from_file_location("orbslam3_peer", _BENCH / "orbslam3_peer.py")
orb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(orb)

from jaxvo.host.frontend.camera import Intrinsics


def test_settings_read_back_by_opencv_filestorage(tmp_path):
    # ORB-SLAM3 reads its settings with cv::FileStorage: read them back the same way
    K = Intrinsics(535.4, 539.2, 320.1, 247.6, 5000.0)
    path = tmp_path / "s.yaml"
    path.write_text(orb.settings_yaml(K, 640, 480, fps=29.97))
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    for key, want in (("Camera1.fx", 535.4), ("Camera1.fy", 539.2), ("Camera1.cx", 320.1),
                      ("Camera1.cy", 247.6), ("RGBD.DepthMapFactor", 1.0)):
        assert fs.getNode(key).real() == pytest.approx(want, abs=1e-6), key
    assert fs.getNode("Camera.width").isInt() and fs.getNode("Camera.width").real() == 640
    assert fs.getNode("Camera.height").real() == 480
    # ORB-SLAM3 aborts on a frame rate that is not an integer
    assert fs.getNode("Camera.fps").isInt() and fs.getNode("Camera.fps").real() == 30
    assert fs.getNode("Camera.RGB").real() == 0  # BGR images, as OpenCV gives them
    assert fs.getNode("File.version").string() == "1.0"


def _grown_reference(mask: np.ndarray, g: int) -> np.ndarray:
    """Pixels within Chebyshev distance g of a mask pixel, by brute force."""
    ys, xs = np.nonzero(mask)
    yy, xx = np.mgrid[: mask.shape[0], : mask.shape[1]]
    out = np.zeros_like(mask)
    for y, x in zip(ys, xs):
        out |= (np.abs(yy - y) <= g) & (np.abs(xx - x) <= g)
    return out


@pytest.mark.parametrize("image", [False, True])
@pytest.mark.parametrize("grow", [0, 3])
def test_mask_frame_removes_depth_and_optionally_colour_of_the_grown_mask(image, grow):
    rng = np.random.default_rng(0)
    bgr = rng.integers(1, 256, (24, 32, 3), dtype=np.uint8)
    depth = rng.uniform(0.5, 4.0, (24, 32)).astype(np.float32)
    mask = np.zeros((24, 32), bool)
    mask[5:8, 10:12] = True
    mask[20, 30] = True
    bgr0, depth0 = bgr.copy(), depth.copy()
    out_bgr, out_depth = orb.mask_frame(bgr, depth, mask, orb.Masking(image, grow))
    gone = _grown_reference(mask, grow)
    np.testing.assert_array_equal(out_depth == 0, gone)  # exact: depth > 0 everywhere before
    np.testing.assert_array_equal(out_depth[~gone], depth[~gone])
    if image:
        assert not out_bgr[gone].any()
        np.testing.assert_array_equal(out_bgr[~gone], bgr[~gone])
    else:
        np.testing.assert_array_equal(out_bgr, bgr)
    np.testing.assert_array_equal(bgr, bgr0)  # inputs left as they were
    np.testing.assert_array_equal(depth, depth0)


def test_streaming_masks_are_the_runs_plugin_masks():
    # frame by frame (a robot's loop) gives each image the mask the whole-sequence run's
    # plug-in masks give it (jaxvo.host.writers.plugin: step k labels image k); the last image takes the
    # last step's map in both (no final state without the scan)
    import jaxvo
    from jaxvo.host.readers.io import InMemorySequence
    from jaxvo.synth.scenes import make_sequence

    # test_pipeline.py's sequence: the scan is the program compiled there
    seq = InMemorySequence(make_sequence("handheld_slow", frames=12, seed=3))
    res = jaxvo.run_sequence(seq, start_pose="identity")
    cell = jaxvo.Config().cell
    want = jaxvo.dynamic_masks(res, seq.height, seq.width, cell)
    assert want.any()  # the scene has a moving object: the comparison is not vacuous
    got = list(orb.streaming_masks(seq, jaxvo.Odometry(seq.intrinsics, seed=0)))
    assert [f.index for f, _ in got] == list(range(len(seq)))
    np.testing.assert_array_equal(np.stack([m for _, m in got]), want)


def test_orbslam3_tracks_the_static_frames(require_data):
    if why := orb.missing():
        pytest.skip(why)
    from jaxvo.evaluation.scores import trajectory_scores
    from jaxvo.host.readers.io import InMemorySequence, open_sequence

    seq = InMemorySequence(open_sequence(require_data("7scenes_static_0000_0299")), 40)
    peer, run = orb.run_orbslam3(seq)
    assert len(run.ms) == 40 and len(peer.trajectory) >= 35
    # about 10 mm measured over these 40 frames; 30 mm is a failure to track, not noise
    assert trajectory_scores(seq.groundtruth, peer.trajectory)["ate_rmse_m"] < 0.03
    # the trajectory starts at the true pose of its first frame (the peers' convention)
    np.testing.assert_allclose(peer.trajectory.poses[0], seq.groundtruth.poses[0], atol=1e-6)


def test_a_failing_child_reports_one_line(tmp_path):
    if why := orb.missing():
        pytest.skip(why)
    bad = tmp_path / "ORBvoc.txt"
    bad.write_text("not a vocabulary\n")
    o = orb.OrbSlam3(Intrinsics(500.0, 500.0, 16.0, 12.0), 32, 24, vocab=bad)
    with pytest.raises(RuntimeError, match="ORB-SLAM3"):
        for i in range(3):
            o.track(np.zeros((24, 32, 3), np.uint8), np.ones((24, 32), np.float32), i / 30)
        o.finish()
