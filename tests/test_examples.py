"""Every script in ``examples/`` runs, on small inputs: no test ran them, and one rotted
unseen (``recorded_sequence.py`` died at its first line when the package began to load
lazily). Each runs in its own interpreter, in a folder of its own (they write there), with
the built-in scenes cut to a few frames; a script that needs what is not here (the shared
data, ORB-SLAM3) is skipped, saying what."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from conftest import bench_module

from jaxvo.synth.scenes import make_sequence, write_sequence

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
FRAMES = 4  # frames of every built-in scene an example makes (pairs enough for each step)
RECORDED = 11  # frames of the folder given to the recorded-sequence examples: frame 10's overlay

# Runs a script as `python SCRIPT ARGS...` would, with jaxvo.make_sequence giving at most
# FRAMES frames (the scripts ask for 45-60; the code paths are the same).
RUNNER = f"""
import runpy, sys
from jaxvo.synth import scenes
full = scenes.make_sequence
def small(name, frames=None, **kwargs):
    return full(name, frames=min(frames or {FRAMES}, {FRAMES}), **kwargs)
scenes.make_sequence = small
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """A small sequence in the TUM layout, for the scripts that read a recorded one."""
    out = tmp_path_factory.mktemp("rec") / "seq"
    write_sequence(make_sequence("handheld_fast", frames=RECORDED, seed=1), out)
    return out


def _orbslam3_missing() -> str | None:
    return bench_module("orbslam3_peer").missing()


def _args(name: str, recorded: Path, tmp_path: Path) -> list[str]:
    """The command-line arguments that make ``name`` small, or a skip saying why it cannot
    run here."""
    if name == "orbslam3_with_jaxvo_masks.py":
        why = _orbslam3_missing()
        if why:
            pytest.skip(f"{name} needs ORB-SLAM3: {why}")
        return [str(recorded)]
    if name == "recorded_sequence.py":
        return [str(recorded)]
    if name == "render_scenarios.py":
        return ["--out", str(tmp_path / "pictures"), "--frames", str(FRAMES)]
    return []


def test_every_example_is_listed():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(SCRIPTS), (
        "a new example: give it its small arguments in _args and list it in SCRIPTS")


SCRIPTS = ("orbslam3_with_jaxvo_masks.py", "parameter_study.py", "quickstart_synthetic.py",
           "recorded_sequence.py", "render_scenarios.py", "seed_study.py")
# each compiles its own programs: 57-112 s apiece at load average 7 on 2 cores; the two
# quickest (22 and 46 s there) run in the quick suite too
QUICK = ("recorded_sequence.py", "render_scenarios.py")


@pytest.mark.parametrize("name", [n if n in QUICK else pytest.param(n, marks=pytest.mark.slow)
                                  for n in SCRIPTS])
def test_example_runs_on_small_inputs(name, recorded, tmp_path):
    args = _args(name, recorded, tmp_path)
    done = subprocess.run([sys.executable, "-c", RUNNER, str(EXAMPLES / name), *args],
                          cwd=tmp_path, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip(), "the example printed nothing"
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
