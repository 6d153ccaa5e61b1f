"""When the background switches to another motion (jaxvo.core.background's challenge), the
path so far is redrawn along that motion's chain: the walk back through the pairs
(jaxvo.core.pipeline.revised_poses), the streaming odometry's revision of its poses, and
the trajectory file written again."""

from __future__ import annotations

import numpy as np

from jaxvo.core.pipeline import revised_poses
from jaxvo.host.readers.io import TrajectoryWriter
from jaxvo.odometry import Odometry
from jaxvo.trajectory import read_trajectory

M = 3  # identifiers in these hand-made runs


def _shift(x: float) -> np.ndarray:
    T = np.eye(4, dtype=np.float32)
    T[0, 3] = x
    return T


def _run(pairs: int):
    """Hand-made outputs of ``pairs`` pairs: pose x = pair index, identifier k's chain at
    pair i x = 100 k + i, no renumbering but a swap of 1 and 3 in pair 1."""
    T_w_c = np.stack([_shift(i) for i in range(pairs)])
    chains = np.stack([np.stack([_shift(100 * (k + 1) + i) for k in range(M)])
                       for i in range(pairs)])
    perms = np.tile(np.arange(M, dtype=np.int32), (pairs, 1))
    perms[1] = [2, 1, 0]
    return T_w_c, chains, perms


def _x(poses) -> list[float]:
    return [float(T[0, 3]) for T in np.asarray(poses)]


def test_a_switch_redraws_every_earlier_pose_along_the_winner_renumbered_back():
    """A switch to identifier 2 in pair 3: pairs 2 and 1 read identifier 2's chain, pair 0
    reads identifier 2 still (the swap of pair 1 is of 1 and 3); with the winner 3 the
    swap of pair 1 sends the walk to identifier 1's chain in pair 0. The switch's own pair
    keeps its pose; without a switch nothing changes."""
    T_w_c, chains, perms = _run(4)
    none = np.zeros(4, np.int32)
    assert _x(revised_poses(T_w_c, none, chains, perms)) == [0, 1, 2, 3]
    assert _x(revised_poses(T_w_c, np.array([0, 0, 0, 2], np.int32), chains, perms)) == [
        200, 201, 202, 3]
    assert _x(revised_poses(T_w_c, np.array([0, 0, 0, 3], np.int32), chains, perms)) == [
        100, 301, 302, 3]


def test_the_redraw_stops_where_the_identifier_was_given_to_its_object():
    """Identifier 2 given anew in pair 1 (numbered as entering it): a switch to it in pair
    3 redraws pairs 2 and 1 along its chain, and pair 0, when identifier 2 was another
    object's or none, keeps its committed pose. Given in pair 3 itself, nothing before it
    is redrawn."""
    T_w_c, chains, perms = _run(4)
    new_ids = np.zeros((4, M), bool)
    new_ids[1, 1] = True
    switched = np.array([0, 0, 0, 2], np.int32)
    assert _x(revised_poses(T_w_c, switched, chains, perms, new_ids)) == [0, 201, 202, 3]
    new_ids = np.zeros((4, M), bool)
    new_ids[3, 1] = True
    assert _x(revised_poses(T_w_c, switched, chains, perms, new_ids)) == [0, 1, 2, 3]


def test_a_later_switch_redraws_over_an_earlier_one():
    T_w_c, chains, perms = _run(4)
    assert _x(revised_poses(T_w_c, np.array([0, 3, 0, 0], np.int32), chains, perms)) == [
        300, 1, 2, 3]
    assert _x(revised_poses(T_w_c, np.array([0, 3, 0, 2], np.int32), chains, perms)) == [
        200, 201, 202, 3]


def test_the_streaming_odometry_revises_its_poses_as_the_walk_does():
    """The poses kept by Odometry (the first image's, then one a pair) redrawn by a switch
    in the last pair: the same as the walk over the whole run (padded in front to a power
    of two), the first pose and the last untouched, the revised ones returned."""
    T_w_c, chains, perms = _run(5)
    odo = Odometry((500.0, 500.0, 320.0, 240.0))
    odo.poses = [np.eye(4)] + [T.astype(np.float64) for T in T_w_c]
    new_ids = np.zeros((5, M), bool)
    new_ids[1, 1] = True
    odo._chains, odo._permutations, odo._new_ids = list(chains), list(perms), list(new_ids)
    revised = odo._revise(2)
    switched = np.array([0, 0, 0, 0, 2], np.int32)
    expected = np.asarray(revised_poses(T_w_c, switched, chains, perms, new_ids))
    np.testing.assert_array_equal(np.asarray(odo.poses[1:]), expected)
    np.testing.assert_array_equal(revised, expected[:-1])
    np.testing.assert_array_equal(odo.poses[0], np.eye(4))
    assert _x(odo.trajectory.poses) == [0, 0, 201, 202, 203, 4]


def test_the_trajectory_file_is_written_again_with_the_revised_poses(tmp_path):
    """The file holds the revised poses and its header; standard output cannot take back
    what it printed: the count of poses left as they were."""
    path = tmp_path / "traj.txt"
    with TrajectoryWriter(path, comment="a run") as w:
        for i in range(4):
            w.write(float(i), _shift(i))
        assert w.revise(np.stack([_shift(10), _shift(11)])) == 0
        w.write(4.0, _shift(4))
        assert w.revise(np.stack([_shift(13)])) == 0  # a second switch: once more, whole
        w.write(5.0, _shift(5))
    traj = read_trajectory(path)
    assert _x(traj.poses) == [0, 10, 11, 13, 4, 5]
    assert path.read_text().startswith("# a run\n")
    assert path.read_text().count("# a run") == 1
    assert _x(w.written().poses) == [0, 10, 11, 13, 4, 5]
    out = TrajectoryWriter("-")
    out.write(0.0, _shift(0))
    out.write(1.0, _shift(1))
    assert out.revise(np.stack([_shift(9)])) == 1


def test_jaxvo_run_rewrites_its_file_and_counts_the_revised_poses(tmp_path):
    """The run's recorder: a result with revised poses rewrites them in the trajectory file
    and counts the switch and the poses; a result without leaves them."""
    from types import SimpleNamespace

    from jaxvo.config import Config
    from jaxvo.run import Recorder
    from jaxvo.status import Status

    path = tmp_path / "traj.txt"
    with TrajectoryWriter(path) as writer:
        rec = Recorder(Config(), writer, images=None, folders={})
        for i in range(4):
            rec.recent[i] = SimpleNamespace(index=i)
            output = None if i == 0 else SimpleNamespace(
                reacquired=False, keyframes=None, dynamic=np.zeros(4, bool))
            revised = np.stack([_shift(10), _shift(11)]) if i == 3 else None
            rec.record(SimpleNamespace(index=i, timestamp=float(i), T_w_c=_shift(i),
                                       dropped=None, status=Status.OK, output=output,
                                       revised=revised))
    assert _x(read_trajectory(path).poses) == [0, 10, 11, 3]
    assert (rec.switches, rec.revised, rec.unrevised) == (1, 2, 0)


def test_real_frames_under_near_boxes_switch_once_and_the_path_redrawn_is_nearer_the_truth(
        require_data):
    """7-Scenes frames 150-239 with fixed_camera_2's boxes inserted (seed 1; the validation
    split's composite, shortened): the background is first committed to the wrong motion,
    the challenge switches it once, late in the run, and the poses before the switch are
    redrawn along the winner's chain; the whole path is then far nearer the truth than the
    poses the frames returned as they came (measured: 108 -> 51 mm ATE)."""
    import jaxvo
    from jaxvo.host.readers.io import InMemorySequence
    from jaxvo.synth.scenes import composite_sequence

    seq = InMemorySequence(composite_sequence(require_data("7scenes_static_0000_0299"),
                                              "fixed_camera_2", start=150, frames=90, seed=1))
    odo = Odometry(seq.intrinsics, seed=0, T_w_c0=seq.groundtruth.poses[0])
    results = [odo.process(f.bgr, f.depth, f.timestamp) for f in seq]
    kept = [r for r in results if r.dropped is None]
    switched = [r for r in results if r.revised is not None]
    assert len(switched) == 1 and switched[0].index > 45, [r.index for r in switched]
    # every kept pose between the first frame's (the start) and the switching pair's is
    # redrawn, the later ones stay as returned
    k = kept.index(switched[0])
    assert len(switched[0].revised) == k - 1
    np.testing.assert_allclose(odo.trajectory.poses[0], seq.groundtruth.poses[0], atol=1e-6)
    np.testing.assert_array_equal(odo.trajectory.poses[1:k], switched[0].revised)
    np.testing.assert_array_equal(odo.trajectory.poses[k:], [r.T_w_c for r in kept[k:]])
    truth = seq.groundtruth
    as_returned = jaxvo.Trajectory(odo.trajectory.timestamps, [r.T_w_c for r in kept])
    before = jaxvo.trajectory_scores(truth, as_returned)["ate_rmse_m"]
    after = jaxvo.trajectory_scores(truth, odo.trajectory)["ate_rmse_m"]
    assert after < 0.6 * before, (before, after)
