"""The benches' ``--config`` / ``--set NAME=VALUE`` options (``bench/bench_seeds.py``): read as
each field's type, and a bad one refused in one line before anything runs."""

from __future__ import annotations

import argparse

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def seeds():
    return bench_module("bench_seeds")


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


def test_a_bad_params_setting_is_one_line(seeds):
    with pytest.raises(argparse.ArgumentTypeError, match="Params.lam"):
        seeds.params_setting("lam=-1")
    with pytest.raises(argparse.ArgumentTypeError, match="lam must be a number"):
        seeds.params_setting("lam=x")
    assert seeds.params_setting("lam=2") == "lam=2"
