"""jaxvo: robust RGB-D visual odometry for dynamic scenes via rigid motion segmentation.

The pipeline, in the order data flows (one module per stage):

``io`` (TUM sequences, trajectories) -> ``flow`` (grid LK flow, host) ->
``spatial`` (hypotheses + clustering, device) -> ``temporal`` (label matching + grid
model, device) -> ``egomotion`` -> ``pipeline`` (per-frame step, scan, streaming) ->
``metrics`` (ATE, RPE, segmentation scores).

The public names below load lazily: ``import jaxvo`` imports neither JAX nor OpenCV, so
``jaxvo --help``, ``--version`` and one-line errors answer at once; ``jaxvo.Odometry``
imports its module (and JAX) on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# module -> the public names it defines, in the pipeline's order
_EXPORTS: dict[str, tuple[str, ...]] = {
    "jaxvo.errors": ("InputError",),
    "jaxvo.config": ("Config", "Params", "check_config", "check_params", "default_params",
                     "grid_shape", "params_as_arrays"),
    "jaxvo.status": ("Status",),
    "jaxvo.host.camera": ("PRESETS", "Intrinsics", "check_intrinsics", "preset",
                     "read_camera_file"),
    "jaxvo.host.io": ("Frame", "Trajectory", "TumSequence", "associate", "open_sequence",
                 "read_trajectory", "write_trajectory"),
    "jaxvo.synth.scenes": ("SCENARIOS", "ObjectSpec", "Scenario", "SensorOptions",
                    "SyntheticSequence", "composite_sequence", "make_sequence",
                    "write_sequence"),
    "jaxvo.host.flow": ("FrameChain", "GridFlow", "GridFlowTracker", "SequenceFlows",
                   "flows_for_sequence", "grid_flow", "sequence_flows"),
    "jaxvo.core.procrustes": ("fit_rigid", "residuals"),
    "jaxvo.core.spatial": ("Segmentation", "segment"),
    "jaxvo.core.temporal": ("TemporalOut", "TemporalState", "init_temporal", "update_temporal"),
    "jaxvo.core.egomotion": ("estimate_egomotion",),
    "jaxvo.core.lm": ("levenberg_marquardt",),
    "jaxvo.core.pipeline": ("PipelineState", "StepOutput", "batch_params", "init_pipeline",
                       "jit_step", "run_scan", "run_study", "step"),
    "jaxvo.odometry": ("FrameResult", "Odometry", "SequenceResult", "run_sequence"),
    "jaxvo.host.plugin": ("dynamic_masks", "iter_dynamic_masks"),
    "jaxvo.host.mapping": ("FusedMaps", "PointMap", "fuse_maps", "matched_poses", "write_ply"),
    "jaxvo.host.recording": ("RerunLogger",),
    "jaxvo.evaluation.metrics": ("SegmentationScores", "align_umeyama", "ate", "rpe"),
    "jaxvo.evaluation.scores": ("segmentation_scores", "trajectory_scores"),
    "jaxvo.study.spec": ("StudySpec", "load_spec", "parse_spec"),
    "jaxvo.study.runner": ("StudyResult", "run_spec"),
    "jaxvo.study.report": ("write_report",),
    "jaxvo.host.compile_cache": ("setup_compile_cache",),
}

_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_MODULE_OF)  # noqa: PLE0605 (built from _EXPORTS: one list to keep)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxvo' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))

