"""The benches' cached flows (``bench/bench_robustness.py``): a case whose frames the chain
drops keeps a pose for each frame it kept, and its ground truth and grid truth line up; a
cache file is written whole or not at all."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import bench_module

from jaxvo.config import Config
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import InMemorySequence
from jaxvo.synth.scenes import make_sequence
from jaxvo.trajectory import Trajectory


def test_a_dropped_frame_has_no_timestamp_and_the_truth_keeps_its_times(tmp_path):
    """Frame 3 without depth is dropped by the chain (no valid track): the flow's 5 pairs
    run over 6 timestamps, frame 3's left out; the ground truth keeps all 7 frames with
    their times (so each pose is scored at its own frame); the bench's ATE runs. An oracle
    whose movers filled the view crashed the scoring there (145 poses, 150 timestamps)."""
    robustness, splits = bench_module("bench_robustness"), bench_module("splits")
    seq = InMemorySequence(make_sequence("static", frames=7, seed=0))
    seq._frames[3] = seq._frames[3]._replace(depth=np.zeros_like(seq._frames[3].depth))
    case = splits.Case("dropped", "dev", "synthetic", None, lambda: seq)
    data, _ = robustness.build_flow(case, tmp_path / "flow.npz", Config())
    kept = [0, 1, 2, 4, 5, 6]
    np.testing.assert_array_equal(data["frames"], kept)
    assert data["flow_valid"].shape[0] == len(kept) - 1
    np.testing.assert_array_equal(data["timestamps"], np.asarray(seq.timestamps)[kept])
    assert data["gt_poses"].shape == (7, 4, 4) and len(data["gt_times"]) == 7
    est = Trajectory(data["timestamps"], data["gt_poses"][kept])  # the truth at the kept frames
    scores = trajectory_scores(bench_module("_common").groundtruth(data), est)
    assert scores["ate_rmse_m"] < 1e-9


def test_a_cache_file_stopped_while_written_is_not_left_behind(tmp_path, monkeypatch):
    """The flow cache is written whole or not at all: Ctrl-C during the write leaves no file
    (a truncated ``.npz`` failed the next run's load with a traceback)."""
    robustness = bench_module("bench_robustness")
    target = tmp_path / "flow.npz"

    def interrupted(file, **arrays):  # numpy's writer stopped halfway, path or file object
        if isinstance(file, (str, Path)):
            Path(file).write_bytes(b"PK partial")
        else:
            file.write(b"PK partial")
        raise KeyboardInterrupt

    monkeypatch.setattr(robustness.np, "savez_compressed", interrupted)
    try:
        robustness.save_npz(target, a=np.zeros(3))
    except KeyboardInterrupt:
        pass
    assert not target.exists() and list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    robustness.save_npz(target, a=np.arange(3))
    np.testing.assert_array_equal(np.load(target)["a"], np.arange(3))
