"""Configuration of the whole pipeline.

Two objects, following the house style:

* :class:`Config` is a frozen dataclass of plain Python values: what a user sets, every
  field with its default. Each side reads its own part of it: the host's grid flow
  :attr:`Config.flow` (a :class:`FlowOptions`: the LK, depth and keyframe-tracking settings,
  which also key a study's flow cache), the jitted step :attr:`Config.step` (a
  :class:`StepOptions`, a static argument: everything that sets an array shape or a loop
  trip count; changing it recompiles the step, changing a flow setting does not).
* :class:`Params` is a ``NamedTuple`` of numeric values that a parameter study sweeps. Its
  fields may be Python floats or JAX arrays; ``jax.vmap`` can batch any of them without a
  recompile. :func:`default_params` gives the thesis's values.

Units: metres, pixels, frames.
"""

from __future__ import annotations

import dataclasses
import operator
from typing import NamedTuple


@dataclasses.dataclass(frozen=True)
class Config:
    """Every setting of the odometry that is no number a study sweeps: the host flow's
    (:attr:`flow`) and the step's (:attr:`step`, static under ``jax.jit``)."""

    # --- grid-based optical flow (thesis section 2.2) ---
    cell: int = 16  # grid cell size in pixels (thesis: 16 x 16)
    # The thesis ran mexopencv's LK defaults (window 21, 3 levels); on a 2-core host those
    # cost ~3x more per pair (fwd + bwd, 1200 points) for ~3 % more valid points.
    lk_window: int = 9  # Lucas-Kanade window side, pixels
    lk_levels: int = 2  # pyramid levels above the base image
    # when the last pair's median track was longer than this, LK takes one level more
    # (pixels). Fast hand-held motion (7-Scenes at every 4th frame, ~30 px a frame) kept
    # 22 % fewer tracks with 2 levels than with 3 (296 against 378 a pair; ATE 24.8 against
    # 19.9 mm); a third level always cost fixed_camera_2 1-4 frames of its 89 with the
    # right number of motions (seeds 0-2) and 0.3-0.6 ms a pair
    lk_fast_px: float = 8.0
    patch: int = 7  # side of the patches compared by the similarity check, pixels
    lk_iters: int = 10  # most Lucas-Kanade iterations per pyramid level
    lk_eps: float = 0.03  # LK stops once an update is shorter than this, pixels
    fb_max: float = 1.0  # largest forward-backward (bi-directional) error kept, pixels
    min_similarity: float = 0.8  # smallest patch correlation coefficient kept (-1..1)
    depth_min: float = 0.2  # nearest depth reading trusted, metres
    depth_max: float = 10.0  # farthest depth reading trusted, metres
    depth_jump: float = 0.05  # largest depth change within 3x3 pixels, fraction of the depth
    fill_radius: int = 2  # holes are filled from the (2r+1)^2 neighbourhood, pixels
    fill_min_valid: int = 6  # fewest valid neighbours (of (2r+1)^2 - 1) needed to fill a hole
    depth_smooth: bool = True  # also average valid depth over agreeing (2r+1)^2 windows
    # each cell's grid point at its most trackable pixel with depth (host.flow.textured_points)
    # instead of its centre, which on a wall or floor gives LK nothing to follow
    textured_points: bool = False

    # --- spatial segmentation (thesis chapter 3, Algorithms 1 and 2) ---
    # H, the most hypotheses a frame pair may take: a cap. The search stops earlier, once
    # the points are explained (Params.s_min) or too few are left unexplained, so 10, 20
    # and 40 gave bit-identical runs in 35 of 36 cells of examples/thesis_parameters.toml
    num_hypotheses: int = 20
    sample_size: int = 4  # m, points per minimal sample
    sample_radius: int = 3  # neighbourhood of the seed point, in grid cells
    # candidate samples drawn (vmapped) per hypothesis step; on the synthetic scenes the
    # first verified one is nearly always among the first 8 (16 gave identical results)
    num_candidates: int = 8
    # fixed trip count of the inlier refinement loop; the clusters are refined jointly on
    # all points afterwards, so 2 trips score as 4 did (F within 0.01) at half the cost
    refine_iters: int = 2
    # refinement of each cluster's motion (Algorithm 2): 2 and 3 trips score the same on the
    # synthetic scenes; 1 trip let fixed_camera_2 lose its background in one run
    cluster_refine_iters: int = 2
    max_segments: int = 8  # most distinct motions kept per frame

    # --- temporal segmentation (thesis chapter 4, Algorithm 3) ---
    max_ids: int = 8  # identifiers (m of section 4.1); identifier 1 is the static background
    match_window: int = 5  # tMinSize: previous frames the label matching looks back over

    # --- ego-motion ---
    # robust re-weighting iterations of the ego-motion, its support growing with the fit
    # (egomotion.fit_egomotion; as many fits as the 1 + 5 before the support grew)
    ego_iters: int = 6
    # Gauss-Newton steps on the image-plane and depth errors after the 3D fit
    # (egomotion.refine_reprojection; 0 turns it off)
    ego_reprojection_iters: int = 3

    # --- sensor noise (jaxvo.core.noise) ---
    # calibrate the noise online (Params.noise_rate a frame, 0 leaves it as given). Off, the
    # step does not compile the calibration (two masked quantiles a frame): it did not pay
    # on the validation split (docs/report/robustness.md), and a study that sweeps
    # noise_rate turns it on
    noise_calibration: bool = False

    # --- frame-to-keyframe tracking (jaxvo.core.keyframe, our addition) ---
    # the ego-motion also fits the keyframe's static grid points tracked into the current
    # image (jaxvo.host.keyframes.KeyframeTracker), so that drift accrues per keyframe
    keyframes: bool = False
    # a new keyframe is taken when fewer than this fraction of the keyframe's points that
    # its first pair tracked are still tracked
    keyframe_overlap: float = 0.7
    # the keyframe's points are every keyframe_stride-th grid row and column (LK per point
    # is most of the cost; on the dev split 2 scored as well as 1 or better: ATE 15.06,
    # 17.18, 19.91 mm against 15.82-16.86, 18.41-19.21, 19.91-20.41 mm at every 1st, 2nd, 4th frame)
    keyframe_stride: int = 2
    # the local window: the latest keyframes whose poses and points are refined together
    # each time a keyframe is taken (jaxvo.core.keyframe); 1: the latest keyframe alone.
    # 4: 6 (with more frequent keyframes) was no better on the development frames
    keyframe_window: int = 4
    # Levenberg-Marquardt iterations of the window's refinement; not tuned (10 gave the
    # same ATE in the one check made, docs/report/keyframes.md has the window's figures)
    keyframe_iters: int = 5

    @property
    def flow(self) -> FlowOptions:
        """The settings the host's grid flow and keyframe tracker read."""
        return _view(FlowOptions, self)

    @property
    def step(self) -> StepOptions:
        """The settings the jitted step reads: its static argument."""
        return _view(StepOptions, self)


# Each side's options: the fields of Config that one side reads, without defaults of their
# own (Config holds each default once; build them with Config(...).flow / .step). A field
# both sides read (the grid cell, the keyframe window) is in both. Reading a field the
# options lack is an AttributeError, so the lists cannot fall behind the code.


@dataclasses.dataclass(frozen=True)
class FlowOptions:
    """What the host's grid flow (:mod:`jaxvo.host.flow`, :mod:`jaxvo.host.depth`) and
    keyframe tracker (:mod:`jaxvo.host.keyframes`) read of a :class:`Config`: a study's flow
    cache is keyed by them. See :class:`Config` for each field."""

    cell: int
    lk_window: int
    lk_levels: int
    lk_fast_px: float
    patch: int
    lk_iters: int
    lk_eps: float
    fb_max: float
    min_similarity: float
    depth_min: float
    depth_max: float
    depth_jump: float
    fill_radius: int
    fill_min_valid: int
    depth_smooth: bool
    textured_points: bool
    sample_size: int  # a pair with fewer valid vectors than a sample needs is dropped
    keyframes: bool
    keyframe_overlap: float
    keyframe_stride: int
    keyframe_window: int


@dataclasses.dataclass(frozen=True)
class StepOptions:
    """What the jitted per-frame step (:mod:`jaxvo.core`) reads of a :class:`Config`: its
    static argument (shapes, trip counts, switches), so that a flow setting never
    recompiles it. See :class:`Config` for each field."""

    cell: int
    num_hypotheses: int
    sample_size: int
    sample_radius: int
    num_candidates: int
    refine_iters: int
    cluster_refine_iters: int
    max_segments: int
    max_ids: int
    match_window: int
    ego_iters: int
    ego_reprojection_iters: int
    noise_calibration: bool
    keyframes: bool
    keyframe_stride: int
    keyframe_window: int
    keyframe_iters: int


def _view(options: type, cfg: Config):
    """``options`` (:class:`FlowOptions` or :class:`StepOptions`) with ``cfg``'s values."""
    return options(**{f.name: getattr(cfg, f.name) for f in dataclasses.fields(options)})


# Config fields that are gone, and what replaced them: Config(window=5) and a study's
# `window = 5` are told this instead of Python's "unexpected keyword argument"
REMOVED_CONFIG = {
    "window": "the consecutive-frame window was removed (issue 21): Config(keyframes=True) "
              "refines a window over the latest keyframes instead (Config.keyframe_window of "
              "them; --keyframes on the command line)",
}


def _checked_init(init):
    """``Config.__init__`` saying, for a field it does not have, what replaced it
    (:data:`REMOVED_CONFIG`) or which fields are near in name."""
    import functools

    @functools.wraps(init)
    def __init__(self, *args, **kwargs):
        known = {f.name for f in dataclasses.fields(Config)}
        for name in kwargs:
            if name not in known:
                import difflib

                near = difflib.get_close_matches(name, sorted(known), n=3)
                raise TypeError(f"Config has no field {name!r}: " + (
                    REMOVED_CONFIG.get(name) or ("did you mean " + " or ".join(near) + "?"
                                                 if near else "see jaxvo.Config's fields")))
        init(self, *args, **kwargs)

    return __init__


Config.__init__ = _checked_init(Config.__init__)


class Params(NamedTuple):
    """Numeric settings a parameter study may batch over (any field may be an array).

    What each field still changes is measured by ``bench/params_effect.py``
    (``docs/report/params_effect.md``: six built-in scenes, each field halved and doubled):
    ``confidence``, ``pixel_sigma``, ``cluster_min_samples`` and the evidence fields move
    the moving-object F-measure (by 0.07-0.9), ``noise_rate`` and ``confidence`` the ATE;
    ``lam``, ``delta``, ``cluster_eps`` and ``min_segment_points`` change labels in some
    frames and F by 0.01-0.02; ``s_min``, ``min_match_corr``, ``max_age`` and
    ``min_static_points`` change labels or statuses in some frames but no score;
    ``id_retention`` changes nothing there (see its comment).
    """

    # spatial segmentation
    lam: float = 1e3  # lambda of the entropy, thesis eq. (3.1), 1/m^2
    delta: float = 1e-2  # delta of the entropy, thesis eq. (3.1)
    # stop when the mean entropy falls below this (Algorithm 1, line 3). A fully explained
    # point still has entropy 1 - exp(-delta) = 0.00995, so the rule can only fire above
    # that floor; a slow object on a tenth of the image keeps the mean near 0.02 (0.05 here
    # stopped the search before the object was sampled; 0.012 and 0.005 score the same).
    # With noise the mean stays above it, so the search also ends once at most
    # min_segment_points valid points are inliers of no hypothesis; 0 runs all H trips
    s_min: float = 0.012
    # confidence of every statistical test against the sensor noise model (jaxvo.core.noise):
    # a point is an inlier of a motion when its normalised residual is within the
    # chi-square(3) quantile at this confidence; a minimal sample fits one motion when its
    # points' residuals sum within chi-square(3 m - 6)
    confidence: float = 0.99
    cluster_eps: float = 0.5  # DBSCAN radius on the inlier-set (Jaccard) distance
    cluster_min_samples: float = 1.0  # DBSCAN core-point threshold (count, incl. itself)
    min_segment_points: float = 12.0  # N_threshold of Algorithm 2, grid points

    # sensor noise (jaxvo.core.noise): the values a sequence starts from, a little above the real
    # development frames' noise measured against ground truth (7-Scenes frames 0-149: 0.75
    # px across the ray, 0.9-1.3e-3 z^2 a depth reading along it; bench/calibrate_noise.py):
    # a start below the noise splits the background into regional segments, a start above
    # it only merges slow motions for the first frames. With Config.noise_calibration the
    # pipeline calibrates both online from the background's residuals, moving log(value) by
    # noise_rate a frame (without it, noise_rate has no effect). Off by default: at 0.2 it
    # did not pay on the validation split
    # (7-Scenes frames 150-299 ATE 33.2/32.0/24.4 mm at every 1st/2nd/4th frame against
    # 24.3/24.5/25.8 off; TUM people covered 26.9 % against 48.8 %; docs/report/robustness.md)
    pixel_sigma: float = 0.75  # tracker noise across the viewing ray, pixels per axis
    depth_coeff: float = 1.5e-3  # depth noise along the ray over z^2, a reading, 1/m
    noise_rate: float = 0.0

    # temporal segmentation
    min_match_corr: float = 0.3  # weakest correlation (eq. 4.1) that still counts as a match
    # saturation of the grid-model age, frames: a new motion shows in the temporal labels
    # after about this many frames, a stopped object turns static after as many
    max_age: float = 15.0
    # frames before an unseen identifier may be reused. It only matters once all max_ids
    # identifiers have been used and a new motion needs one (objects that come and go
    # over a long sequence): on the built-in scenes it changes no bit of any run
    id_retention: float = 15.0
    # moving evidence of a cell (evidence.evidence_delta, evidence.update_evidence): a
    # point that moves has residuals about evidence_effect times the noise; one frame
    # shifts the log-odds by at most evidence_step; the evidence decays by evidence_decay
    # a frame and stays within +-(logit(confidence) + evidence_margin); a cell is reported
    # moving once its posterior exceeds `confidence`. The bound follows the confidence:
    # a fixed bound of 6 (the same at 0.99) left nothing ever reported moving at
    # confidence 0.999, whose log-odds is 6.9
    evidence_effect: float = 3.0
    evidence_step: float = 3.0
    evidence_decay: float = 0.9
    evidence_margin: float = 1.4

    # ego-motion; also the fewest points any fit of the camera's motion is made from
    # (jaxvo.core.robust.enough_points)
    min_static_points: float = 12.0  # fewer static points than this: the frame is skipped

    # the background choice (jaxvo.core.background). Both were set at 0.1 when the choice
    # was written and have not been swept since (params_effect.md predates them as fields):
    # an order of magnitude below the full weight, so that they break ties without deciding.
    # A point not yet established as background or as moving (new in view, or its
    # evidence faded) weighs this much in the background's support against one established
    # as background: new surface can support the background, the established decides.
    unestablished_weight: float = 0.1
    # a segment's support counts this much (plus the share of it the predicted camera
    # motion explains) even when none of it follows the prediction, so that a wrong
    # prediction (a sudden camera move: nothing follows it) leaves the choice to the support
    unpredicted_support: float = 0.1
    # spatial segmentation: two motions are the same motion found twice when one moves the
    # other's points to within this share of the inlier test of where the other does; a
    # quarter: the gap is a fraction of the noise, so a small object whose motion differs
    # from the camera's by less than the noise at its depth is not merged into it
    same_place: float = 0.25
    # depth order (jaxvo.core.background.depth_order): the share of decisive neighbour pairs
    # across a boundary between two motions in which the static side lies behind, measured
    # on the development composites (86-89 % of 4557 and 1404 such pairs, three_boxes and
    # fixed_camera_2, frames 0-149); each net pair is worth logit(order_reliability)
    order_reliability: float = 0.85


def default_params() -> Params:
    """The thesis's defaults (lambda 1e3, delta 1e-2), the rest tuned on synthetic scenes."""
    return Params()


def params_as_arrays(params: Params) -> Params:
    """Float32 arrays for every field, so the values are traced rather than baked in."""
    import jax.numpy as jnp  # here, so that host-only commands (jaxvo eval) never load JAX

    return Params(*(jnp.asarray(v, jnp.float32) for v in params))


# Smallest grid cell checked by check_config, pixels: a 4-pixel grid already tracks 16
# times the points of the thesis's 16-pixel one (19200 on a 640x480 image) and costs about
# as much more per frame; below it the points crowd inside one LK window and patch.
MIN_CELL = 4


# The values each Params field can take: (lowest, lowest allowed?, highest, highest
# allowed?), None for no bound. Outside them a run does not fail, it quietly reports
# nothing (confidence 1: an infinite moving threshold) or NaN tests (confidence 1.5).
_PARAM_RANGES = {
    "lam": (0.0, False, None, False),
    "delta": (0.0, False, None, False),
    "s_min": (0.0, True, None, False),
    "confidence": (0.0, False, 1.0, False),
    "cluster_eps": (0.0, True, 1.0, True),
    "cluster_min_samples": (1.0, True, None, False),
    "min_segment_points": (0.0, True, None, False),
    "pixel_sigma": (0.0, False, None, False),
    "depth_coeff": (0.0, False, None, False),
    "noise_rate": (0.0, True, 1.0, True),
    "min_match_corr": (-1.0, True, 1.0, True),
    "max_age": (1.0, True, None, False),
    "id_retention": (0.0, True, None, False),
    "evidence_effect": (0.0, False, None, False),
    "evidence_step": (0.0, False, None, False),
    "evidence_decay": (0.0, True, 1.0, True),
    "evidence_margin": (0.0, True, None, False),
    "min_static_points": (0.0, True, None, False),
    "unestablished_weight": (0.0, True, 1.0, True),
    "unpredicted_support": (0.0, True, None, False),
    "same_place": (0.0, False, 1.0, True),
    "order_reliability": (0.5, False, 1.0, False),
}


def check_param(field: str, value, *, name: str | None = None) -> None:
    """Raise :class:`~jaxvo.errors.InputError` unless every entry of ``value`` (a number or
    an array of them, for a batched study) is a finite number in ``field``'s range (any
    finite number for a field without one)."""
    import numpy as np

    from jaxvo.errors import InputError

    name = name or f"Params.{field}"
    low, low_in, high, high_in = _PARAM_RANGES.get(field, (None, False, None, False))
    try:
        v = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    inside = np.ones(v.shape, bool)
    if low is not None:
        inside &= (v >= low) if low_in else (v > low)
    if high is not None:
        inside &= (v <= high) if high_in else (v < high)
    if not np.all(inside):
        span = (f"{'[' if low_in else '('}{low:g}, " if low is not None else "(-inf, ") + \
               (f"{high:g}{']' if high_in else ')'}" if high is not None else "inf)")
        bad = v[~inside].flat[0]
        raise InputError(f"{name} must be in {span}, got {bad:g}")


def check_params(params: Params, *, names: dict[str, str] | None = None) -> None:
    """:func:`check_param` for every field of ``params``."""
    for field, value in zip(Params._fields, params, strict=True):
        check_param(field, value, name=(names or {}).get(field))


def check_config(
    cfg: Config,
    *,
    height: int | None = None,
    width: int | None = None,
    names: dict[str, str] | None = None,
) -> None:
    """Raise :class:`~jaxvo.errors.InputError` for settings no run can use.

    The grid cell must be at least :data:`MIN_CELL` pixels (and leave 2 x 2 cells on the
    image, when its size is given); there must be at least one hypothesis, minimal samples
    of at least 3 points, and room for at least one segment; the keyframe window holds at
    least one keyframe, its points every stride-th grid point (with keyframes, enough of
    them for a fit when the image size is given), with no negative iteration count; every
    other whole number at its least, every float in its range (not NaN), every switch a
    bool.

    Args:
      cfg: the settings.
      height, width: the image size, pixels, when known.
      names: what to call a field in the message (e.g. ``{"cell": "--cell"}`` on the command
        line); others are named ``Config.<field>``.
    """
    from jaxvo.errors import InputError

    def name(field: str) -> str:
        return (names or {}).get(field, f"Config.{field}")

    for field, least, unit in _CONFIG_LEAST:
        value = getattr(cfg, field)
        try:
            whole = operator.index(value)  # Python and NumPy integers, not floats
        except TypeError:
            raise InputError(f"{name(field)} must be a whole number, got {value!r}") from None
        if whole < least:
            raise InputError(f"{name(field)} must be at least {least} {unit}, got {value}")
    for field, (low, low_in, high, high_in) in _CONFIG_RANGES.items():
        value = getattr(cfg, field)
        ok = isinstance(value, int | float) and not isinstance(value, bool) or (
            hasattr(value, "dtype") and getattr(value, "ndim", 1) == 0)
        v = float(value) if ok else float("nan")
        inside = (v >= low if low_in else v > low) and (high is None or (
            v <= high if high_in else v < high))
        if not inside:  # also NaN, and what is no number
            span = f"{'[' if low_in else '('}{low:g}, " + (
                f"{high:g}{']' if high_in else ')'}" if high is not None else "inf)")
            raise InputError(f"{name(field)} must be a number in {span}, got {value!r}")
    if not cfg.depth_max > cfg.depth_min:
        raise InputError(f"{name('depth_max')} {cfg.depth_max} must be beyond "
                         f"{name('depth_min')} {cfg.depth_min}")
    for field in ("depth_smooth", "textured_points", "noise_calibration", "keyframes"):
        if not isinstance(getattr(cfg, field), bool | np_bool()):
            raise InputError(f"{name(field)} must be True or False, got {getattr(cfg, field)!r}")
    if height is not None and width is not None and min(height, width) // cfg.cell < 2:
        raise InputError(
            f"{name('cell')} {cfg.cell} leaves fewer than 2 x 2 grid cells on the "
            f"{width}x{height} image: at most {min(height, width) // 2} pixels"
        )
    if cfg.keyframes and height is not None and width is not None:
        rows, cols = height // cfg.cell, width // cfg.cell
        kept = -(-rows // cfg.keyframe_stride) * -(-cols // cfg.keyframe_stride)
        least = int(Params().min_static_points)
        if kept < least:
            best = _largest_stride(rows, cols, least)
            raise InputError(
                f"{name('keyframe_stride')} {cfg.keyframe_stride} keeps {kept} of the "
                f"{rows}x{cols} grid's points in a keyframe, fewer than the {least} a fit of "
                "the camera's motion needs (Params.min_static_points): " + (
                    f"at most {best}" if best else f"the grid itself is too coarse: a smaller "
                    f"{name('cell')}"))


def np_bool():
    """NumPy's bool type (a ``Config`` built from arrays may hold one)."""
    import numpy as np

    return np.bool_


def _largest_stride(rows: int, cols: int, least: int) -> int:
    """The largest keyframe stride that keeps ``least`` points of a ``rows`` x ``cols`` grid
    (0: none does)."""
    best = 0
    for stride in range(1, max(rows, cols) + 1):
        if -(-rows // stride) * -(-cols // stride) >= least:
            best = stride
    return best


# The least value of each whole-number Config field, and its unit in messages
_CONFIG_LEAST = (
    ("cell", MIN_CELL, "pixels"),
    ("num_hypotheses", 1, "hypothesis"),
    ("sample_size", 3, "points (a rigid fit needs 3)"),
    ("max_segments", 1, "segment"),
    ("keyframe_window", 1, "keyframe"),
    ("keyframe_stride", 1, "grid row and column"),
    ("keyframe_iters", 0, "iterations"),
    ("lk_window", 3, "pixels"),
    ("lk_levels", 0, "pyramid levels"),
    ("patch", 3, "pixels"),
    ("lk_iters", 1, "iteration"),
    ("fill_radius", 0, "pixels"),
    ("fill_min_valid", 0, "neighbours"),
    ("sample_radius", 1, "grid cell"),
    ("num_candidates", 1, "candidate"),
    ("refine_iters", 0, "iterations"),
    ("cluster_refine_iters", 0, "iterations"),
    ("max_ids", 1, "identifier"),
    ("match_window", 1, "frame"),
    ("ego_iters", 0, "iterations"),
    ("ego_reprojection_iters", 0, "iterations"),
)
# The values each float Config field can take: (lowest, lowest allowed?, highest, highest
# allowed?), None for no bound; NaN is refused everywhere (keyframe_overlap = nan took no
# keyframe ever, silently)
_CONFIG_RANGES = {
    "lk_fast_px": (0.0, False, None, False),
    "lk_eps": (0.0, False, None, False),
    "fb_max": (0.0, False, None, False),
    "min_similarity": (-1.0, True, 1.0, True),
    "depth_min": (0.0, True, None, False),
    "depth_max": (0.0, False, None, False),
    "depth_jump": (0.0, False, None, False),
    "keyframe_overlap": (0.0, True, 1.0, True),
}


def grid_shape(height: int, width: int, cell: int) -> tuple[int, int]:
    """Rows and columns of the flow grid for an image of ``height`` x ``width`` pixels."""
    if cell <= 0:
        raise ValueError(f"grid cell must be a positive number of pixels, got {cell}")
    rows, cols = height // cell, width // cell
    if rows < 2 or cols < 2:
        raise ValueError(f"image {width}x{height} is too small for {cell}-pixel grid cells")
    return rows, cols
