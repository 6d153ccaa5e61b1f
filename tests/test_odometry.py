"""``jaxvo.Odometry`` and ``jaxvo.run_sequence``: what users pass them as settings, and the
compiled step the streaming odometry runs."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxvo
import jaxvo.odometry as odometry
from jaxvo.config import Config
from jaxvo.errors import InputError
from jaxvo.odometry import Odometry, as_config
from jaxvo.status import Status


def test_settings_may_be_a_mapping_of_config_fields():
    """``cfg={"cell": 32}`` was an AttributeError ('dict' object has no attribute 'cell')
    deep in the run; it is the Config with those fields."""
    assert as_config({"cell": 32, "keyframes": True}) == jaxvo.Config(cell=32, keyframes=True)
    cfg = jaxvo.Config(cell=24)
    assert as_config(cfg) is cfg
    odo = jaxvo.Odometry("tum_fr3", cfg={"cell": 32})
    assert odo.cfg == jaxvo.Config(cell=32)


def test_a_mapping_meets_the_config_checks_before_any_work():
    seq = jaxvo.make_sequence("static", frames=3, seed=0)
    with pytest.raises(InputError, match="cell"):
        jaxvo.run_sequence(seq, cfg={"cell": 1})
    with pytest.raises(TypeError, match="Config has no field 'cel'"):
        jaxvo.run_sequence(seq, cfg={"cel": 16})
    with pytest.raises(TypeError, match="cfg must be a jaxvo.Config or a mapping"):
        jaxvo.Odometry("tum_fr3", cfg=16)


@pytest.fixture(scope="module")
def seq():
    """test_pipeline.py's and test_keyframe.py's sequence at its first 6 frames: Odometry
    with Config() or Config(keyframes=True) on its 640x480 images runs the exported step
    those tests (and every default ``jaxvo run``) compile, so only jit_step compiles here."""
    full = jaxvo.make_sequence("handheld_slow", frames=12, seed=3)
    return full.intrinsics, list(full)[:6]


def run(cfg: Config, seq, monkeypatch, *, exported: bool):
    """Odometry over ``seq``, its step exported or :func:`jit_step` as it is."""
    assert jax.config.jax_compilation_cache_dir  # the session's cache (conftest): exported
    if not exported:
        monkeypatch.setattr(odometry, "exported_program", lambda *a, **k: None)
    intrinsics, frames = seq
    odo = Odometry(intrinsics, cfg=cfg, seed=3)
    results = [odo.process(f.bgr, f.depth, f.timestamp) for f in frames]
    monkeypatch.undo()
    return odo, results


@pytest.mark.parametrize("keyframes", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_the_exported_step_gives_the_bits_of_jit_step(keyframes, seq, monkeypatch):
    """The step exported in the compile cache (what a later process loads without tracing
    it) gives the bits of jit_step called as it is, frame by frame."""
    pytest.importorskip("flatbuffers")
    cfg = Config(keyframes=keyframes)
    odo_a, exported = run(cfg, seq, monkeypatch, exported=True)
    odo_b, plain = run(cfg, seq, monkeypatch, exported=False)
    # the exported program (jitted, traced once over the frames) against jit_step's closure
    assert odo_a._step._cache_size() == 1 and not hasattr(odo_b._step, "lower")
    assert sum(r.status == Status.OK for r in plain) >= 3  # motions were estimated
    for a, b in zip(exported, plain, strict=True):
        np.testing.assert_array_equal(a.T_w_c, b.T_w_c)  # bit for bit
        assert a.status == b.status
        jax.tree.map(np.testing.assert_array_equal, a.output, b.output)
