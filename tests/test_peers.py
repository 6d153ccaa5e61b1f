"""The OpenCV peers run frame to frame on the same frames as jaxvo."""

import numpy as np
import pytest

from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import InMemorySequence
from jaxvo.host.services.peers import available_peers, run_peer
from jaxvo.synth.scenes import make_sequence


@pytest.fixture(scope="module")
def seq():
    return InMemorySequence(make_sequence("static", frames=6, seed=2))


def test_opencv_rgbd_tracks_a_static_scene(seq):
    run = run_peer(seq, "opencv_rgbd")
    assert run.trajectory.poses.shape == (6, 4, 4) and run.failures == 0
    np.testing.assert_allclose(run.trajectory.poses[0], seq.groundtruth.poses[0], atol=1e-12)
    # a few frames of a slow camera: within 2 cm of the truth (OpenCV's own accuracy)
    assert trajectory_scores(seq.groundtruth, run.trajectory)["ate_rmse_m"] < 0.02


def test_a_keep_mask_is_honoured(seq):
    # keeping no pixel leaves OpenCV nothing to track: every pair fails, the pose is carried
    run = run_peer(seq, "opencv_depth", keep=lambda i: np.zeros((seq.height, seq.width), bool))
    assert run.failures == 5
    np.testing.assert_allclose(run.trajectory.poses, np.broadcast_to(run.trajectory.poses[0],
                                                                     (6, 4, 4)))


def test_unknown_peer_names_the_available_ones(seq):
    assert "opencv_rgb" in available_peers()
    with pytest.raises(ValueError, match="opencv_rgb"):
        run_peer(seq, "dvo")
