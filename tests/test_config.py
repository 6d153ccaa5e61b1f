"""jaxvo.config: each side's options declared once, Config composing them and read by
setting name, every setting checked as its declaration says."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from jaxvo.config import (
    PARAM_SPANS,
    Config,
    FlowOptions,
    Params,
    SharedOptions,
    Span,
    StepOptions,
    check_config,
    check_params,
    config_fields,
    number,
    whole,
)
from jaxvo.errors import InputError, check_seed


def names(options: type) -> set[str]:
    return {f.name for f in dataclasses.fields(options)}


def test_flat_keywords_set_the_side_that_reads_them_and_reads_find_it():
    cfg = Config(cell=8, lk_window=5, num_hypotheses=10, keyframes=True)
    assert (cfg.cell, cfg.lk_window, cfg.num_hypotheses, cfg.keyframes) == (8, 5, 10, True)
    assert isinstance(cfg.flow, FlowOptions) and isinstance(cfg.step, StepOptions)
    assert (cfg.flow.cell, cfg.step.cell, cfg.flow.keyframes, cfg.step.keyframes) == (
        8, 8, True, True)  # a shared setting reaches both sides
    assert cfg.flow.lk_window == 5 and cfg.step.num_hypotheses == 10
    assert not hasattr(cfg.step, "lk_window") and not hasattr(cfg.flow, "num_hypotheses")
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        cfg.nothing  # noqa: B018
    assert (Config.cell, Config.keyframes, Config.lk_window) == (16, False, 9)  # the defaults
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        Config.nothing  # noqa: B018
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.cell = 4


def test_the_two_sides_compose_a_config_and_settings_by_name_replace_theirs():
    flow, step = FlowOptions(lk_window=5), StepOptions(max_ids=4)
    cfg = Config(flow=flow, step=step)
    assert cfg.flow is flow and cfg.step is step and cfg.lk_window == 5 and cfg.max_ids == 4
    assert Config(flow, step, cell=8).flow == dataclasses.replace(flow, cell=8)
    with pytest.raises(ValueError, match="disagree on cell .8 against 16.: set it once"):
        Config(flow=FlowOptions(cell=8))
    with pytest.raises(TypeError, match="takes a FlowOptions and a StepOptions"):
        Config(flow=step)
    with pytest.raises(InputError, match="keyframe_window must be a whole number, got nan"):
        check_config(Config(keyframe_window=float("nan")))  # one value on both sides


def test_replace_equality_and_hashing_follow_the_settings():
    cfg = Config(cell=12)
    moved = dataclasses.replace(cfg, keyframes=True, lk_window=5)
    assert (moved.cell, moved.keyframes, moved.lk_window) == (12, True, 5)
    assert moved.step.keyframes and moved.flow.keyframes and moved.flow.cell == 12
    assert Config(cell=12) == cfg and hash(Config(cell=12)) == hash(cfg)
    assert cfg != Config() and len({cfg, Config(cell=12), Config()}) == 2
    # the step's static argument: a flow setting leaves it equal, so nothing recompiles
    assert Config(lk_window=5).step == Config().step
    assert hash(Config(lk_window=5).step) == hash(Config().step)
    assert Config(max_ids=4).step != Config().step
    assert pickle.loads(pickle.dumps(moved)) == moved
    assert Config(**moved.as_dict()) == moved  # by name, as a study spec builds it
    assert Config(flow=moved.flow, step=moved.step) == moved


def test_each_setting_is_declared_once_with_what_a_run_can_use():
    fields = config_fields()
    assert set(fields) == names(FlowOptions) | names(StepOptions)
    assert names(FlowOptions) & names(StepOptions) == names(SharedOptions)
    assert len(fields) == 35 and list(fields)[:len(names(SharedOptions))] == [
        f.name for f in dataclasses.fields(SharedOptions)]
    for name, spec in fields.items():
        kind = type(spec.default)
        assert kind in (bool, int, float), name
        if kind is int:
            assert isinstance(spec.metadata["least"], int) and spec.metadata["unit"], name
        if kind is float:
            assert isinstance(spec.metadata["span"], Span), name
            assert spec.metadata["span"].holds(spec.default), name
    assert Config().as_dict() == {name: spec.default for name, spec in fields.items()}
    check_config(Config(), height=480, width=640)  # every default passes


def test_config_is_built_in_its_class_not_patched_at_import():
    assert "__init__" in vars(Config) and not hasattr(Config.__init__, "__wrapped__")
    assert Config.__init__.__qualname__ == "Config.__init__"


@pytest.mark.parametrize("settings, needle", [
    ({"sample_radius": 0}, r"^Config.sample_radius must be at least 1 grid cell, got 0$"),
    ({"patch": 7.0}, r"^Config.patch must be a whole number, got 7.0$"),
    ({"min_similarity": -1.5}, r"^Config.min_similarity must be a number in \[-1, 1\], got -1.5$"),
    ({"lk_eps": 0.0}, r"^Config.lk_eps must be a number in \(0, inf\), got 0.0$"),
    ({"depth_smooth": "yes"}, r"^Config.depth_smooth must be True or False, got 'yes'$"),
    ({"noise_calibration": 0}, r"^Config.noise_calibration must be True or False, got 0$"),
    ({"keyframe_track_window": True},
     r"^Config.keyframe_track_window tracks the keyframes' window: it needs Config.keyframes$"),
])
def test_check_config_reads_each_setting_as_declared(settings, needle):
    with pytest.raises(InputError, match=needle):
        check_config(Config(**settings))


def test_numpy_values_pass_as_their_python_kind():
    check_config(Config(cell=np.int64(8), depth_smooth=np.bool_(False),
                        lk_fast_px=np.float32(4.0)), height=480, width=640)


def test_a_span_says_and_holds_its_ends():
    assert str(Span(0.0, True, 1.0, False)) == "[0, 1)"
    assert str(Span(None, False, 2.5, True)) == "(-inf, 2.5]"
    assert str(Span(-1.0, False, None, False)) == "(-1, inf)"
    span = Span(0.0, True, 1.0, False)
    assert span.holds(np.array([0.0, 0.5, 1.0, np.nan])).tolist() == [True, True, False, False]


def test_the_declaration_helpers_carry_what_the_checks_read():
    assert whole(3, 1, "frame").metadata == {"least": 1, "unit": "frame"}
    assert number(0.5, Span(0.0, True, 1.0, True)).default == 0.5


# --- bad settings, as a user gives them (from the bad-input tests) ---------------------


def test_check_params_names_the_field_and_its_range():
    assert set(PARAM_SPANS) == set(Params._fields)  # every field has its range
    check_params(Params())  # the defaults pass, and so does a batch of good values
    check_params(Params(confidence=np.array([0.9, 0.99]), evidence_margin=np.zeros(2)))
    with pytest.raises(InputError, match=r"^Params.evidence_margin must be in \[0, inf\), got -1$"):
        check_params(Params(evidence_margin=-1.0))
    with pytest.raises(InputError, match=r"^Params.confidence must be in \(0, 1\), got 1\.5$"):
        check_params(Params(confidence=np.array([0.9, 1.5])))
    with pytest.raises(InputError, match=r"^Params.max_age must be a finite number"):
        check_params(Params(max_age=float("inf")))
    with pytest.raises(InputError, match=r"^--conf must be a number, got 'high'$"):
        check_params(Params(confidence="high"), names={"confidence": "--conf"})


def test_check_config_and_check_seed_name_the_field():
    with pytest.raises(InputError, match="Config.num_hypotheses must be at least 1"):
        check_config(Config(num_hypotheses=0))
    with pytest.raises(InputError, match="Config.cell must be a whole number"):
        check_config(Config(cell=16.0))
    check_config(Config(cell=np.int64(16)), height=480, width=640)  # NumPy integers pass
    assert check_seed(np.uint32(7)) == 7
    with pytest.raises(InputError, match="seed must be"):
        check_seed(1.5)


def test_config_names_the_replacement_and_checks_every_value():
    """Config(window=5): TypeError 'unexpected keyword argument'; keyframe_overlap = nan and
    keyframe_stride = 1000 ran, taking no keyframe or one point a keyframe."""
    with pytest.raises(TypeError, match="keyframes=True.* refines a window over the latest"):
        Config(window=5)
    with pytest.raises(TypeError, match="did you mean cell"):
        Config(cel=8)
    for cfg, needle in ((Config(keyframe_overlap=float("nan")), ("keyframe_overlap must be a "
                         r"number in \[0, 1\], got nan")),
                        (Config(keyframes=True, keyframe_stride=1000),
                         "keyframe_stride 1000 keeps 1 of the 30x40 grid's points"),
                        (Config(fb_max=-1.0), r"fb_max must be a number in \(0, inf\)"),
                        (Config(lk_levels=-1), "lk_levels must be at least 0"),
                        (Config(keyframes="no"), "keyframes must be True or False"),
                        (Config(depth_min=5.0, depth_max=1.0), "depth_max 1.0 must be beyond")):
        with pytest.raises(InputError, match=needle):
            check_config(cfg, height=480, width=640)
    check_config(Config(keyframes=True), height=480, width=640)  # the defaults pass
    with pytest.raises(InputError, match="the grid itself is too coarse"):
        check_config(Config(keyframes=True, cell=200), height=480, width=640)
