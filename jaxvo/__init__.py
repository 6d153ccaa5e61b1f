"""jaxvo: robust RGB-D visual odometry for dynamic scenes via rigid motion segmentation.

The pipeline, in the order data flows (one module per stage):

``io`` (TUM sequences, trajectories) -> ``flow`` (grid LK flow, host) ->
``spatial`` (hypotheses + clustering, device) -> ``temporal`` (label matching + grid
model, device) -> ``egomotion`` -> ``pipeline`` (per-frame step, scan, streaming) ->
``metrics`` (ATE, RPE, segmentation scores).
"""

from jaxvo.camera import PRESETS, Intrinsics, check_intrinsics, preset, read_camera_file
from jaxvo.compile_cache import setup_compile_cache
from jaxvo.config import (
    Config,
    Params,
    check_config,
    check_params,
    default_params,
    grid_shape,
    params_as_arrays,
)
from jaxvo.egomotion import estimate_egomotion
from jaxvo.errors import InputError
from jaxvo.evaluation import segmentation_scores, trajectory_scores
from jaxvo.flow import (
    FrameChain,
    GridFlow,
    GridFlowTracker,
    SequenceFlows,
    flows_for_sequence,
    grid_flow,
    sequence_flows,
)
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
from jaxvo.odometry import FrameResult, Odometry, SequenceResult, run_sequence
from jaxvo.pipeline import (
    PipelineState,
    StepOutput,
    batch_params,
    init_pipeline,
    jit_step,
    run_scan,
    run_study,
    step,
)
from jaxvo.plugin import dynamic_masks, iter_dynamic_masks
from jaxvo.procrustes import fit_rigid, residuals
from jaxvo.spatial import Segmentation, segment
from jaxvo.status import Status
from jaxvo.study import StudyResult, StudySpec, load_spec, parse_spec, run_spec
from jaxvo.study_report import write_report
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
from jaxvo.window import (
    WindowOut,
    WindowState,
    init_window,
    levenberg_marquardt,
    update_window,
    window_trajectory,
)

__version__ = "0.1.0"

__all__ = [
    "PRESETS",
    "SCENARIOS",
    "Config",
    # io, metrics
    "Frame",
    "FrameChain",
    "FrameResult",
    # flow
    "GridFlow",
    "GridFlowTracker",
    "InputError",
    "Intrinsics",
    # synthetic data
    "ObjectSpec",
    "Odometry",
    "Params",
    "PipelineState",
    "Scenario",
    "Segmentation",
    "SegmentationScores",
    "SensorOptions",
    "SequenceFlows",
    "SequenceResult",
    "Status",
    "StepOutput",
    # studies
    "StudyResult",
    "StudySpec",
    "SyntheticSequence",
    # temporal
    "TemporalOut",
    "TemporalState",
    "Trajectory",
    "TumSequence",
    # sliding-window refinement
    "WindowOut",
    "WindowState",
    "align_umeyama",
    "associate",
    "ate",
    "batch_params",
    "check_config",
    "check_intrinsics",
    "check_params",
    "composite_sequence",
    "default_params",
    # plug-in masks
    "dynamic_masks",
    "estimate_egomotion",
    "fit_rigid",
    "flows_for_sequence",
    "grid_flow",
    "grid_shape",
    "init_pipeline",
    "init_temporal",
    "init_window",
    "iter_dynamic_masks",
    "jit_step",
    "levenberg_marquardt",
    "load_spec",
    "make_sequence",
    "open_sequence",
    "params_as_arrays",
    "parse_spec",
    "preset",
    "read_camera_file",
    "read_trajectory",
    "residuals",
    "rpe",
    "run_scan",
    "run_sequence",
    "run_spec",
    "run_study",
    "segment",
    "segmentation_scores",
    "sequence_flows",
    "setup_compile_cache",
    "step",
    "trajectory_scores",
    "update_temporal",
    "update_window",
    "window_trajectory",
    "write_report",
    "write_sequence",
    "write_trajectory",
]
