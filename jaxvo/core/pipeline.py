"""The per-frame step of the odometry, and the whole-sequence scan built from it (device side).

One step reads top to bottom as the thesis's pipeline (Fig. 1.2), a chain of stage updates
``update_x(state_x, XInputs(...), params, *, cfg, grid) -> (state_x, out_x)`` (a stage with
nothing to carry, one frame's measurement: ``x(XInputs(...), params, *, cfg, grid) ->
out_x``), each stage's state its own and each stage's inputs one typed value built here by
keyword:

  the frame's points and their noise, built once (:func:`jaxvo.core.points.frame_points`)
  -> spatial segmentation (Algorithms 1, 2; :mod:`jaxvo.core.spatial`)
  -> the occlusion memory (:func:`jaxvo.core.occlusion.update_occlusion`)
  -> the segments' identifiers (Algorithm 3; :func:`jaxvo.core.identifiers.identify`) and
     the background among them (:func:`jaxvo.core.background.update_background`)
  -> ego-motion from the background -> camera pose chain (:mod:`jaxvo.core.egomotion`)
  -> moving evidence under the ego-motion (:func:`jaxvo.core.evidence.moving_evidence`)
     and, with keyframes, over the frames since the keyframe (:mod:`jaxvo.core.separation`)
  -> labels: the dual-mode grid model, compensated (:func:`jaxvo.core.temporal.update_temporal`)
  -> sensor noise (:mod:`jaxvo.core.noise`)
  -> keyframes and their local window (:mod:`jaxvo.core.keyframe`, ``cfg.keyframes``).

When a stage fails the frame is skipped: the pose is carried over and the status records
why (Fig. 1.2). The step is a pure function of ``(state, flow, key)``, so the same code runs
frame by frame (streaming, :mod:`jaxvo.odometry`), inside one ``lax.scan`` over a recorded
sequence (:func:`run_scan`), and under ``vmap`` over seeds and parameters
(:func:`run_study`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.background import (
    BackgroundInputs,
    BackgroundOut,
    BackgroundState,
    init_background,
    update_background,
)
from jaxvo.core.egomotion import (
    EgoInputs,
    EgoState,
    init_ego,
    predicted_motion,
    update_egomotion,
)
from jaxvo.core.evidence import (
    EvidenceInputs,
    moving_evidence,
    moving_logodds,
    neighbourhood,
    reported_ids,
)
from jaxvo.core.geometry import full_precision
from jaxvo.core.identifiers import measured_labels
from jaxvo.core.inputs import GridFlow, KeyframeFlow
from jaxvo.core.keyframe import (
    KeyframeInputs,
    KeyframeState,
    SupportInputs,
    init_keyframe,
    keyframe_support,
    update_keyframe,
)
from jaxvo.core.noise import (
    NoiseInputs,
    NoiseScale,
    init_noise,
    residuals,
    transfer,
    update_noise,
)
from jaxvo.core.occlusion import (
    OcclusionInputs,
    OcclusionState,
    forget_occlusion,
    init_occlusion,
    update_occlusion,
)
from jaxvo.core.points import frame_points
from jaxvo.core.separation import (
    SeparationInputs,
    SeparationState,
    init_separation,
    update_separation,
)
from jaxvo.core.spatial import Segmentation, segment_points
from jaxvo.core.temporal import (
    TemporalInputs,
    TemporalOut,
    TemporalState,
    init_temporal,
    update_temporal,
)
from jaxvo.status import Status, first_failure


class PipelineState(NamedTuple):
    """What the odometry carries from one frame to the next: each stage's state."""

    temporal: TemporalState  # identifiers, moving evidence, dual-mode grid model (on the grid)
    ego: EgoState  # the camera's pose and its last measured motion
    frame: jax.Array  # () int32, frame pairs processed so far
    noise: NoiseScale  # the sensor noise model (jaxvo.core.noise; calibrated with cfg.noise_calibration)
    keyframe: KeyframeState | None = None  # the latest keyframe (cfg.keyframes), None: off
    occlusion: OcclusionState | None = None  # the occlusion memory of the last image
    background: BackgroundState | None = None  # the challenge to the background's choice
    # the test over the frames since the keyframe (cfg.keyframes), None: off
    separation: SeparationState | None = None

    @property
    def T_w_c(self):
        """(4, 4) float32 pose of the latest camera (camera-to-world)."""
        return self.ego.T_w_c


class StepOutput(NamedTuple):
    """Per frame pair; grid arrays are anchored on the previous image of the pair."""

    T_w_c: jax.Array  # (4, 4) float32, pose of the current camera
    T_cur_prev: jax.Array  # (4, 4) float32, motion of the static background (carried: predicted)
    status: jax.Array  # () int32 Status code, OK or why the motion was carried
    # (n,) int32 identifiers: 0 unknown, 1 static, >= 2 the moving object (exactly where
    # `moving`; max_ids + 1 moving, not yet named), jaxvo.core.evidence.reported_ids
    ids: jax.Array
    moving: jax.Array  # (n,) bool points reported as moving (evidence over time)
    dynamic: jax.Array  # (n,) bool cells of the plug-in mask: moving, and their unmeasured neighbours
    static: jax.Array  # (n,) bool, points the ego-motion used (static, valid, inlier)
    labels: jax.Array  # (n,) int32 spatial segments of this pair (0 = none)
    hyp_labels: jax.Array  # (n,) int32 best raw hypothesis per point, before clustering
    matched: jax.Array  # (n,) int32 spatial segments after label matching
    num_segments: jax.Array  # () int32 distinct motions found by the spatial stage
    evidence: jax.Array  # (n,) float32 log-odds that each point moves
    background: jax.Array  # () int32 spatial label of the background segment, 0 none
    reacquired: jax.Array  # () bool the background took its identifier back this frame
    noise: NoiseScale  # the sensor noise model after this frame
    keyframes: jax.Array | None = None  # () int32 keyframes taken so far (cfg.keyframes)
    # () int32 the identifier (numbered as entering the frame) whose motion became the
    # background's this frame (its challenge, jaxvo.core.background), 0 none: the pose
    # continues from that identifier's chain, and revised_poses redraws the earlier poses
    # along it from `chains` and `permutation` of the earlier pairs
    switched: jax.Array | None = None
    chains: jax.Array | None = None  # (max_ids, 4, 4) each identifier's pose chain, this image
    permutation: jax.Array | None = None  # (max_ids,) int32 the identifiers' renumbering
    # (max_ids,) bool the identifiers given anew this frame, to a new object (numbered as
    # entering it): revised_poses redraws no pose along one before it was given
    new_ids: jax.Array | None = None
    # () bool the commitment switched to the motion it left out since the keyframe
    # (jaxvo.core.separation, cfg.keyframes): the pose jumped to that motion's, and
    # separated_poses redraws the earlier poses since the keyframe along `other_pose` of
    # the earlier pairs tested against the same keyframe (`tested_keyframe`); None: off
    separated: jax.Array | None = None
    other_pose: jax.Array | None = None  # (4, 4) float32 SeparationOut.other_pose
    tested_keyframe: jax.Array | None = None  # () int32 the keyframe the test read (its number)


def init_pipeline(*, cfg: StepOptions, grid: tuple[int, int], T_w_c0=None,
                  params: Params | None = None) -> PipelineState:
    """Start state: empty grid model, the first camera pose (identity by default) and the
    starting sensor noise of ``params`` (default :class:`Params`)."""
    T0 = jnp.eye(4, dtype=jnp.float32) if T_w_c0 is None else jnp.asarray(T_w_c0, jnp.float32)
    keyframe = init_keyframe(T0, cfg=cfg, grid=grid) if cfg.keyframes else None
    return PipelineState(temporal=init_temporal(cfg=cfg, grid=grid),
                         ego=init_ego(T0),
                         frame=jnp.int32(0), noise=init_noise(Params() if params is None else params),
                         keyframe=keyframe, occlusion=init_occlusion(grid=grid),
                         background=init_background(T0, cfg=cfg),
                         separation=init_separation() if cfg.keyframes else None)


# The start state as one compiled program: built eagerly, its few dozen operations each
# compiled a program of their own on a process's first frame (0.2 s of the first pose).
jit_init = jax.jit(init_pipeline, static_argnames=("cfg", "grid"))


@full_precision
def step(state: PipelineState, flow: GridFlow, key, params: Params, *, cfg: StepOptions, grid,
         batch_axis=None, keyframe: KeyframeFlow | None = None):
    """One frame pair: ``(state, GridFlow, key) -> (state, StepOutput)``.

    Args:
      state: carried :class:`PipelineState`.
      flow: a :class:`~jaxvo.core.inputs.GridFlow`, every field read: the points
        ``pts_prev``, ``pts_cur``, ``valid``, the pair's ``status``; their noise ``focal``,
        ``fb_error``, ``depth_slope``; ``uv_prev``, ``uv_cur`` (carry the grid model);
        ``depth_prev``, ``camera`` (the occlusion memory; cells without depth keep evidence).
      key: PRNG key of this frame (hypothesis sampling).
      params: numeric settings, possibly traced (vmappable).
      cfg: the step's options (``Config.step``), static; grid: static ``(rows, cols)``.
      batch_axis: the vmapped axes' name(s) in a study, :func:`jaxvo.core.spatial.segment`.
      keyframe: with ``cfg.keyframes`` (required then), the pair's
        :class:`~jaxvo.core.inputs.KeyframeFlow` (:class:`jaxvo.host.frontend.keyframes.KeyframeTracker`).
    """
    if cfg.keyframes != (keyframe is not None):
        raise ValueError("the step takes a KeyframeFlow exactly when cfg.keyframes is set "
                         f"(cfg.keyframes={cfg.keyframes}, keyframe given: {keyframe is not None})")
    stage = {"cfg": cfg, "grid": grid}
    pts = frame_points(flow.pts_prev, flow.pts_cur, flow.valid & (flow.status == Status.OK),
                       params, focal=flow.focal, scale=state.noise, fb_error=flow.fb_error,
                       depth_slope=flow.depth_slope)
    seg = segment_points(key, pts, params, batch_axis=batch_axis, **stage)
    labels = measured_labels(seg, pts.valid, cfg=cfg)
    occlusion, occ = update_occlusion(state.occlusion, OcclusionInputs(
        depth=flow.depth_prev, uv=flow.uv_prev, T_w_c=state.ego.T_w_c, camera=flow.camera,
        scale=state.noise, tie=pts.tie), params, **stage)
    background, bg = update_background(state.background, BackgroundInputs(
        seg=seg, pts=pts, T_pred=predicted_motion(state.ego), have_last=state.ego.have_last,
        labels=labels, identifiers=state.temporal.identifiers,
        evidence=state.temporal.evidence, scale=state.noise, T_w_c=state.ego.T_w_c,
        occluded=occ.occluded), params, **stage)
    ei = _ego_inputs(state, flow, keyframe, pts, seg, bg, params, **stage)
    ego, eo = update_egomotion(state.ego._replace(T_w_c=bg.T_w_prev), ei, params, cfg=cfg)
    eo = eo._replace(used=eo.used[:pts.valid.shape[0]])  # the pair's points, not the keyframe's
    ev = moving_evidence(EvidenceInputs(
        seg_labels=seg.labels, pts=pts, T_cur_prev=eo.T_cur_prev, d2_seg=bg.d2_seg, ok=eo.ok,
        in_front=bg.in_front, occluded=bg.occluded), params, **stage)
    ego, ev, separation, sep = _separated(state, flow, keyframe, ego, eo, ev, params, **stage)
    regrounded, T_w_mem = _regrounded(bg, sep, eo)
    temporal, tout = update_temporal(state.temporal, TemporalInputs(
        labels=labels, disp=flow.uv_cur - flow.uv_prev, flow_valid=pts.valid,
        segment_ids=bg.segment_ids, explained=ev.explained, evidence_delta=ev.delta,
        depth_prev=flow.depth_prev, permutation=bg.permutation, forget=bg.forget,
        held=None if sep is None else sep.held), params, **stage)
    noise = _calibrated(state.noise, eo, pts, bg, params, cfg=cfg)
    kf_state, kout = state.keyframe, None
    if keyframe is not None:  # the cells the temporal model holds static on this image
        kf_state, kout = update_keyframe(state.keyframe, KeyframeInputs(
            kf=keyframe, T_w_c=ego.T_w_c, static=temporal.evidence <= moving_logodds(params),
            T_cur_prev=eo.T_cur_prev, T_w_prev=bg.T_w_prev, pts=pts, used=eo.used,
            noise=noise, focal=flow.focal, ok=eo.ok & ~regrounded,
            **_track_residuals(ei, eo, pts.valid.shape[0], cfg=cfg)), params, **stage)
        ego = ego._replace(T_w_c=kout.T_w_c)
    out = _output(ego, eo, seg, bg, tout, noise, pts.valid, params, kout=kout, sep=sep,
                  tested=None if sep is None else state.keyframe.count, **stage)
    return PipelineState(
        temporal=temporal, ego=ego, frame=state.frame + 1, noise=noise, keyframe=kf_state,
        occlusion=forget_occlusion(occlusion, regrounded, T_w_mem),
        background=background, separation=separation), out


def _separated(state: PipelineState, flow: GridFlow, keyframe: KeyframeFlow | None, ego, eo,
               ev, params: Params, *, cfg: StepOptions, grid):
    """With a ``keyframe``, the two motions over the frames since it
    (:func:`jaxvo.core.separation.update_separation`): the pose where the commitment
    switched, and its evidence in place of the pair's where it decides; ``(ego, ev,
    SeparationState, SeparationOut)`` (the stages' outputs as given and ``None`` twice
    without)."""
    if keyframe is None:
        return ego, ev, None, None
    separation, sep = update_separation(state.separation, SeparationInputs(
        kf=keyframe, T_w_kf=state.keyframe.T_w_kf[-1], T_w_c=ego.T_w_c,
        depth_prev=flow.depth_prev, scale=state.noise, focal=flow.focal, ok=eo.ok,
        prior=state.temporal.evidence, pair_delta=ev.delta), params, cfg=cfg, grid=grid)
    return (ego._replace(T_w_c=sep.T_w_c),
            ev._replace(delta=jnp.where(sep.decided, sep.delta, ev.delta)), separation, sep)


def _track_residuals(ei: EgoInputs, eo, n: int, *, cfg: StepOptions) -> dict:
    """With ``cfg.keyframe_track_window``, the keyframe points' normalised residuals under
    the pair's ego-motion and which the fit weighed (``KeyframeInputs`` fields: each
    point's own test over frames, :func:`jaxvo.core.keyframe.track_evidence`); else none."""
    if not cfg.keyframe_track_window:
        return {}
    noise = jax.tree.map(lambda x: x[..., n:], ei.pts.noise)
    return {"track_d2": residuals(eo.T_cur_prev, ei.pts.src[:, n:], ei.pts.dst[:, n:], noise)[0],
            "track_weighed": (ei.weights[n:] > 0) & ei.pts.valid[n:]}


def _regrounded(bg: BackgroundOut, sep, eo):
    """``(regrounded () bool, T_w_c (4, 4))``: whether the commitment switched this frame
    (the background's challenge, or the test over the keyframe ``sep``), and the last
    image's pose under it, which the occlusion memory keeps."""
    if sep is None:
        return bg.switched, bg.T_w_prev
    return (bg.switched | sep.switched,
            jnp.where(sep.switched, sep.T_w_c @ eo.T_cur_prev, bg.T_w_prev))


def _calibrated(scale: NoiseScale, eo, pts, bg: BackgroundOut, params: Params, *,
                cfg: StepOptions) -> NoiseScale:
    """The sensor noise after this frame: calibrated on the points the ego-motion used
    (``cfg.noise_calibration``), else ``scale`` as it was."""
    if not cfg.noise_calibration:
        return scale
    return update_noise(scale, NoiseInputs(
        r=transfer(eo.T_cur_prev, pts.src) - pts.dst, used=(bg.use > 0) & eo.ok,
        noise=pts.noise), params)


def _ego_inputs(state: PipelineState, flow: GridFlow, keyframe: KeyframeFlow | None, pts,
                seg: Segmentation, bg: BackgroundOut, params: Params, *, cfg: StepOptions,
                grid) -> EgoInputs:
    """The ego-motion's :class:`~jaxvo.core.egomotion.EgoInputs`: the points of the
    background (``bg.use``), with a ``keyframe`` also the keyframe's static points tracked
    into this image (:func:`jaxvo.core.keyframe.keyframe_support`), from the background
    segment's motion, among the candidates the predicted motion and every segment's."""
    ego_pts, ego_weights, belief = pts, bg.use, bg.belief
    if keyframe is not None:
        ego_pts, ego_weights, belief = keyframe_support(state.keyframe, SupportInputs(
            kf=keyframe, T_w_prev=state.ego.T_w_c, pts=pts, bg=bg,
            evidence=state.temporal.evidence, focal=flow.focal, scale=state.noise),
            params, cfg=cfg, grid=grid)
    candidates = jnp.concatenate([predicted_motion(state.ego)[None], seg.motions])
    return EgoInputs(pts=ego_pts, weights=ego_weights,
                     T_init=seg.motions[jnp.maximum(bg.background - 1, 0)],
                     status=first_failure(flow.status, seg.status, bg.status), belief=belief,
                     candidates=candidates)


def _output(ego: EgoState, eo, seg: Segmentation, bg: BackgroundOut, tout: TemporalOut,
            noise, valid, params: Params, *, cfg: StepOptions, grid, kout=None, sep=None,
            tested=None) -> StepOutput:
    """The step's :class:`StepOutput` from its stages' outputs: one notion of moving, the
    evidence (``moving``), which the identifiers and the mask cells follow. With keyframes,
    ``kout`` the keyframe stage's, ``sep`` the test over the keyframe's (``tested``: the
    keyframe it read)."""
    moving = tout.evidence > moving_logodds(params)
    return StepOutput(
        T_w_c=ego.T_w_c,
        T_cur_prev=eo.T_cur_prev,
        status=eo.status,
        ids=reported_ids(tout.ids, tout.matched, moving, cfg=cfg),
        moving=moving,
        dynamic=grow_moving(moving, ~valid & (tout.evidence > -moving_logodds(params)),
                            grid=grid, steps=1),
        static=eo.used,
        labels=seg.labels,
        hyp_labels=seg.hyp_labels,
        matched=tout.matched,
        num_segments=seg.num_segments,
        evidence=tout.evidence,
        background=jnp.where(eo.ok, bg.background, 0),
        reacquired=bg.reacquired & eo.ok,
        noise=noise,
        switched=bg.winner,
        chains=bg.chains,
        permutation=bg.permutation,
        new_ids=bg.given,
        keyframes=None if kout is None else kout.count,
        separated=None if sep is None else sep.switched,
        other_pose=None if sep is None else sep.other_pose,
        tested_keyframe=tested,
    )


def grow_moving(moving, open_cells, *, grid, steps: int):
    """(n,) bool ``moving`` grown ``steps`` times into 8-connected ``open_cells`` (n,) bool.

    A cell without a measurement this frame (no valid flow: an object's edge, a blurred or
    textureless part, a depth hole) that is not established background takes the state of
    its measured neighbourhood: it is reported moving when it touches a moving cell.
    Measured cells and established background bound the growth.
    """
    for _ in range(steps):
        moving = moving | (jnp.any(neighbourhood(moving, False, grid=grid), axis=-1)
                           & open_cells)
    return moving


def final_moving(state: PipelineState, params: Params):
    """(n,) bool the cells of the last image reported moving: the final state's evidence,
    already carried forward onto that image's grid."""
    return state.temporal.evidence > moving_logodds(params)


@jax.jit
def revised_poses(T_w_c, switched, chains, permutations, new_ids=None):
    """(T, 4, 4) the poses after each of T pairs as the committed chain has them at the
    end: where the background switched to another motion in a pair
    (``StepOutput.switched`` (T,), the winner numbered as entering that pair), the earlier
    poses are redrawn along the winner's chain (``StepOutput.chains`` (T, max_ids, 4, 4)),
    back to the pair in which its identifier was given to the object
    (``StepOutput.new_ids`` (T, max_ids) bool; None: every identifier's from the start):
    before that the identifier was another object's or none, and the committed poses stay.
    A later switch redraws over an earlier one. Walking back from the last pair, the
    followed identifier is renumbered by each pair's ``permutations`` (T, max_ids) (a swap:
    its own inverse); where it was out of view its chain moved with the camera's predicted
    motion. ``T_w_c`` (T, 4, 4): the poses as the pairs gave them. Pure and traceable: the
    same walk for a study's configurations on the device and for a run on the host."""
    if new_ids is None:
        new_ids = jnp.zeros(permutations.shape, bool)

    def back(follow, xs):
        T, won, chain, perm, given = xs
        pose = jnp.where(follow >= 0, chain[jnp.maximum(follow, 0)], T)
        follow = jnp.where(follow >= 0, perm[jnp.maximum(follow, 0)],
                           jnp.where(won > 0, won - 1, -1))
        follow = jnp.where(given[jnp.maximum(follow, 0)], -1, follow)  # its object begins here
        return follow, pose

    _, poses = jax.lax.scan(back, jnp.int32(-1),
                            (T_w_c, switched, chains, permutations, new_ids), reverse=True)
    return poses


@jax.jit
def separated_poses(T_w_c, separated, other_pose, tested_keyframe):
    """(T, 4, 4) the poses after each of T pairs as the committed chain has them at the
    end, for the switches of the test over the keyframe (:mod:`jaxvo.core.separation`):
    where the commitment switched to the other motion in a pair (``separated`` (T,) bool),
    the poses of the earlier pairs tested against the same keyframe (``tested_keyframe``
    (T,) int32) are redrawn as that motion had them (``other_pose`` (T, 4, 4)); a later
    switch redraws over an earlier one. ``T_w_c`` (T, 4, 4): the poses as the pairs gave
    them. Pure and traceable, as :func:`revised_poses`."""

    def back(followed, xs):
        T, switched, other, keyframe = xs
        follow = (followed >= 0) & (keyframe == followed)
        pose = jnp.where(follow, other, T)
        followed = jnp.where(switched, keyframe, jnp.where(follow, followed, -1))
        return followed, pose

    _, poses = jax.lax.scan(back, jnp.int32(-1),
                            (T_w_c, separated, other_pose, tested_keyframe), reverse=True)
    return poses


def committed_poses(outs: StepOutput):
    """(T, 4, 4) the poses after each of T pairs (``outs``: :class:`StepOutput` stacked
    over them) as the committed chain has them at the end: redrawn where the test over the
    keyframe switched (:func:`separated_poses`, with keyframes), then where the background
    switched to another motion (:func:`revised_poses`). Traceable (a study vmaps it)."""
    T = outs.T_w_c
    if outs.separated is not None:
        T = separated_poses(T, outs.separated, outs.other_pose, outs.tested_keyframe)
    return revised_poses(T, outs.switched, outs.chains, outs.permutation, outs.new_ids)


def frame_key(key, index):
    """The PRNG key of frame pair ``index``: the same in streaming, scan and study runs."""
    return jax.random.fold_in(key, index)


def _step_options(cfg) -> StepOptions:
    """``cfg`` itself where it is the step's options, else a ``TypeError`` naming them: a
    whole ``Config`` as the static argument would compile a program per host setting."""
    if not isinstance(cfg, StepOptions):
        raise TypeError(f"cfg must be the step's options (StepOptions, Config.step), got "
                        f"{type(cfg).__name__}: pass cfg.step")
    return cfg


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def jit_step(state, flow, key, params, *, cfg: StepOptions, grid, keyframe=None):
    """:func:`step` compiled once per (cfg, grid); the key is folded with the frame count.

    ``cfg`` is ``Config.step``: the step's own options, so that a setting of the host's
    flow (an LK window) compiles nothing; a whole ``Config`` is refused."""
    return step(state, flow, frame_key(key, state.frame), params, cfg=_step_options(cfg),
                grid=grid, keyframe=keyframe)


def _scan(flows, key, params, T_w_c0, cfg, grid, outer_axes=(), keyframes=None):
    """Every frame pair in turn; ``outer_axes`` names the vmapped axes of a study, so that
    the hypothesis search skips a trip once every configuration's frame is done."""

    def body(state, xs):
        flow, kf = xs
        return step(state, flow, frame_key(key, state.frame), params, cfg=cfg, grid=grid,
                    batch_axis=outer_axes or None, keyframe=kf)

    return jax.lax.scan(body, init_pipeline(cfg=cfg, grid=grid, T_w_c0=T_w_c0, params=params),
                        (flows, keyframes))


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def run_scan(flows, key, params, T_w_c0, *, cfg: StepOptions, grid, keyframes=None):
    """The whole sequence in one ``lax.scan`` from precomputed flow.

    Args:
      flows: ``GridFlow`` with a leading axis of T frame pairs.
      key: PRNG key of the run (frame keys are folded from it).
      params: numeric settings.
      T_w_c0: (4, 4) pose of the first camera.
      keyframes: with ``cfg.keyframes``, the ``KeyframeFlow`` of every pair stacked as
        ``flows`` (:func:`jaxvo.host.frontend.flow.sequence_flows`); None: frame to frame only.
      cfg: the step's options (``Config.step``); grid: ``(rows, cols)``.

    Returns:
      ``(final_state, outputs)`` with every :class:`StepOutput` field stacked over T.
    """
    return _scan(flows, key, params, T_w_c0, _step_options(cfg), grid, keyframes=keyframes)


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def run_study(flows, keys, params, T_w_c0, *, cfg: StepOptions, grid, keyframes=None):
    """Many configurations of one sequence in one call: ``vmap`` over keys and parameters.

    Args:
      flows: ``GridFlow`` stacked over T frame pairs (shared by every configuration).
      keys: (B, ...) PRNG keys, one per configuration.
      params: ``Params`` whose fields are (B,) arrays (use :func:`batch_params`).
      T_w_c0: (4, 4) first pose.
      keyframes: with ``cfg.keyframes``, the ``KeyframeFlow`` of every pair stacked as
        ``flows`` and shared as they are (as :func:`run_scan` takes them); None: frame to
        frame only.
      cfg: the step's options (``Config.step``); grid: ``(rows, cols)``.

    Returns:
      ``StepOutput`` stacked as (B, T, ...) (the final states are dropped).
    """

    cfg = _step_options(cfg)

    def one(k, p):
        return _scan(flows, k, p, T_w_c0, cfg, grid, outer_axes=("configs",),
                     keyframes=keyframes)[1]

    return jax.vmap(one, axis_name="configs")(keys, params)


def batch_params(base: Params, size: int | None = None, **sweeps) -> Params:
    """``Params`` with every field a (B,) float32 array: ``sweeps`` give per-config values.

    ``batch_params(Params(), lam=[1e2, 1e3, 1e4])`` varies lambda and repeats the rest.
    """
    lengths = {len(v) for v in sweeps.values()}
    if size is not None:
        lengths.add(size)
    if len(lengths) != 1:
        raise ValueError(f"swept values must all have the same length, got {sorted(lengths)}")
    (B,) = lengths
    unknown = set(sweeps) - set(Params._fields)
    if unknown:
        raise ValueError(f"unknown parameter(s) {sorted(unknown)}; choose from {Params._fields}")
    fields = {
        name: jnp.asarray(sweeps[name], jnp.float32)
        if name in sweeps
        else jnp.full((B,), getattr(base, name), jnp.float32)
        for name in Params._fields
    }
    return Params(**fields)
