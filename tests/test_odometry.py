"""``jaxvo.Odometry`` and ``jaxvo.run_sequence``: what users pass them as settings."""

from __future__ import annotations

import pytest

import jaxvo
from jaxvo.errors import InputError
from jaxvo.odometry import as_config


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
