"""jaxvo: robust RGB-D visual odometry for dynamic scenes via rigid motion segmentation.

The pipeline, in the order data flows (one module per stage):

``io`` (TUM sequences, trajectories) -> ``flow`` (grid LK flow, host) ->
``spatial`` (hypotheses + clustering, device) -> ``temporal`` (label matching + grid
model, device) -> ``egomotion`` -> ``pipeline`` (per-frame step, scan, streaming) ->
``metrics`` (ATE, RPE, segmentation scores).
"""

from jaxvo.camera import PRESETS, Intrinsics, preset, read_camera_file
from jaxvo.config import Config, Params, default_params, grid_shape, params_as_arrays
from jaxvo.errors import InputError
from jaxvo.flow import GridFlow, GridFlowTracker, flows_for_sequence, grid_flow
from jaxvo.io import (
    Frame,
    Trajectory,
    TumSequence,
    associate,
    open_sequence,
    read_trajectory,
    write_trajectory,
)
from jaxvo.metrics import SegmentationScores, align_umeyama, ate, rpe
from jaxvo.plugin import dynamic_masks, iter_dynamic_masks
from jaxvo.status import Status
from jaxvo.synth import (
    SCENARIOS,
    ObjectSpec,
    Scenario,
    SensorOptions,
    SyntheticSequence,
    composite_sequence,
    make_sequence,
    write_sequence,
)
from jaxvo.temporal import TemporalOut, TemporalState, init_temporal, update_temporal

__version__ = "0.1.0"

__all__ = [
    "Config",
    "InputError",
    "Intrinsics",
    "PRESETS",
    "Params",
    "Status",
    "default_params",
    "grid_shape",
    "params_as_arrays",
    "preset",
    "read_camera_file",
    # io, metrics
    "Frame",
    "SegmentationScores",
    "Trajectory",
    "TumSequence",
    "align_umeyama",
    "associate",
    "ate",
    "open_sequence",
    "read_trajectory",
    "rpe",
    "write_trajectory",
    # temporal
    "TemporalOut",
    "TemporalState",
    "init_temporal",
    "update_temporal",
    # flow
    "GridFlow",
    "GridFlowTracker",
    "flows_for_sequence",
    "grid_flow",
    # plug-in masks
    "dynamic_masks",
    "iter_dynamic_masks",
    # synthetic data
    "ObjectSpec",
    "SCENARIOS",
    "Scenario",
    "SensorOptions",
    "SyntheticSequence",
    "composite_sequence",
    "make_sequence",
    "write_sequence",
]
