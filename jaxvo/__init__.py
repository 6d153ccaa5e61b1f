"""jaxvo: robust RGB-D visual odometry for dynamic scenes via rigid motion segmentation.

The top level holds the names a user types (``__all__``: the odometry, its sequences and
settings, trajectories and their scores, studies); every other public name lives in its
subpackage, in the order data flows:

``host`` (frames and files, the grid flow with OpenCV, masks, the compile cache) ->
``core`` (the traced per-frame step: spatial and temporal segmentation, ego-motion,
keyframes; ``core.pipeline`` joins them) -> ``odometry`` (``Odometry``, ``run_sequence``)
-> ``evaluation`` (ATE, RPE, segmentation scores); beside them ``synth`` (scenes with
exact ground truth), ``study`` (studies over sequences, settings and seeds) and ``cli``
(the ``jaxvo`` command). ``docs/python.md`` lists which name lives where.

The names load lazily: ``import jaxvo`` imports neither JAX nor OpenCV, so ``jaxvo
--help``, ``--version`` and one-line errors answer at once; ``jaxvo.Odometry`` imports its
module (and JAX) on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# module -> the user-level names it gives the top level, in the pipeline's order
_EXPORTS: dict[str, tuple[str, ...]] = {
    "jaxvo.errors": ("InputError",),
    "jaxvo.config": ("Config", "Params"),
    "jaxvo.status": ("Status",),
    "jaxvo.host.frontend.camera": ("Intrinsics",),
    "jaxvo.host.readers.io": ("open_sequence", "write_trajectory"),
    "jaxvo.trajectory": ("Trajectory", "read_trajectory"),
    "jaxvo.synth.scenes": ("composite_sequence", "make_sequence", "write_sequence"),
    "jaxvo.odometry": ("Odometry", "run_sequence"),
    "jaxvo.host.writers.plugin": ("dynamic_masks",),
    "jaxvo.evaluation.metrics": ("ate", "rpe"),
    "jaxvo.evaluation.scores": ("segmentation_scores", "trajectory_scores"),
    "jaxvo.study.spec": ("load_spec",),
    "jaxvo.study.runner": ("run_spec",),
}

_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_MODULE_OF)  # noqa: PLE0605 (built from _EXPORTS: one list to keep)

# names the top level once held and gave up to their subpackage: still importable from
# here, with a DeprecationWarning saying where they live, so that a script using them goes
# on; they are no current API (not in __all__ nor dir)
_MOVED: dict[str, str] = {
    "setup_compile_cache": "jaxvo.host.services.compile_cache",
    "RerunLogger": "jaxvo.host.writers.recording",
    "fuse_maps": "jaxvo.host.writers.mapping",
    "matched_poses": "jaxvo.host.writers.mapping",
    "write_ply": "jaxvo.host.writers.mapping",
}


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None and name in _MOVED:
        import sys
        import warnings

        # `from jaxvo import x` asks twice, importlib's hasattr first: the user's line warns
        if not sys._getframe(1).f_code.co_filename.startswith("<frozen importlib"):
            warnings.warn(f"jaxvo.{name} moved to {_MOVED[name]}.{name}; import it from there "
                          f"(from {_MOVED[name]} import {name})", DeprecationWarning,
                          stacklevel=2)
        return getattr(importlib.import_module(_MOVED[name]), name)  # not kept: each use warns
    if module is None:
        raise AttributeError(f"module 'jaxvo' has no attribute {name!r} (the top level holds "
                             "the names a user types; the others live in their subpackage, "
                             "docs/python.md says which)")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

