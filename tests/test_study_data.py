"""The study's flow cache (jaxvo.study.data): what keys it (the flow's options, a format
version and the sequence's identity, its frames' files included) and what does not (the
source text, the step's settings)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from test_study import folder_spec

from jaxvo.config import Config
from jaxvo.study import runner as study

# ---------------------------------------------------------------------- the flow cache


def test_the_flow_reads_only_its_options_and_they_key_the_cache():
    """The flow's tracker holds ``Config.flow`` (a FlowOptions) and nothing else of the
    Config, so the flow runs on those options alone (a read of any other setting would
    raise) and no setting outside them can change it without keying the cache. Every
    Config field is the flow's, the step's or both (the grid cell, the keyframe window)."""
    import dataclasses

    from jaxvo.config import StepOptions
    from jaxvo.host.frontend.flow import GridFlowTracker, sequence_flows
    from jaxvo.synth.scenes import make_sequence

    seq = make_sequence("handheld_fast", frames=3, seed=0)
    for keyframes in (False, True):  # the keyframe tracker reads settings of its own
        cfg = Config(cell=32, keyframes=keyframes)
        flows = sequence_flows(seq, cfg.flow)
        assert len(flows.flows.valid) == 2 and (flows.keyframes is None) == (not keyframes)
        tracker = GridFlowTracker(seq.intrinsics, cfg, height=seq.height, width=seq.width)
        assert tracker.cfg == cfg.flow
    step_fields = {f.name for f in dataclasses.fields(StepOptions)}
    assert set(study.flow_fields()) | step_fields == set(study.config_fields())
    assert {"keyframes", "keyframe_stride", "keyframe_overlap"} <= set(study.flow_fields())
    assert "num_hypotheses" not in study.flow_fields() and "lk_window" not in step_fields

    s = study.SequenceSpec("x", "static", None, 5, 0, 1, None)
    key = study.sequence_key(s, Config())
    assert key == study.sequence_key(s, Config(num_hypotheses=5, max_ids=4))
    assert key != study.sequence_key(s, Config(cell=32))
    assert key != study.sequence_key(s._replace(seed=1), Config())
    assert key == study.sequence_key(s._replace(label="y"), Config())


def test_the_flow_cache_key_is_no_source_text(tmp_path):
    """The key was a hash of ten modules' source: a comment changed it (every cached flow
    and every run of a resumed study redone), a module left off the list did not. It is
    the flow's options and FLOW_FORMAT, bumped by hand: the same key from a copy of the
    package whose flow module holds one comment more."""
    import shutil

    import jaxvo

    code = ("from jaxvo.config import Config\n"
            "from jaxvo.study import runner as study\n"
            "s = study.SequenceSpec('x', 'static', None, 5, 0, 1, None)\n"
            "print(study.sequence_key(s, Config()))\n")
    keys = []
    for name, comment in (("a", ""), ("b", "\n# a comment about the tracker\n")):
        shutil.copytree(Path(jaxvo.__file__).parent, tmp_path / name / "jaxvo")
        with (tmp_path / name / "jaxvo" / "host" / "flow.py").open("a") as fh:
            fh.write(comment)
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                              cwd=tmp_path / name, timeout=120, check=False,
                              env={**os.environ, "PYTHONPATH": str(tmp_path / name)})
        assert done.returncode == 0, done.stderr[-2000:]
        keys.append(done.stdout.strip())
    assert keys[0] == keys[1] and len(keys[0]) == 16


def test_the_flow_cache_key_follows_the_flow_options_and_format(monkeypatch):
    from jaxvo.study import data

    s = study.SequenceSpec("x", "static", None, 5, 0, 1, None)
    key = study.sequence_key(s, Config())
    assert key != study.sequence_key(s, Config(lk_window=13))
    assert key != study.sequence_key(s, Config(depth_smooth=not Config().depth_smooth))
    monkeypatch.setattr(data, "FLOW_FORMAT", data.FLOW_FORMAT + 1)
    study.sequence_key.cache_clear()
    assert study.sequence_key(s, Config()) != key
    # a scene's scenario is part of the sequence's identity, by value
    import dataclasses

    from jaxvo.synth import scenario

    faster = dataclasses.replace(scenario.SCENARIOS["static"], camera_speed=0.5)
    monkeypatch.setitem(scenario.SCENARIOS, "static", faster)
    study.sequence_key.cache_clear()
    assert study.sequence_key(s, Config()) != key


def test_changed_frames_under_the_same_lists_run_again(tmp_path):
    """A folder's depth images rewritten under the same lists: the flow cache and
    --resume trusted the lists and kept the old flow and result (0.062 mm where a fresh
    study gave 4.956); the frames' files are in the sequence's identity, so the flow and
    the run are done again and the result is the fresh study's."""
    import cv2

    from jaxvo.synth.scenes import make_sequence, write_sequence

    folder = tmp_path / "seq"
    write_sequence(make_sequence("handheld_fast", frames=8, seed=0), folder)
    spec = folder_spec(tmp_path, folder, seed=0, cell=32, num_hypotheses=4,
                       noise_calibration=True)
    out, flows = tmp_path / "out", tmp_path / "flows"
    before = study.run_spec(spec, out, flow_cache=flows).rows[0]
    for png in sorted((folder / "depth").iterdir())[4:]:  # the far half 1.5 times farther
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED).astype(np.float64)
        assert cv2.imwrite(str(png), np.round(raw * 1.5).astype(np.uint16))
    res = study.run_spec(spec, out, resume=True, flow_cache=flows)  # in the same process
    assert res.ran == 1 and len(list(flows.iterdir())) == 2
    fresh = study.run_spec(spec, tmp_path / "fresh", flow_cache=tmp_path / "flows2").rows[0]
    assert res.rows[0]["digest"] == fresh["digest"] != before["digest"]
