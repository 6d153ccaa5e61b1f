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

from jaxvo.config import Config, Params, scan_batch_for
from jaxvo.egomotion import estimate_egomotion
from jaxvo.geometry import invert_pose
from jaxvo.procrustes import fit_rigid_cols, residuals, residuals_cols
from jaxvo.spatial import inlier_threshold, segment
from jaxvo.status import Status, first_failure
from jaxvo.temporal import (
    STATIC_ID,
    TemporalState,
    init_temporal,
    own_segment_err,
    update_temporal,
)


class PipelineState(NamedTuple):
    """What the odometry carries from one frame to the next."""

    temporal: TemporalState  # dual-mode grid model, identifiers, label history
    T_w_c: jax.Array  # (4, 4) float32, pose of the latest camera (camera-to-world)
    frame: jax.Array  # () int32, frame pairs processed so far
    T_last: jax.Array  # (4, 4) float32, the last accepted ego-motion T_cur_prev
    have_last: jax.Array  # () bool, whether T_last holds an accepted ego-motion yet


class StepOutput(NamedTuple):
    """Per frame pair; grid arrays are anchored on the previous image of the pair."""

    T_w_c: jax.Array  # (4, 4) float32, pose of the current camera
    T_cur_prev: jax.Array  # (4, 4) float32, estimated motion of the static background
    status: jax.Array  # () int32 Status code, OK or why the frame was skipped
    ids: jax.Array  # (n,) int32 temporal identifiers: 0 unknown, 1 static, >1 moving objects
    moving: jax.Array  # (n,) bool points reported as moving (see moving_points)
    static: jax.Array  # (n,) bool, points the ego-motion used (static, valid, inlier)
    labels: jax.Array  # (n,) int32 spatial segments of this pair (0 = none)
    hyp_labels: jax.Array  # (n,) int32 best raw hypothesis per point, before clustering
    matched: jax.Array  # (n,) int32 spatial segments after label matching
    num_segments: jax.Array  # () int32 distinct motions found by the spatial stage


def moving_points(tout, follows):
    """Grid points reported as moving: the temporal model says a moving identifier, or this
    frame's label-matched measurement does (the model switches only after several frames,
    thesis section 4.2; the measurement shows a newly moving object at once).

    The measurement alone does not count where the model says static and the point itself
    follows the predicted camera motion (``follows`` (n,) bool): an object's segment also
    takes far-wall points that its motion explains within the wall's wide threshold
    (``handheld_slow`` seed 2: 15-40 such points a frame), and these are no evidence of
    motion. (The same rule as for cells an object enters, ``temporal._update_models``.)
    """
    still = (tout.ids == STATIC_ID) & follows
    return (tout.ids > STATIC_ID) | ((tout.matched > STATIC_ID) & ~still)


def static_weights(tout, valid):
    """(n,) float weights of the points the ego-motion may use.

    The temporal model's static points, less those this frame's matched measurement gives
    to a moving identifier, as long as that leaves at least half of them. The model takes
    up to ``max_age`` frames to hand a cell over, so an object that starts to move (or
    separates from a background it was merged with) stays static in the model meanwhile
    and drags the ego-motion (``fixed_camera_2``: 400 mm of drift in one run of four); the
    measurement shows it at once. The measurement alone is not used: where the label
    matching briefly hands the background another identifier it would remove most of the
    background (tried: fixed-camera scenes 10-30x worse); the half rule keeps the model's
    set then.
    """
    model = valid & (tout.ids == STATIC_ID)
    agreed = model & (tout.matched <= STATIC_ID)
    use_agreed = 2 * jnp.sum(agreed) >= jnp.sum(model)
    return jnp.where(use_agreed, agreed, model).astype(jnp.float32)


def follows_prediction(seg, follows, *, cfg: Config):
    """(max_segments,) bool: whether most of each segment's points move as the camera motion
    predicted from the previous frame says static points do; ``follows`` (n,) bool says it
    of each valid point (its residual under that motion within the inlier threshold)."""
    member = seg.labels[None, :] == jnp.arange(1, cfg.max_segments + 1)[:, None]
    n = jnp.sum(member, axis=1)
    return 2 * jnp.sum(member & follows[None, :], axis=1) > n


def held_objects(ids, flow, valid, own_err, tau2, params: Params, *, cfg: Config):
    """(n,) int32 per point: a moving identifier its point still moves with (0 = none).

    A slow object merges with the background in the spatial stage once its motion differs
    from the background's by less than the per-point inlier threshold (``handheld_fast``
    seed 2: a box at 1.9 m moving 5-10 mm a frame against a 9.4 mm threshold), and the
    temporal model then hands its cells to the background within a few frames. The points
    still labelled with the object's identifier tell where it is, and together they show
    its motion where no single point can. The points of each of the ``cfg.held_ids``
    moving identifiers with the most labelled points get a rigid fit of their own (a refit
    on that fit's inliers scored the same and cost 0.15 ms a frame). The identifier is
    held when that fit lowers their squared residuals, relative to the segments now
    holding them, by at least ``params.hold_gain`` of ``tau^2`` on average over at least
    ``min_segment_points`` points; it then claims the points its fit explains within the
    threshold and better than their own segment does.

    Args:
      ids: (n,) int32 temporal labels carried into this frame (on this pair's grid).
      flow: the pair's ``GridFlow`` (``pts_prev``, ``pts_cur``).
      valid: (n,) bool points with a segment.
      own_err: (n,) squared residual of each point under its own segment's motion.
      tau2: (n,) squared inlier thresholds.
    """
    moving = jnp.arange(STATIC_ID + 1, cfg.max_ids + 1)
    in_id = valid[None, :] & (ids[None, :] == moving[:, None])  # (max_ids - 1, n)
    count, slot = jax.lax.top_k(jnp.sum(in_id, axis=1), min(cfg.held_ids, cfg.max_ids - 1))
    k = moving[slot]
    member = in_id[slot]  # (held_ids, n)
    src, dst = flow.pts_prev.T, flow.pts_cur.T

    def fit(w):
        T, ok = fit_rigid_cols(src, dst, w)
        return residuals_cols(T, src, dst), ok

    err, ok = jax.vmap(fit)(member.astype(jnp.float32))
    gain = jnp.sum(jnp.where(member, (own_err[None, :] - err) / tau2[None, :], 0.0), axis=1)
    held = ok & (count >= params.min_segment_points) & (gain >= params.hold_gain * count)
    claims = member & held[:, None] & (err <= tau2[None, :]) & (err < own_err[None, :])
    return jnp.where(jnp.any(claims, axis=0), k[jnp.argmax(claims, axis=0)], 0)


def init_pipeline(*, cfg: Config, grid: tuple[int, int], T_w_c0=None) -> PipelineState:
    """Start state: empty grid model and the first camera pose (identity by default)."""
    T0 = jnp.eye(4, dtype=jnp.float32) if T_w_c0 is None else jnp.asarray(T_w_c0, jnp.float32)
    eye = jnp.eye(4, dtype=jnp.float32)
    return PipelineState(init_temporal(cfg=cfg, grid=grid), T0, jnp.int32(0), eye, jnp.bool_(False))


def spatial_step(flow, key, params: Params, *, cfg: Config, grid, batch_axis=None):
    """The spatial stage of one frame pair (Algorithms 1, 2); it needs no carried state, so
    a recorded sequence segments many frames at once (see :func:`segment_frames`, which
    names its vmapped axes in ``batch_axis``)."""
    valid = flow.valid & (flow.status == Status.OK)
    return segment(key, flow.pts_prev, flow.pts_cur, valid, params, cfg=cfg, grid=grid,
                   batch_axis=batch_axis)


def step(state: PipelineState, flow, key, params: Params, *, cfg: Config, grid, seg=None):
    """One frame pair: ``(state, GridFlow, key) -> (state, StepOutput)``.

    Args:
      state: carried :class:`PipelineState`.
      flow: a ``GridFlow`` of device or host arrays (``pts_prev``, ``pts_cur``, ``uv_prev``,
        ``uv_cur``, ``valid``, ``status``), see :mod:`jaxvo.flow`.
      key: PRNG key of this frame (hypothesis sampling).
      params: numeric settings, possibly traced (vmappable).
      cfg: static settings; grid: static ``(rows, cols)``.
      seg: this pair's :func:`spatial_step` result when already computed (``key`` is then
        unused).
    """
    valid = flow.valid & (flow.status == Status.OK)

    if seg is None:
        seg = spatial_step(flow, key, params, cfg=cfg, grid=grid)

    disp = flow.uv_cur - flow.uv_prev
    # after the first accepted ego-motion, the previous one predicts the background's
    # every point's residual under the predicted camera motion and under each segment's
    # motion: the first says which segments move as the background should, the others let
    # the temporal stage keep an object in cells its motion still explains best, and let a
    # slow object merged into the background keep its identifier (held_objects)
    z = jnp.maximum(flow.pts_prev[:, 2], flow.pts_cur[:, 2])
    tau2 = inlier_threshold(z, params.inlier_dist, params) ** 2
    err = jax.vmap(lambda T: residuals(T, flow.pts_prev, flow.pts_cur))(
        jnp.concatenate([state.T_last[None], seg.motions])
    )
    follows = valid & (err[0] <= tau2) & state.have_last
    consistent = follows_prediction(seg, follows, cfg=cfg)
    seg_err = jnp.where((seg.sizes > 0)[:, None], err[1:], 1e6)
    held = held_objects(state.temporal.ids, flow, valid & (seg.labels > 0),
                        own_segment_err(seg_err, seg.labels), tau2, params, cfg=cfg)
    temporal, tout = update_temporal(
        state.temporal, seg, disp, valid, params, cfg=cfg, grid=grid, consistent=consistent,
        follows=follows, seg_err=(seg_err, tau2), held=held,
    )

    static_w = static_weights(tout, valid)
    T_cur_prev, ego_status, inliers = estimate_egomotion(
        flow.pts_prev, flow.pts_cur, static_w, params, cfg=cfg
    )

    status = first_failure(flow.status, seg.status, ego_status)
    ok = status == Status.OK
    T_cur_prev = jnp.where(ok, T_cur_prev, jnp.eye(4, dtype=jnp.float32))
    T_w_c = state.T_w_c @ invert_pose(T_cur_prev)

    out = StepOutput(
        T_w_c=T_w_c,
        T_cur_prev=T_cur_prev,
        status=status,
        ids=tout.ids,
        moving=moving_points(tout, follows),
        static=inliers & ok,
        labels=seg.labels,
        hyp_labels=seg.hyp_labels,
        matched=tout.matched,
        num_segments=seg.num_segments,
    )
    T_last = jnp.where(ok, T_cur_prev, state.T_last)
    have_last = state.have_last | ok
    return PipelineState(temporal, T_w_c, state.frame + 1, T_last, have_last), out


def frame_key(key, index):
    """The PRNG key of frame pair ``index``: the same in streaming, scan and study runs."""
    return jax.random.fold_in(key, index)


@functools.partial(jax.jit, static_argnames=("cfg", "grid"))
def jit_step(state, flow, key, params, *, cfg: Config, grid):
    """:func:`step` compiled once per (cfg, grid); the key is folded with the frame count."""
    return step(state, flow, frame_key(key, state.frame), params, cfg=cfg, grid=grid)


def segment_frames(flows, keys, params, *, cfg: Config, grid, outer_axes=()):
    """The spatial stage of many frame pairs: ``spatial_step`` on several frames per vmapped
    call, the calls one after another (``Segmentation`` fields stacked over the frames).

    The spatial stage carries no state, so a recorded sequence segments several frames at
    once, which shares XLA's per-operation cost on the CPU (8 a call: 1.5x faster than one
    by one) and fills an accelerator (see :func:`jaxvo.config.scan_batch_for`). The vmapped
    axis is named so that the hypothesis search skips its trips once every frame of the
    call is done (``spatial._search_step``), of every configuration too in a study (whose
    vmapped axes are ``outer_axes``). The frames are padded to a whole number of calls (the
    padding's results are dropped) so that only one batched body compiles.

    Args:
      flows: ``GridFlow`` stacked over T frame pairs; keys: (T,) PRNG keys, one per pair.
    """
    n = flows.valid.shape[0]
    b = scan_batch_for(cfg, n, jax.default_backend())
    pad = (-n) % b
    padded = jax.tree.map(lambda a: jnp.concatenate([a, a[:pad]]), (flows, keys))
    batched = jax.vmap(
        lambda f, k: spatial_step(f, k, params, cfg=cfg, grid=grid,
                                  batch_axis=("frames", *outer_axes)),
        axis_name="frames",
    )
    segs = jax.lax.map(
        lambda fk: batched(*fk),
        jax.tree.map(lambda a: a.reshape(-1, b, *a.shape[1:]), padded),
    )
    return jax.tree.map(lambda a: a.reshape(-1, *a.shape[2:])[:n], segs)


def _scan(flows, key, params, T_w_c0, cfg, grid, outer_axes=()):
    # the stateless spatial stage for every frame first, then the stateful stages frame by
    # frame
    keys = jax.vmap(lambda i: frame_key(key, i))(jnp.arange(flows.valid.shape[0]))
    segs = segment_frames(flows, keys, params, cfg=cfg, grid=grid, outer_axes=outer_axes)

    def body(state, flow_seg):
        flow, seg = flow_seg
        return step(state, flow, None, params, cfg=cfg, grid=grid, seg=seg)

    return jax.lax.scan(body, init_pipeline(cfg=cfg, grid=grid, T_w_c0=T_w_c0), (flows, segs))


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
