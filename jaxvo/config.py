"""Configuration of the whole pipeline.

Following the house style, what a user sets is frozen dataclasses of plain Python values,
one for each side that reads them, and :class:`Params` for the numbers a study sweeps:

* :class:`FlowOptions`: what the host's grid flow, depth refinement and keyframe tracker
  read (they also key a study's flow cache).
* :class:`StepOptions`: what the jitted per-frame step reads, its static argument (every
  array shape and loop trip count); changing it recompiles the step, changing a flow
  setting does not.
* :class:`SharedOptions`: the few settings both sides read (the grid cell, the sample size,
  the keyframe switches), declared once and held by both.
* :class:`Config` composes the two (``cfg.flow``, ``cfg.step``) and is built and read by
  setting name: ``Config(cell=8, keyframes=True)``, ``cfg.cell``,
  ``dataclasses.replace(cfg, cell=8)``.
* :class:`Params` is a ``NamedTuple`` of numeric values that a parameter study sweeps. Its
  fields may be Python floats or JAX arrays; ``jax.vmap`` can batch any of them without a
  recompile. :func:`default_params` gives the thesis's values.

Each setting is declared once, with its default and the values a run can use (:func:`whole`,
:func:`number`; a bool is True or False); :func:`check_config` and :func:`check_param` read
those. Units: metres, pixels, frames.
"""

from __future__ import annotations

import dataclasses
import operator
from typing import NamedTuple


class Span(NamedTuple):
    """The values a number may take: ``low`` / ``high`` (None: no bound), each included or
    not. NaN is outside every span."""

    low: float | None
    low_in: bool
    high: float | None
    high_in: bool

    def holds(self, v):
        """Whether ``v`` (a float or a numpy array of them) lies inside, elementwise."""
        ok = v == v  # NaN is outside
        if self.low is not None:
            ok = ok & ((v >= self.low) if self.low_in else (v > self.low))
        if self.high is not None:
            ok = ok & ((v <= self.high) if self.high_in else (v < self.high))
        return ok

    def __str__(self) -> str:
        low = f"{'[' if self.low_in else '('}{self.low:g}, " if self.low is not None \
            else "(-inf, "
        high = f"{self.high:g}{']' if self.high_in else ')'}" if self.high is not None \
            else "inf)"
        return low + high


ANY = Span(None, False, None, False)
POSITIVE = Span(0.0, False, None, False)
NON_NEGATIVE = Span(0.0, True, None, False)
UNIT = Span(0.0, True, 1.0, True)  # a fraction, ends included


def whole(default: int, least: int, unit: str):
    """A whole-number setting: its default and least value (``unit`` names it in messages)."""
    return dataclasses.field(default=default, metadata={"least": least, "unit": unit})


def number(default: float, span: Span):
    """A float setting: its default and the :class:`Span` of values a run can use."""
    return dataclasses.field(default=default, metadata={"span": span})


# Smallest grid cell checked by check_config, pixels: a 4-pixel grid already tracks 16
# times the points of the thesis's 16-pixel one and costs about as much more per frame;
# below it the points crowd inside one LK window and patch.
MIN_CELL = 4


@dataclasses.dataclass(frozen=True)
class SharedOptions:
    """What both sides read: the host flow and the step hold the same values."""

    cell: int = whole(16, MIN_CELL, "pixels")  # grid cell size in pixels (thesis: 16 x 16)
    # m, points per minimal sample; the host drops a pair with fewer valid vectors
    sample_size: int = whole(4, 3, "points (a rigid fit needs 3)")
    # frame-to-keyframe tracking (jaxvo.core.keyframe, our addition): the ego-motion also
    # fits the keyframe's static grid points tracked into the current image
    # (jaxvo.host.frontend.keyframes.KeyframeTracker), so that drift accrues per keyframe
    keyframes: bool = False
    # the keyframe's points are every keyframe_stride-th grid row and column: LK per point is
    # most of the cost, and 2 scored as well as 1 on the development split
    # (docs/report/keyframes.md)
    keyframe_stride: int = whole(2, 1, "grid row and column")
    # the local window: the latest keyframes whose poses and points are refined together
    # each time a keyframe is taken (jaxvo.core.keyframe); 1: the latest keyframe alone; a
    # longer window was no better on the development frames (docs/report/keyframes.md)
    keyframe_window: int = whole(4, 1, "keyframe")
    # every frame also tracks and fits the points of the window's older keyframes (their
    # poses and depths as the window refined them), not only the latest keyframe's, and
    # each keyframe point is tested over the frames at its tracks' measured noise and keeps
    # its own evidence, added to its cell's: the window as a local map (jaxvo.core.keyframe,
    # docs/report/keyframes.md)
    keyframe_track_window: bool = False


@dataclasses.dataclass(frozen=True)
class FlowOptions(SharedOptions):
    """What the host's grid flow (:mod:`jaxvo.host.frontend.flow`, :mod:`jaxvo.host.frontend.depth`) and
    keyframe tracker (:mod:`jaxvo.host.frontend.keyframes`) read: a study's flow cache is keyed by
    them (thesis section 2.2)."""

    # The thesis ran mexopencv's LK defaults (window 21, 3 levels); on a small host those
    # cost several times more per pair for few more valid points (docs/report/pipeline.md).
    lk_window: int = whole(9, 3, "pixels")  # Lucas-Kanade window side, pixels
    lk_levels: int = whole(2, 0, "pyramid levels")  # pyramid levels above the base image
    # when the last pair's median track was longer than this, LK takes one level more
    # (pixels): fast hand-held motion keeps more tracks with a third level, which costs the
    # slow sequences labels and time (docs/report/pipeline.md)
    lk_fast_px: float = number(8.0, POSITIVE)
    patch: int = whole(7, 3, "pixels")  # side of the patches the similarity check compares
    lk_iters: int = whole(10, 1, "iteration")  # most Lucas-Kanade iterations per level
    lk_eps: float = number(0.03, POSITIVE)  # LK stops once an update is shorter, pixels
    fb_max: float = number(1.0, POSITIVE)  # largest forward-backward error kept, pixels
    # smallest patch correlation coefficient kept
    min_similarity: float = number(0.8, Span(-1.0, True, 1.0, True))
    depth_min: float = number(0.2, NON_NEGATIVE)  # nearest depth reading trusted, metres
    depth_max: float = number(10.0, POSITIVE)  # farthest depth reading trusted, metres
    # largest depth change within 3x3 pixels, a fraction of the depth
    depth_jump: float = number(0.05, POSITIVE)
    fill_radius: int = whole(2, 0, "pixels")  # holes are filled from the (2r+1)^2 window
    # fewest valid neighbours (of (2r+1)^2 - 1) needed to fill a hole
    fill_min_valid: int = whole(6, 0, "neighbours")
    depth_smooth: bool = True  # also average valid depth over agreeing (2r+1)^2 windows
    # each cell's grid point at its most trackable pixel with depth (host.frontend.flow.textured_points)
    # instead of its centre, which on a wall or floor gives LK nothing to follow
    textured_points: bool = False
    # a new keyframe is taken when fewer than this fraction of the keyframe's points that
    # its first pair tracked are still tracked
    keyframe_overlap: float = number(0.7, UNIT)
    # ... and at the latest this many pairs after it was taken (0: no bound), so that a
    # keyframe whose tracked points a near mover holds is renewed while the world's points
    # leave the view (a second at 30 Hz; docs/report/separation.md)
    keyframe_max_age: int = whole(30, 0, "pairs")


@dataclasses.dataclass(frozen=True)
class StepOptions(SharedOptions):
    """What the jitted per-frame step (:mod:`jaxvo.core`) reads: its static argument
    (shapes, trip counts, switches), so that a flow setting never recompiles it."""

    # --- spatial segmentation (thesis chapter 3, Algorithms 1 and 2) ---
    # H, the most hypotheses a frame pair may take: a cap. The search stops earlier, once
    # the points are explained (Params.s_min) or too few are left unexplained, so a larger
    # cap changes almost no run (docs/report/core_decisions.md)
    num_hypotheses: int = whole(20, 1, "hypothesis")
    sample_radius: int = whole(3, 1, "grid cell")  # neighbourhood of the seed, grid cells
    # candidate samples drawn (vmapped) per hypothesis step; on the synthetic scenes the
    # first verified one is nearly always among the first few
    num_candidates: int = whole(8, 1, "candidate")
    # fixed trip count of the inlier refinement loop; the clusters are refined jointly on
    # all points afterwards, so few trips score as many do at a fraction of the cost
    refine_iters: int = whole(2, 0, "iterations")
    # refinement of each cluster's motion (Algorithm 2): one trip fewer let a fixed-camera
    # scene lose its background (docs/report/core_decisions.md)
    cluster_refine_iters: int = whole(2, 0, "iterations")
    max_segments: int = whole(8, 1, "segment")  # most distinct motions kept per frame

    # --- temporal segmentation (thesis chapter 4, Algorithm 3) ---
    # identifiers (m of section 4.1); identifier 1 is the static background
    max_ids: int = whole(8, 1, "identifier")
    # tMinSize: previous frames the label matching looks back over
    match_window: int = whole(5, 1, "frame")

    # --- ego-motion ---
    # robust re-weighting iterations of the ego-motion, its support growing with the fit
    # (egomotion.fit_egomotion)
    ego_iters: int = whole(6, 0, "iterations")
    # Gauss-Newton steps on the image-plane and depth errors after the 3D fit
    # (egomotion.refine_reprojection; 0 turns it off)
    ego_reprojection_iters: int = whole(3, 0, "iterations")

    # --- sensor noise (jaxvo.core.noise) ---
    # calibrate the noise online (Params.noise_rate a frame). Off, the step does not
    # compile the calibration: it did not pay on the validation split
    # (docs/report/robustness.md), and a study that sweeps noise_rate turns it on
    noise_calibration: bool = False

    # Levenberg-Marquardt iterations of the keyframe window's refinement; not tuned
    # (docs/report/keyframes.md)
    keyframe_iters: int = whole(5, 0, "iterations")


# Config fields that are gone, and what replaced them: Config(window=5) and a study's
# `window = 5` are told this instead of Python's "unexpected keyword argument"
REMOVED_CONFIG = {
    "window": "the consecutive-frame window was removed: Config(keyframes=True) "
              "refines a window over the latest keyframes instead (Config.keyframe_window of "
              "them; --keyframes on the command line)",
}


def config_fields() -> dict[str, dataclasses.Field]:
    """Every setting of a :class:`Config` by name, each once: those both sides read, then
    the flow's, then the step's."""
    fields = {f.name: f for f in dataclasses.fields(FlowOptions)}
    fields.update((f.name, f) for f in dataclasses.fields(StepOptions) if f.name not in fields)
    return fields


_SHARED = frozenset(f.name for f in dataclasses.fields(SharedOptions))
_FLOW = frozenset(f.name for f in dataclasses.fields(FlowOptions))
_STEP = frozenset(f.name for f in dataclasses.fields(StepOptions))


def _unknown_setting(name: str) -> TypeError:
    """What ``Config(name=...)`` is told for a setting it lacks: what replaced it
    (:data:`REMOVED_CONFIG`) or which settings are near in name."""
    import difflib

    near = difflib.get_close_matches(name, sorted(_FLOW | _STEP), n=3)
    return TypeError(f"Config has no field {name!r}: " + (
        REMOVED_CONFIG.get(name) or ("did you mean " + " or ".join(near) + "?"
                                     if near else "see jaxvo.Config's fields")))


class _Settings(type):
    """:class:`Config`'s class: a setting read off the class is its default
    (``Config.keyframes``), as on a dataclass with the settings as fields."""

    def __getattr__(cls, name: str):
        spec = config_fields().get(name)
        if spec is None:
            raise AttributeError(f"type object 'Config' has no attribute {name!r}")
        return spec.default


@dataclasses.dataclass(frozen=True, init=False)
class Config(metaclass=_Settings):
    """Every setting of the odometry that is no number a study sweeps: the host flow's
    :attr:`flow` and the step's :attr:`step` (static under ``jax.jit``).

    Built by setting name over the defaults (``Config(cell=8, keyframes=True)``) or from the
    two sides' options (``Config(flow=..., step=...)``, settings by name then replacing
    theirs), and read by setting name (``cfg.cell``; ``Config.cell``, the default): see
    :func:`config_fields`. Hashable, and equal when every setting is.
    """

    flow: FlowOptions = FlowOptions()
    step: StepOptions = StepOptions()

    def __init__(self, flow: FlowOptions | None = None, step: StepOptions | None = None,
                 **settings):
        flow = FlowOptions() if flow is None else flow
        step = StepOptions() if step is None else step
        if not isinstance(flow, FlowOptions) or not isinstance(step, StepOptions):
            raise TypeError(f"Config(flow=, step=) takes a FlowOptions and a StepOptions, got "
                            f"{type(flow).__name__} and {type(step).__name__}")
        for name in settings:
            if name not in _FLOW and name not in _STEP:
                raise _unknown_setting(name)
        if settings.keys() & _FLOW:
            flow = dataclasses.replace(flow, **{k: v for k, v in settings.items() if k in _FLOW})
        if settings.keys() & _STEP:
            step = dataclasses.replace(step, **{k: v for k, v in settings.items() if k in _STEP})
        for name in sorted(_SHARED):  # the same object passes (a NaN is for check_config)
            if getattr(flow, name) is not getattr(step, name) and \
                    getattr(flow, name) != getattr(step, name):
                raise ValueError(f"Config's flow and step disagree on {name} ("
                                 f"{getattr(flow, name)!r} against {getattr(step, name)!r}): "
                                 f"set it once, Config({name}=...)")
        object.__setattr__(self, "flow", flow)
        object.__setattr__(self, "step", step)

    def __getattr__(self, name: str):
        # only for what is not an attribute of its own: a setting, read from its side
        if name in _FLOW:
            return getattr(self.flow, name)
        if name in _STEP:
            return getattr(self.step, name)
        raise AttributeError(f"'Config' object has no attribute {name!r}")

    def as_dict(self) -> dict:
        """Every setting by name, in :func:`config_fields`' order."""
        return {name: getattr(self, name) for name in config_fields()}


class Params(NamedTuple):
    """Numeric settings a parameter study may batch over (any field may be an array).

    What each field still changes is measured by ``bench/params_effect.py``
    (``docs/report/params_effect.md``: six built-in scenes, each field halved and doubled):
    ``confidence``, ``pixel_sigma``, ``cluster_min_samples`` and the evidence fields move
    the moving-object F-measure, ``noise_rate`` and ``confidence`` the ATE; ``lam``,
    ``delta``, ``cluster_eps`` and ``min_segment_points`` change labels in some frames and F
    a little; ``s_min``, ``min_match_corr``, ``max_age`` and ``min_static_points`` change
    labels or statuses in some frames but no score; ``id_retention`` changes nothing there
    (see its comment).
    """

    # spatial segmentation
    lam: float = 1e3  # lambda of the entropy, thesis eq. (3.1), 1/m^2
    delta: float = 1e-2  # delta of the entropy, thesis eq. (3.1)
    # stop when the mean entropy falls below this (Algorithm 1, line 3). A fully explained
    # point still has entropy 1 - exp(-delta), so the rule can only fire above that floor;
    # a slow object on a tenth of the image keeps the mean just above it, and a larger
    # value stopped the search before the object was sampled (docs/report/core_decisions.md).
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

    # sensor noise (jaxvo.core.noise): the values a sequence starts from, a little above the
    # real development frames' noise measured against ground truth (bench/calibrate_noise.py):
    # a start below the noise splits the background into regional segments, a start above
    # it only merges slow motions for the first frames. With Config.noise_calibration the
    # pipeline calibrates both online from the background's residuals, moving log(value) by
    # noise_rate a frame (without it, noise_rate has no effect). Off by default: it did not
    # pay on the validation split (docs/report/robustness.md)
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
    # moving once its posterior exceeds `confidence`. The bound follows the confidence: a
    # fixed bound left nothing ever reported moving at a confidence whose log-odds exceeds it
    evidence_effect: float = 3.0
    evidence_step: float = 3.0
    evidence_decay: float = 0.9
    evidence_margin: float = 1.4

    # ego-motion; also the fewest points any fit of the camera's motion is made from
    # (jaxvo.core.robust.enough_points)
    min_static_points: float = 12.0  # fewer static points than this: the frame is skipped

    # the background choice (jaxvo.core.background). Both were set when the choice was
    # written and have not been swept since (params_effect.md predates them as fields):
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
    # on the development composites (docs/report/background.md); each net pair is worth
    # logit(order_reliability)
    order_reliability: float = 0.85


# The values each Params field can take (a field not named: any finite number). Outside
# them a run does not fail, it quietly reports nothing (confidence 1: an infinite moving
# threshold) or NaN tests (confidence above 1).
PARAM_SPANS = {
    "lam": POSITIVE,
    "delta": POSITIVE,
    "s_min": NON_NEGATIVE,
    "confidence": Span(0.0, False, 1.0, False),
    "cluster_eps": UNIT,
    "cluster_min_samples": Span(1.0, True, None, False),
    "min_segment_points": NON_NEGATIVE,
    "pixel_sigma": POSITIVE,
    "depth_coeff": POSITIVE,
    "noise_rate": UNIT,
    "min_match_corr": Span(-1.0, True, 1.0, True),
    "max_age": Span(1.0, True, None, False),
    "id_retention": NON_NEGATIVE,
    "evidence_effect": POSITIVE,
    "evidence_step": POSITIVE,
    "evidence_decay": UNIT,
    "evidence_margin": NON_NEGATIVE,
    "min_static_points": NON_NEGATIVE,
    "unestablished_weight": UNIT,
    "unpredicted_support": NON_NEGATIVE,
    "same_place": Span(0.0, False, 1.0, True),
    "order_reliability": Span(0.5, False, 1.0, False),
}


def default_params() -> Params:
    """The thesis's defaults (lambda 1e3, delta 1e-2), the rest tuned on synthetic scenes."""
    return Params()


def params_as_arrays(params: Params, device=None) -> Params:
    """Float32 arrays for every field, so the values are traced rather than baked in, on
    ``device`` (a ``jax.Device``; None: JAX's default).

    Made by NumPy and put on the device as they are: ``jnp.asarray`` compiled a conversion
    for each field in a process's first call."""
    import jax  # here, so that host-only commands (jaxvo eval) never load JAX
    import numpy as np

    return jax.device_put(Params(*(np.asarray(v, np.float32) for v in params)), device)


def check_param(field: str, value, *, name: str | None = None) -> None:
    """Raise :class:`~jaxvo.errors.InputError` unless every entry of ``value`` (a number or
    an array of them, for a batched study) is a finite number in ``field``'s span
    (:data:`PARAM_SPANS`; any finite number for a field without one)."""
    import numpy as np

    from jaxvo.errors import InputError

    name = name or f"Params.{field}"
    span = PARAM_SPANS.get(field, ANY)
    try:
        v = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    inside = span.holds(v)
    if not np.all(inside):
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

    Every setting as its declaration says (:func:`whole`: a whole number at its least;
    :func:`number`: a float in its span, not NaN; a bool: True or False); the depth band
    not empty; the keyframe window tracked only with keyframes; with the image size, 2 x 2
    grid cells on it and, with keyframes, enough points in a keyframe for a fit.

    Args:
      cfg: the settings.
      height, width: the image size, pixels, when known.
      names: what to call a field in the message (e.g. ``{"cell": "--cell"}`` on the command
        line); others are named ``Config.<field>``.
    """
    from jaxvo.errors import InputError

    def name(field: str) -> str:
        return (names or {}).get(field, f"Config.{field}")

    for field in config_fields():
        problem = setting_problem(field, getattr(cfg, field))
        if problem:
            raise InputError(f"{name(field)} {problem}")
    if cfg.keyframe_track_window and not cfg.keyframes:
        raise InputError(f"{name('keyframe_track_window')} tracks the keyframes' window: it "
                         f"needs {name('keyframes')}")
    if not cfg.depth_max > cfg.depth_min:
        raise InputError(f"{name('depth_max')} {cfg.depth_max} must be beyond "
                         f"{name('depth_min')} {cfg.depth_min}")
    if height is not None and width is not None:
        _check_image(cfg, height, width, name)


def setting_problem(field: str, value) -> str | None:
    """What is wrong with ``value`` for the setting ``field`` as its declaration says, alone
    (None: nothing); :func:`check_config` adds what the settings decide together."""
    import numpy as np

    spec = config_fields()[field]
    if isinstance(spec.default, bool):
        if not isinstance(value, bool | np.bool_):
            return f"must be True or False, got {value!r}"
    elif "least" in spec.metadata:
        try:
            whole_value = operator.index(value)  # Python and NumPy integers, not floats
        except TypeError:
            return f"must be a whole number, got {value!r}"
        if whole_value < spec.metadata["least"]:
            return f"must be at least {spec.metadata['least']} {spec.metadata['unit']}, " \
                   f"got {value}"
    elif "span" in spec.metadata:
        ok = isinstance(value, int | float) and not isinstance(value, bool) or (
            hasattr(value, "dtype") and getattr(value, "ndim", 1) == 0)
        if not (ok and spec.metadata["span"].holds(float(value))):  # also NaN, and no number
            return f"must be a number in {spec.metadata['span']}, got {value!r}"
    return None


def _check_image(cfg: Config, height: int, width: int, name) -> None:
    """The settings against the image size: 2 x 2 grid cells, and with keyframes enough
    points in a keyframe for a fit of the camera's motion."""
    from jaxvo.errors import InputError

    if min(height, width) // cfg.cell < 2:
        raise InputError(
            f"{name('cell')} {cfg.cell} leaves fewer than 2 x 2 grid cells on the "
            f"{width}x{height} image: at most {min(height, width) // 2} pixels"
        )
    if cfg.keyframes:
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


def _largest_stride(rows: int, cols: int, least: int) -> int:
    """The largest keyframe stride that keeps ``least`` points of a ``rows`` x ``cols`` grid
    (0: none does)."""
    best = 0
    for stride in range(1, max(rows, cols) + 1):
        if -(-rows // stride) * -(-cols // stride) >= least:
            best = stride
    return best


def grid_shape(height: int, width: int, cell: int) -> tuple[int, int]:
    """Rows and columns of the flow grid for an image of ``height`` x ``width`` pixels."""
    if cell <= 0:
        raise ValueError(f"grid cell must be a positive number of pixels, got {cell}")
    rows, cols = height // cell, width // cell
    if rows < 2 or cols < 2:
        raise ValueError(f"image {width}x{height} is too small for {cell}-pixel grid cells")
    return rows, cols
