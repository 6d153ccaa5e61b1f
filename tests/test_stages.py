"""The stage contract of the traced step (jaxvo.core.pipeline): every stage is called the
same way, its inputs are one NamedTuple built by keyword, and the step reads as the
pipeline. These read the source and the signatures; what each stage computes is tested in
its own module's tests."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest

import jaxvo.core.pipeline as pipeline
from jaxvo.core.background import update_background
from jaxvo.core.egomotion import update_egomotion
from jaxvo.core.evidence import moving_evidence
from jaxvo.core.keyframe import keyframe_support, update_keyframe
from jaxvo.core.occlusion import update_occlusion
from jaxvo.core.temporal import update_temporal

PIPELINE = Path(pipeline.__file__)

# stages that carry a state: update_x(state, XInputs, params, *, cfg, grid) -> (state, out)
STATEFUL = (update_occlusion, update_background, update_temporal, update_keyframe,
            keyframe_support)
# one frame's measurements, with nothing to carry: x(XInputs, params, *, cfg, grid) -> out
MEASURES = (moving_evidence,)


def _positional(fn):
    return [p.name for p in inspect.signature(fn).parameters.values()
            if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]


def _keyword(fn):
    return {p.name for p in inspect.signature(fn).parameters.values()
            if p.kind == p.KEYWORD_ONLY}


@pytest.mark.parametrize("fn", STATEFUL, ids=lambda f: f.__name__)
def test_every_stage_with_a_state_takes_state_inputs_params_then_cfg_and_grid(fn):
    assert _positional(fn) == ["state", "inputs", "params"]
    assert {"cfg", "grid"} <= _keyword(fn)


@pytest.mark.parametrize("fn", MEASURES, ids=lambda f: f.__name__)
def test_every_measurement_takes_inputs_params_then_cfg_and_grid(fn):
    assert _positional(fn) == ["inputs", "params"]
    assert {"cfg", "grid"} <= _keyword(fn)


def test_the_ego_motion_takes_state_inputs_params():
    assert _positional(update_egomotion) == ["state", "inputs", "params"]


def _positional_builds(tree: ast.AST) -> list[str]:
    """Calls of a name ending in 'Inputs' with a positional argument: 'Name (line)'."""
    found = []
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id.endswith("Inputs") and node.args):
            found.append(f"{node.func.id} (line {node.lineno})")
    return found


def test_the_positional_build_check_finds_one():
    tree = ast.parse("a = EgoInputs(pts, w)\nb = EgoInputs(pts=pts, weights=w)\n")
    assert _positional_builds(tree) == ["EgoInputs (line 1)"]


def test_the_pipeline_builds_every_stage_input_by_keyword():
    """Two (n,) bool fields swapped in a positional build compile silently."""
    assert _positional_builds(ast.parse(PIPELINE.read_text())) == []


def test_the_step_reads_as_the_pipeline_in_about_forty_lines():
    fn = next(n for n in ast.walk(ast.parse(PIPELINE.read_text()))
              if isinstance(n, ast.FunctionDef) and n.name == "step")
    body = fn.body[1:] if isinstance(fn.body[0], ast.Expr) else fn.body  # after the docstring
    lines = body[-1].end_lineno - body[0].lineno + 1
    assert lines <= 45, f"step's body is {lines} lines"


def test_the_step_refuses_keyframes_without_their_flow():
    import numpy as np

    from jaxvo.config import Config, Params
    from jaxvo.core.inputs import invalid_flow

    cfg = Config(keyframes=True).step
    grid = (4, 5)
    state = pipeline.init_pipeline(cfg=cfg, grid=grid)
    flow = invalid_flow(np.zeros((grid[0] * grid[1], 2), np.float32))
    with pytest.raises(ValueError, match="KeyframeFlow"):
        pipeline.step(state, flow, None, Params(), cfg=cfg, grid=grid)


def test_the_compiled_entry_points_refuse_a_whole_config():
    """A whole Config as the static argument compiled a program per host setting (an LK
    window): the step's entry points take its StepOptions (Config.step) alone."""
    from jaxvo.config import Config

    with pytest.raises(TypeError, match="pass cfg.step"):
        pipeline._step_options(Config())
    assert pipeline._step_options(Config().step) == Config().step
