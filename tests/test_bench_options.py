"""The benches' options (``bench/_options.py``): ``--config`` / ``--set NAME=VALUE`` read as
each field's type, and a bad option of any script refused in one line ``error: ...`` (exit 2)
before anything runs."""

from __future__ import annotations

import argparse

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def seeds():
    return bench_module("_options")


def test_values_take_their_fields_types(seeds):
    cfg = seeds.config_from(["lk_window=13", "keyframes=on", "keyframe_overlap=0.5"])
    assert (cfg.lk_window, cfg.keyframes, cfg.keyframe_overlap) == (13, True, 0.5)
    assert seeds.config_from(["depth_smooth=false"]).depth_smooth is False
    assert seeds.params_from(["lam=2"]).lam == 2.0


@pytest.mark.parametrize("text, says", [
    ("nonsense=1", "NAME one of"),
    ("lk_window", "want NAME=VALUE"),
    ("lk_window=abc", "lk_window must be an integer"),
    ("keyframes=maybe", "keyframes is true or false"),
    ("lk_window=-3", "Config.lk_window must be at least 3"),
])
def test_a_bad_config_setting_is_one_line(seeds, text, says):
    with pytest.raises(argparse.ArgumentTypeError, match=says) as e:
        seeds.config_setting(text)
    assert "\n" not in str(e.value)


def test_settings_that_run_only_together_each_pass_alone(seeds):
    """``keyframe_track_window=true`` needs ``keyframes=true``: each passes as a value (the
    pair is checked together, by ``check_options``); it was refused alone, so no run could
    ask for it."""
    pair = ["keyframes=true", "keyframe_track_window=true"]
    assert [seeds.config_setting(t) for t in pair] == pair
    assert seeds.config_from(pair).keyframe_track_window


def test_a_bad_params_setting_is_one_line(seeds):
    with pytest.raises(argparse.ArgumentTypeError, match="Params.lam"):
        seeds.params_setting("lam=-1")
    with pytest.raises(argparse.ArgumentTypeError, match="lam must be a number"):
        seeds.params_setting("lam=x")
    assert seeds.params_setting("lam=2") == "lam=2"


def _refused(capsys, script: str, *argv: str) -> str:
    """The one line ``script`` (a bench script's main) refuses ``argv`` with, exit 2."""
    with pytest.raises(SystemExit) as e:
        bench_module(script).main(list(argv))
    assert e.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert ": error: " in lines[-1], lines  # argparse's usage lines, then the one error line
    assert not any("Traceback" in line for line in lines)
    return lines[-1]


@pytest.mark.parametrize("argv, says", [
    # each value passes alone; the pair cannot run
    (["--config", "depth_min=5", "depth_max=1"], ("argument --config: Config.depth_max 1.0 "
                                                 "must be beyond Config.depth_min 5.0")),
    (["--config", "num_hypotheses=100000000"], ("argument --config: a run with "
                                               "num_hypotheses=100000000 needs about")),
    (["--config", "cell=1000"], "argument --config: Config.cell 1000 leaves fewer than 2 x 2"),
    (["--config", "keyframe_track_window=true"], ("argument --config: "
                                                 "Config.keyframe_track_window tracks")),
    (["--skip", "200", "--frames", "100"], "argument --skip: 200 leaves no frame to time"),
    (["--frames", "1"], "argument --frames: must be at least 2"),
])
def test_time_process_refuses_what_cannot_run_before_reading_frames(capsys, argv, says,
                                                                    require_data):
    require_data("7scenes_static_0000_0299")
    assert says in _refused(capsys, "time_process", *argv)


def test_a_missing_data_root_names_jaxvo_data(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("JAXVO_DATA", str(tmp_path / "nowhere"))
    line = _refused(capsys, "time_process")
    assert "no 7scenes_static_0000_0299 under the data root" in line and "JAXVO_DATA" in line


@pytest.mark.parametrize("script, argv, says", [
    ("bench_cover", ["--seeds", "0"], "argument --seeds: must be at least 1"),
    ("bench_cover", ["--only", "heavy_cover_90"], "argument --only: no case 'heavy_cover_90'"),
    ("bench_robustness", ["--set", "nonsense=1"], "argument --set: 'nonsense=1': want NAME"),
    ("bench_robustness", ["--set", "lam"], "argument --set: 'lam': want NAME=VALUE"),
    ("bench_robustness", ["--only", "NO_SUCH_CASE", "--set", "lam=2"],
     "argument --only: no case 'NO_SUCH_CASE'"),
    ("bench_seeds", ["--only", "static_dev_evry1"], ("argument --only: no case "
                                                    "'static_dev_evry1'")),
])
def test_bad_options_are_one_line_before_any_work(capsys, tmp_path, script, argv, says):
    """Each did work first (30 s, then a ValueError), or ran nothing and exited 0 with empty
    tables written over the earlier ones."""
    (tmp_path / "seeds.md").write_text("earlier\n")
    line = _refused(capsys, script, *argv, "--out", str(tmp_path))
    assert says in line
    assert (tmp_path / "seeds.md").read_text() == "earlier\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seeds.md"]
