"""Bad input that asks for memory: refused up front, with what it needs and what there is.

A run, a study, a synthetic sequence or the Python API whose settings cannot fit in
the machine's memory is refused before anything compiles.

The answers every case expects and the sequence each breaks: tests/bad_input.py.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from bad_input import FRAMES, assert_one_line_error, base, base_seq, cli  # noqa: F401 (fixtures)

from jaxvo.config import Config
from jaxvo.errors import InputError
from jaxvo.odometry import Odometry
from jaxvo.synth.scenes import make_sequence


@pytest.mark.parametrize("args, needle", [
    (["--hypotheses", "100000"], "--hypotheses 100000"),
])
def test_run_that_cannot_fit_in_memory_is_refused_before_compiling(
        base, tmp_path, capsys, args, needle):
    """These compiled for 16-24 s, then died with an out-of-memory traceback (8.4 TB)."""
    t0 = time.perf_counter()
    res = cli(capsys, "run", base, "--out", tmp_path / "t.txt", *args)
    assert_one_line_error(res, needle, "needs about", "of memory; this machine has",
                          "available")
    assert time.perf_counter() - t0 < 10  # seconds: nothing compiled (the step takes 16+)
    assert not (tmp_path / "t.txt").exists()


def test_synth_and_demo_of_a_billion_frames_are_refused(tmp_path, capsys):
    res = cli(capsys, "synth", "static", tmp_path / "o", "--frames", "1000000000")
    assert_one_line_error(res, "jaxvo synth --frames 1000000000 needs about 861 GB of memory")
    assert not (tmp_path / "o").exists()
    res = cli(capsys, "demo", "--frames", "10000000", "--peers", "none")
    assert_one_line_error(res, "jaxvo demo --frames 10000000 needs about", "TB of memory")


@pytest.mark.parametrize("extra, needle", [
    ("[fixed]\nnum_hypotheses = 100000\n", "num_hypotheses 100000"),
])
def test_study_that_cannot_fit_in_memory_is_refused(tmp_path, capsys, extra, needle):
    spec = tmp_path / "s.toml"
    spec.write_text("[[sequences]]\nscene = 'static'\nframes = 3\n" + extra)
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          needle, "needs about", "available")
    assert not (tmp_path / "r").exists()
    spec.write_text("[[sequences]]\nscene = 'static'\nframes = 1000000000\n")
    assert_one_line_error(cli(capsys, "study", spec, "--out", tmp_path / "r", "-q"),
                          "(1000000000 frames)", "TB of memory")


def test_python_api_refuses_memory_it_cannot_have(base_seq):
    from jaxvo.odometry import run_sequence

    f = base_seq[0]
    with pytest.raises(ValueError, match="Odometry with num_hypotheses 100000, cell "
                                         "16 needs about .* GB of memory"):
        Odometry(base_seq.intrinsics, cfg=Config(num_hypotheses=100000)).process(f.bgr, f.depth,
                                                                               0.0)
    with pytest.raises(InputError, match=f"run_sequence of {FRAMES} frames with num_hypotheses "
                                         "100000, cell 16 needs about"):
        run_sequence(base_seq, cfg=Config(num_hypotheses=100000))


def test_check_memory_gives_both_numbers():
    from jaxvo.host.services.memory import check_memory, run_bytes

    need = run_bytes(Config(), height=480, width=640)
    check_memory(need, what="x", available=2 * need)
    with pytest.raises(InputError, match=r"^x needs about 1.2 GB of memory; this machine has "
                                         r"1 GB available$"):
        check_memory(1.2e9, what="x", available=1e9)
    # the estimate grows with what the settings hold: hypotheses squared, keyframes squared
    assert run_bytes(Config(num_hypotheses=2000), height=480, width=640) > need + 40e6
    kf = run_bytes(Config(keyframes=True), height=480, width=640)
    assert need < kf < need + 10e6  # the default window of 4 keyframes costs little
    assert run_bytes(Config(keyframes=True, keyframe_window=10000), height=480,
                     width=640) > 1e13


def test_a_run_over_a_whole_sequence_counts_the_flow_it_holds_keyframes_included():
    """run_sequence and a study hold every pair's flow at once, with keyframes also its
    keyframe flow (80 bytes a grid point at the default window against the grid flow's
    53): run_bytes grows per frame by what sequence_flows really holds."""
    from jaxvo.host.frontend.flow import sequence_flows
    from jaxvo.host.services.memory import run_bytes

    seq = make_sequence("handheld_fast", frames=4, seed=0)
    per_frame = {}
    for keyframes in (False, True):
        cfg = Config(keyframes=keyframes)
        held = sequence_flows(seq, cfg)
        pairs = len(held.flows.valid)
        fields = [*held.flows, *(held.keyframes or ())]
        nbytes = sum(np.asarray(a).nbytes for a in fields)
        grow = (run_bytes(cfg, height=480, width=640, frames=1000)
                - run_bytes(cfg, height=480, width=640)) / 1000
        per_frame[keyframes] = grow
        outputs = 23.0 * 1200  # the stacked step outputs a frame, counted beside the flow
        assert grow - outputs == pytest.approx(nbytes / pairs, rel=1e-6)
    assert per_frame[True] - per_frame[False] > 60 * 1200  # the keyframe flow, counted
