"""``jaxvo``'s top level: names that moved to a subpackage still import, with a warning."""

from __future__ import annotations

import importlib

import pytest
from conftest import python_code

import jaxvo

MOVED = {
    "setup_compile_cache": "jaxvo.host.services.compile_cache",
    "RerunLogger": "jaxvo.host.writers.recording",
    "fuse_maps": "jaxvo.host.writers.mapping",
    "matched_poses": "jaxvo.host.writers.mapping",
    "write_ply": "jaxvo.host.writers.mapping",
}


@pytest.mark.parametrize("name, module", sorted(MOVED.items()))
def test_a_moved_name_still_imports_and_says_where_it_lives(name, module):
    """Scripts that used these from ``jaxvo`` stopped at import when they left the top
    level; they get the same object and a DeprecationWarning naming its module."""
    with pytest.warns(DeprecationWarning, match=rf"jaxvo\.{name} moved to {module}\.{name}"):
        value = getattr(jaxvo, name)
    assert value is getattr(importlib.import_module(module), name)
    assert name not in jaxvo.__all__ and name not in dir(jaxvo)


def test_a_from_import_of_a_moved_name_warns_and_loads_no_jax_before():
    code = ("import sys, warnings\n"
            "import jaxvo\n"
            "assert 'jax' not in sys.modules\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            "    from jaxvo import write_ply\n"
            "ours = [x for x in w if 'jaxvo.write_ply moved' in str(x.message)]\n"
            "assert [x.category for x in ours] == [DeprecationWarning], w\n"
            "assert 'jaxvo.host.writers.mapping' in str(ours[0].message)\n")
    done = python_code(code)
    assert done.returncode == 0, done.stderr[-2000:]


def test_an_unknown_name_is_still_an_attribute_error():
    with pytest.raises(AttributeError, match="docs/python.md"):
        jaxvo.no_such_name  # noqa: B018
