"""The per-frame step of the odometry, and the whole-sequence scan built from it (device side).

One step reads top to bottom as the thesis's pipeline (Fig. 1.2):

  grid flow of a frame pair -> spatial segmentation (Algorithms 1, 2)
  -> temporal segmentation (Algorithm 3, dual-mode grid model)
  -> ego-motion from the static identifier -> camera pose chain.

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

from jaxvo.config import Config, Params
from jaxvo.core.egomotion import estimate_egomotion
from jaxvo.core.geometry import invert_pose
from jaxvo.core.noise import (
    NoiseScale,
    init_noise,
    residuals,
    residuals_many,
    transfer,
    update_noise,
)
from jaxvo.core.spatial import frame_points, segment
from jaxvo.core.temporal import (
    TemporalState,
    choose_background,
    identify,
    init_temporal,
    measured_labels,
    moving_logodds,
    update_temporal,
)
from jaxvo.core.window import WindowOut, WindowState, init_window, update_window
from jaxvo.status import Status, first_failure

# The calibration stays within these: LK is not more precise than about 0.1 px (and a
# simulator's noise can be far below a real sensor's), and a sensor noisier than 2 px and
# 4e-3 z^2 (three times a Kinect's raw depth noise) is not one the method can work with;
# without the ceiling, frames whose ego-motion followed an object measured the background's
# residuals as noise, and the model grew until every motion merged (to 4 px, 5e-3 z^2).
NOISE_FLOOR = NoiseScale(0.1, 3e-4)  # plain floats: a JAX array here would start the
NOISE_CEILING = NoiseScale(2.0, 4e-3)  # backend at import (jax.distributed needs it unstarted)
# The weight of a point whose evidence has not yet established it as background or as
# moving (new in view, or its evidence faded) against one established as background.
_UNESTABLISHED = 0.1
# A segment's support counts this much even when none of its explained points follows the
# predicted camera motion, so that a wrong prediction (a sudden camera move: nothing
# follows it) leaves the choice to the support alone.
_UNPREDICTED = 0.1


class PipelineState(NamedTuple):
    """What the odometry carries from one frame to the next."""

    temporal: TemporalState  # dual-mode grid model, identifiers, evidence, label history
    T_w_c: jax.Array  # (4, 4) float32, pose of the latest camera (camera-to-world)
    frame: jax.Array  # () int32, frame pairs processed so far
    T_last: jax.Array  # (4, 4) float32, the last accepted ego-motion T_cur_prev
    have_last: jax.Array  # () bool, whether T_last holds an accepted ego-motion yet
    noise: NoiseScale  # the sensor noise model (jaxvo.core.noise; calibrated when noise_rate > 0)
    window: WindowState | None = None  # the last cfg.window frames (jaxvo.core.window), None: off


class StepOutput(NamedTuple):
    """Per frame pair; grid arrays are anchored on the previous image of the pair."""

    T_w_c: jax.Array  # (4, 4) float32, pose of the current camera
    T_cur_prev: jax.Array  # (4, 4) float32, motion of the static background (carried: predicted)
    status: jax.Array  # () int32 Status code, OK or why the motion was carried
    ids: jax.Array  # (n,) int32 temporal identifiers: 0 unknown, 1 static, >1 moving objects
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
    # with cfg.window: the window's refined poses and the pose of the frame that left it
    # (jaxvo.core.window.WindowOut); T_w_c above is then the window's newest pose
    window: WindowOut | None = None


def belief_weights(prior, params: Params):
    """(n,) how much each point counts as background by what earlier frames say of it: 1
    where its static posterior reaches the confidence (established background),
    ``_UNESTABLISHED`` where it is not yet established either way (new in view, or its
    evidence faded), 0 where it is believed to move."""
    L = moving_logodds(params)
    return jnp.where(prior <= -L, 1.0, jnp.where(prior <= L, _UNESTABLISHED, 0.0))


def background_support(d2_seg, sizes, weights, z, d2_pred, have_last, thr):
    """Each segment's support as the background in this frame, and its consistency with
    the camera's predicted motion: ``(support (S,), consistency (S,))``, 0 where unused.

    The background is the motion consistent with the camera's predicted motion (the
    previous ego-motion) and supported by the most surface. The support of a segment's
    motion is the surface its explained points stand for, each weighted by how much
    earlier frames say it is background (:func:`belief_weights`): a grid point at depth z
    stands for ``(z / f)^2`` square metres, so the room behind a person or a box covering
    half the view (nearer, and at one depth) still has more surface than they have. Points
    count where the motion explains them (not only its own segment's), so a piece of the
    background split off by noise adds to the motion that explains it. The consistency is
    ``_UNPREDICTED + f``, ``f`` the share of that surface the predicted motion explains too
    (1 before any ego-motion). The temporal stage accumulates the support per identifier
    and weighs it by the consistency (:func:`jaxvo.core.temporal.choose_background`).

    Args:
      d2_seg: (S, n) normalised residuals of every point under each segment's motion;
      sizes: (S,) segment sizes (0 unused); weights: (n,) belief weights (0 invalid);
      z: (n,) depth, metres; d2_pred: (n,) normalised residuals under the predicted
      motion; have_last: () bool a prediction exists; thr: () the inlier test.
    """
    explained = d2_seg <= thr
    surface = explained * (weights * z * z)[None, :]
    follows = jnp.sum(surface * (d2_pred <= thr)[None, :], axis=1)
    total = jnp.sum(surface, axis=1)
    f = jnp.where(have_last, follows / jnp.maximum(total, 1e-12), 1.0)
    used = sizes > 0
    return jnp.where(used, total, 0.0), jnp.where(used, _UNPREDICTED + f, 0.0)


def explained_segments(seg, d2, valid, thr, *, cfg: Config):
    """(S,) bool the segments most of whose valid points the motion behind ``d2`` (n,)
    explains within the inlier test ``thr``."""
    member = (seg.labels[None, :] == jnp.arange(1, cfg.max_segments + 1)[:, None]) & valid
    count = jnp.sum(member, axis=1)
    fits = jnp.sum(member & (d2 <= thr)[None, :], axis=1)
    return (count > 0) & (2 * fits >= count)


def evidence_delta(seg, d2_ego, d2_seg, explained, valid, params: Params):
    """(n,) float32 this frame's log-likelihood ratio, moving over static, of every point.

    Static: the point follows the ego-motion, its residual ``d2_ego`` chi-square with 3
    degrees of freedom. Moving: it follows its own segment's motion, where that segment
    moves unlike the background (not ``explained``): the Gaussian log-ratio
    ``(d2_ego - d2_own) / 2``, which a slow object's points build up over frames though
    each alone stays within the noise. A point outside such a segment is evidence of static
    only, by how well the noise explains its residual: against residuals
    ``k = params.evidence_effect`` times the noise, ``-3 log k + d2 (1 - 1/k^2) / 2``,
    never above 0. A lone large residual is an outlier (a depth edge, a mistracked point),
    not evidence of motion: counted as such, it put 1-2 % of a static real scene's cells
    in motion (7-Scenes frames 0-149; 0.04-0.3 % this way). Every ratio is kept within
    ``+-params.evidence_step``: one frame cannot shift the odds by more than that.
    """
    s = d2_seg.shape[0]
    lab = jnp.clip(seg.labels - 1, 0, s - 1)
    own = jnp.take_along_axis(d2_seg, lab[None, :], axis=0)[0]
    in_moving = (seg.labels > 0) & ~explained[lab]
    k2 = params.evidence_effect ** 2
    static = jnp.minimum(-1.5 * jnp.log(k2) + 0.5 * d2_ego * (1.0 - 1.0 / k2), 0.0)
    delta = jnp.where(in_moving, 0.5 * (d2_ego - own), static)
    delta = jnp.clip(delta, -params.evidence_step, params.evidence_step)
    return jnp.where(valid, delta, 0.0).astype(jnp.float32)


def init_pipeline(*, cfg: Config, grid: tuple[int, int], T_w_c0=None,
                  params: Params | None = None) -> PipelineState:
    """Start state: empty grid model, the first camera pose (identity by default) and the
    starting sensor noise of ``params`` (default :class:`Params`)."""
    T0 = jnp.eye(4, dtype=jnp.float32) if T_w_c0 is None else jnp.asarray(T_w_c0, jnp.float32)
    eye = jnp.eye(4, dtype=jnp.float32)
    window = init_window(cfg=cfg, grid=grid, T_w_c0=T0) if cfg.window else None
    return PipelineState(init_temporal(cfg=cfg, grid=grid), T0, jnp.int32(0), eye,
                         jnp.bool_(False), init_noise(Params() if params is None else params),
                         window)


def step(state: PipelineState, flow, key, params: Params, *, cfg: Config, grid,
         batch_axis=None):
    """One frame pair: ``(state, GridFlow, key) -> (state, StepOutput)``.

    Args:
      state: carried :class:`PipelineState`.
      flow: a ``GridFlow`` of device or host arrays (``pts_prev``, ``pts_cur``, ``uv_prev``,
        ``uv_cur``, ``valid``, ``status``, ``focal``), see :mod:`jaxvo.host.flow`.
      key: PRNG key of this frame (hypothesis sampling).
      params: numeric settings, possibly traced (vmappable).
      cfg: static settings; grid: static ``(rows, cols)``.
      batch_axis: the name(s) of vmapped axes the call runs under (a study), see
        :func:`jaxvo.core.spatial.segment`.
    """
    valid = flow.valid & (flow.status == Status.OK)
    pts = frame_points(flow.pts_prev, flow.pts_cur, valid, params, focal=flow.focal,
                       scale=state.noise)
    valid = pts.valid

    # 1. spatial segmentation (Algorithms 1, 2) under the sensor noise model
    seg = segment(key, flow.pts_prev, flow.pts_cur, valid, params, cfg=cfg, grid=grid,
                  focal=flow.focal, scale=state.noise, batch_axis=batch_axis)

    # 2. identifiers (Algorithm 3) and the background: the segment whose motion explains
    # the most surface that earlier frames established as background
    T_pred = jnp.where(state.have_last, state.T_last, jnp.eye(4, dtype=jnp.float32))
    d2_all = residuals_many(jnp.concatenate([T_pred[None], seg.motions]), pts.src, pts.dst,
                            pts.noise)[0]
    d2_pred, d2_seg = d2_all[0], d2_all[1:]
    z = jnp.maximum(pts.src[2], pts.dst[2])
    prior = state.temporal.evidence
    belief = jnp.where(valid, belief_weights(prior, params), 0.0)
    labels = measured_labels(seg, valid, cfg=cfg)
    segment_ids = identify(state.temporal, labels, params, cfg=cfg)
    support, consistency = background_support(d2_seg, seg.sizes, belief, z, d2_pred,
                                              state.have_last, pts.thr)
    temporal, segment_ids, bg, reacquired = choose_background(
        state.temporal, segment_ids, support, consistency, params)

    # 3. ego-motion: re-weighted from the background segment's motion over every point,
    # each weighted by its belief, less those in a segment that moves unlike the
    # background (Algorithm 1's refinement on all points, for the background; a segment
    # the background's motion explains is a piece of the background that fast motion or
    # depth distortion split off)
    bgi = jnp.maximum(bg - 1, 0)
    static_seg = (explained_segments(seg, d2_seg[bgi], valid, pts.thr, cfg=cfg)
                  | (jnp.arange(1, cfg.max_segments + 1) == bg))
    in_moving_seg = (seg.labels > 0) & ~static_seg[jnp.clip(seg.labels - 1, 0, None)]
    use = jnp.where(in_moving_seg, 0.0, belief)
    T_ego, ego_status, inliers = estimate_egomotion(
        flow.pts_prev, flow.pts_cur, use, params, cfg=cfg,
        focal=flow.focal, scale=state.noise, T_init=seg.motions[bgi])
    status = first_failure(flow.status, seg.status, ego_status)
    ok = status == Status.OK
    # a frame without a motion of its own carries the predicted one: a moving camera is
    # never frozen by a skipped pair
    T_cur_prev = jnp.where(ok, T_ego, T_pred)
    T_w_c = state.T_w_c @ invert_pose(T_cur_prev)

    # 4. evidence of each point's own motion under the ego-motion, and the temporal model
    d2_ego = residuals(T_cur_prev, pts.src, pts.dst, pts.noise)[0]
    explained = explained_segments(seg, d2_ego, valid, pts.thr, cfg=cfg)
    delta = evidence_delta(seg, d2_ego, d2_seg, explained, valid & ok, params)
    temporal, tout = update_temporal(
        temporal, seg, flow.uv_cur - flow.uv_prev, valid, params, cfg=cfg, grid=grid,
        segment_ids=segment_ids, explained=explained & ok, evidence_delta=delta,
    )

    # 5. the sensor noise, from the residuals of the points the ego-motion was fitted to
    used = inliers & ok
    noise = update_noise(state.noise, transfer(T_cur_prev, pts.src) - pts.dst, (use > 0) & ok,
                         pts.noise, params.noise_rate, floor=NOISE_FLOOR, ceiling=NOISE_CEILING)

    # 6. the sliding-window refinement of the recent poses (jaxvo.core.window, cfg.window > 0)
    window, wout = state.window, None
    if cfg.window:
        window, wout = update_window(state.window, flow, T_cur_prev, used, noise, params,
                                     cfg=cfg, grid=grid)
        T_w_c = wout.T_w_c[-1]

    moving = tout.evidence > moving_logodds(params)
    out = StepOutput(
        T_w_c=T_w_c,
        T_cur_prev=T_cur_prev,
        status=status,
        ids=tout.ids,
        moving=moving,
        dynamic=grow_moving(moving, ~valid & (tout.evidence > -moving_logodds(params)),
                            grid=grid, steps=1),
        static=used,
        labels=seg.labels,
        hyp_labels=seg.hyp_labels,
        matched=tout.matched,
        num_segments=seg.num_segments,
        evidence=tout.evidence,
        background=jnp.where(ok, bg, 0),
        reacquired=reacquired & ok,
        noise=noise,
        window=wout,
    )
    T_last = jnp.where(ok, T_cur_prev, state.T_last)
    have_last = state.have_last | ok
    return PipelineState(temporal, T_w_c, state.frame + 1, T_last, have_last, noise,
                         window), out


def grow_moving(moving, open_cells, *, grid, steps: int):
    """(n,) bool ``moving`` grown ``steps`` times into 8-connected ``open_cells`` (n,) bool.

    A cell without a measurement this frame (no valid flow: an object's edge, a blurred or
    textureless part, a depth hole) that is not established background takes the state of
    its measured neighbourhood: it is reported moving when it touches a moving cell.
    Measured cells and established background bound the growth.
    """
    rows, cols = grid
    m = moving.reshape(rows, cols)
    o = open_cells.reshape(rows, cols)
    for _ in range(steps):
        p = jnp.pad(m, 1)
        near = jnp.zeros_like(m)
        for dr in (0, 1, 2):
            for dc in (0, 1, 2):
                near = near | p[dr:dr + rows, dc:dc + cols]
        m = m | (near & o)
    return m.reshape(-1)


def final_moving(state: PipelineState, params: Params):
    """(n,) bool the cells of the last image reported moving: the final state's evidence,
    already carried forward onto that image's grid."""
    return state.temporal.evidence > moving_logodds(params)


def frame_key(key, index):
    """The PRNG key of frame pair ``index``: the same in streaming, scan and study runs."""
    return jax.random.fold_in(key, index)


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def jit_step(state, flow, key, params, *, cfg: Config, grid):
    """:func:`step` compiled once per (cfg, grid); the key is folded with the frame count."""
    return step(state, flow, frame_key(key, state.frame), params, cfg=cfg, grid=grid)


def _scan(flows, key, params, T_w_c0, cfg, grid, outer_axes=()):
    """Every frame pair in turn; ``outer_axes`` names the vmapped axes of a study, so that
    the hypothesis search skips a trip once every configuration's frame is done."""

    def body(state, flow):
        return step(state, flow, frame_key(key, state.frame), params, cfg=cfg, grid=grid,
                    batch_axis=outer_axes or None)

    return jax.lax.scan(body, init_pipeline(cfg=cfg, grid=grid, T_w_c0=T_w_c0, params=params),
                        flows)


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def run_scan(flows, key, params, T_w_c0, *, cfg: Config, grid):
    """The whole sequence in one ``lax.scan`` from precomputed flow.

    Args:
      flows: ``GridFlow`` with a leading axis of T frame pairs.
      key: PRNG key of the run (frame keys are folded from it).
      params: numeric settings.
      T_w_c0: (4, 4) pose of the first camera.

    Returns:
      ``(final_state, outputs)`` with every :class:`StepOutput` field stacked over T.
    """
    return _scan(flows, key, params, T_w_c0, cfg, grid)


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def run_study(flows, keys, params, T_w_c0, *, cfg: Config, grid):
    """Many configurations of one sequence in one call: ``vmap`` over keys and parameters.

    Args:
      flows: ``GridFlow`` stacked over T frame pairs (shared by every configuration).
      keys: (B, ...) PRNG keys, one per configuration.
      params: ``Params`` whose fields are (B,) arrays (use :func:`batch_params`).
      T_w_c0: (4, 4) first pose.

    Returns:
      ``StepOutput`` stacked as (B, T, ...) (the final states are dropped).
    """

    def one(k, p):
        return _scan(flows, k, p, T_w_c0, cfg, grid, outer_axes=("configs",))[1]

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
