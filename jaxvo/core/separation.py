"""Two motions told apart over the frames since the keyframe (device side; our addition).

A near mover that moves almost as the camera does (a box carried with it, a person walking
beside it) is one rigid motion with the background in every pair: its motion relative to
the camera stays within one pair's noise, the spatial stage finds one segment, and the
ego-motion follows whichever covers more of the view. Over ``k`` frames the two motions
draw apart by ``v k / fps`` while a keyframe track's noise stays about one pair's: on the
heavy-cover scenes no background point is told apart from the box in a pair, and nearly
all are after a few frames (docs/report/separation.md). So with keyframes (``cfg.keyframes``)
the latest keyframe's grid points tracked into this image are tested once more:

* under the **committed** motion since the keyframe, ``inv(T_w_c) T_w_kf`` (the ego-motion
  of this frame chained to the keyframe's pose), and under the **other** motion: the one
  of the points the committed motion does not explain, fit and refined as Algorithm 1
  refines a hypothesis (:func:`jaxvo.core.spatial.refine_motion`: a point joins it only
  where it explains the point better than the committed motion does);
* where the two are told apart (most of neither's points within the other's test, each
  with enough points for a fit), a point that one of them explains and the other does not
  is evidence in its cell, in place of the pair's (which cannot tell them apart): moving,
  the Gaussian log-ratio ``(d2_committed - d2_other) / 2``, where only the other explains
  it, as a segment that moves unlike the background does in a pair; static, as a point
  the camera's motion explains (:func:`jaxvo.core.evidence.static_loglik`), where only the
  committed one does. What both explain is evidence for neither: while the other motion
  was told apart within the evidence's half-life, a cell established moving that its pair
  calls static keeps its evidence (the pair cannot tell; ``held``);
* which of the two is the world is asked as the background's challenge asks it of a
  pair's motions (:mod:`jaxvo.core.background`): the odds of the surfaces they explain
  (:func:`jaxvo.core.background.surface_loglik`), no evidence where the other motion's
  points lie in front of the committed one's (a nearer surface occludes the world), summed
  by Page's CUSUM (:func:`jaxvo.core.background.page_cusum`). When the sum crosses the
  bound the commitment switches: this image's pose becomes the keyframe's moved by the
  other motion, and the two motions' cells take each other's evidence (the committed
  motion's established moving, the other's established static), so that the pairs that
  follow fit the world's points.

The keyframe's points a cell carries are its own and its neighbours' of the same surface
(depths within the two-reading test), as the keyframe offers every ``keyframe_stride``-th
grid point only. A switch redraws the poses since the keyframe along the other motion's
(:func:`jaxvo.core.pipeline.separated_poses`); those before the keyframe stay as they were:
the other motion was measured against this keyframe only.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.background import depth_order, page_cusum, surface_loglik
from jaxvo.core.evidence import moving_logodds, neighbourhood, static_loglik
from jaxvo.core.geometry import invert_pose
from jaxvo.core.inputs import KeyframeFlow, keyframe_grid, keyframe_index
from jaxvo.core.noise import NoiseScale, residuals
from jaxvo.core.points import Points, frame_points
from jaxvo.core.procrustes import fit_rigid_cols
from jaxvo.core.robust import MOST, cauchy, enough_points, explains
from jaxvo.core.spatial import refine_motion


class SeparationInputs(NamedTuple):
    """What the test over the keyframe reads (:func:`update_separation`)."""

    kf: KeyframeFlow  # the pair's keyframe flow (every keyframe point, not only the static)
    T_w_kf: jax.Array  # (4, 4) float32 the latest keyframe's pose
    T_w_c: jax.Array  # (4, 4) float32 this image's committed pose (after the ego-motion)
    depth_prev: jax.Array  # (n,) float32 the pair's previous image's depth at its grid points
    scale: NoiseScale  # the sensor noise model
    focal: jax.Array  # () float32 focal length, pixels
    ok: jax.Array  # () bool this frame's ego-motion was measured
    prior: jax.Array  # (n,) float32 each cell's moving log-odds entering the frame
    pair_delta: jax.Array  # (n,) float32 the pair's evidence (jaxvo.core.evidence)


class SeparationState(NamedTuple):
    """What the test over the keyframe carries from frame to frame (:func:`update_separation`)."""

    # () float32 the evidence that the motion the committed one leaves out since the
    # keyframe is the world's: a CUSUM, 0 after a switch
    challenge: jax.Array
    # () float32 1 where the two motions were told apart in the last frame, fading by the
    # evidence's decay after: the other motion is still near where it was last seen
    other: jax.Array


def init_separation() -> SeparationState:
    """No evidence against the commitment, no other motion seen."""
    return SeparationState(challenge=jnp.float32(0.0), other=jnp.float32(0.0))


class SeparationOut(NamedTuple):
    """One frame of the test over the keyframe (:func:`update_separation`)."""

    switched: jax.Array  # () bool the commitment switched to the other motion this frame
    T_w_c: jax.Array  # (4, 4) float32 this image's pose: the other motion's where switched
    # (4, 4) float32 this image's pose were the other motion the world's, where the two were
    # told apart (else the committed one): a switch redraws the poses since the keyframe
    # along these (jaxvo.core.pipeline.separated_poses)
    other_pose: jax.Array
    # (n,) float32 log-likelihood ratios, moving over static, for the pair's previous
    # image's cells; on a switch beyond the evidence's bound, so that the cells take it
    delta: jax.Array
    # (n,) bool the cells whose evidence this test decides in place of the pair's: where
    # its keyframe points follow one of the two motions and not the other
    decided: jax.Array
    # (n,) bool the cells established moving whose pair says static while the other motion
    # is near (SeparationState.other): the pair cannot tell the two apart, so nothing is
    # learnt of them this frame (they keep their evidence, as a cell without a depth
    # reading does)
    held: jax.Array


def update_separation(state: SeparationState, inputs: SeparationInputs, params: Params, *,
                      cfg: StepOptions, grid: tuple[int, int]):
    """The committed motion since the keyframe against the other motion of its points: the
    moving evidence the test adds and whether the commitment switches (module docstring).

    Args:
      state: the CUSUM and the other motion's recency carried (:class:`SeparationState`);
      inputs: :class:`SeparationInputs`; params: numeric settings; cfg, grid: static.

    Returns:
      ``(SeparationState, SeparationOut)``.
    """
    kf, T_w_kf, T_w_c, depth_prev, scale, focal, ok, prior, pair_delta = inputs
    index = keyframe_index(grid, cfg.keyframe_stride)
    pts = frame_points(kf.pts_kf[index], kf.pts_cur[index], kf.valid[index] & ok, params,
                       focal=focal, scale=scale)
    T_committed = invert_pose(T_w_c) @ T_w_kf  # keyframe -> this image
    d2_c = residuals(T_committed, pts.src, pts.dst, pts.noise)[0]
    mine = pts.valid & (d2_c <= pts.thr)
    T_other, fits = _other_motion(pts, ~mine, pts.thr, iters=cfg.refine_iters)
    T_other, d2_o, _, theirs = refine_motion(T_other, jnp.int32(0), pts, cfg.refine_iters,
                                             d2_c)
    theirs = theirs & fits
    apart = (enough_points(mine, params) & enough_points(theirs, params)
             & ~explains((d2_o <= pts.thr)[None], mine[None], MOST)[0]
             & ~explains((d2_c <= pts.thr)[None], theirs[None], MOST)[0])
    # which of the two is the world: the larger surface of the points only it explains
    # (what both explain is evidence for neither), unless the other lies in front
    z = jnp.maximum(pts.src[2], pts.dst[2])
    surface = lambda m: jnp.sum(jnp.where(m, z * z, 0.0))
    only_mine, only_theirs = mine & (d2_o > pts.thr), theirs & (d2_c > pts.thr)
    labels = jnp.where(mine, 1, jnp.where(theirs, 2, 0))
    explained = jnp.stack([d2_c <= pts.thr, d2_o <= pts.thr]) & pts.valid
    z_cur = pts.dst[2]
    behind, front = depth_order(labels, z_cur, scale.depth_coeff * z_cur * z_cur, explained,
                                pts.tie, grid=keyframe_grid(grid, cfg.keyframe_stride))
    occludes = front[1, 0] > behind[1, 0]
    llr = jnp.where(apart & ~occludes,
                    surface_loglik(surface(only_theirs), surface(only_mine), params), 0.0)
    score, crossed = page_cusum(state.challenge, llr, params)
    switched = crossed & apart & ~occludes
    # each keyframe point's evidence where one motion explains it and the other does not
    step = params.evidence_step
    static = static_loglik(d2_c, params)
    each = jnp.where(apart & only_mine, jnp.clip(static, -step, step),
                     jnp.where(apart & only_theirs,
                               jnp.clip(0.5 * (d2_c - d2_o), -step, step), 0.0))
    bound = 2.0 * (moving_logodds(params) + params.evidence_margin)
    each = jnp.where(switched, jnp.where(mine, bound, jnp.where(theirs, -bound, 0.0)), each)
    delta = _spread(each, kf.cell_prev[index], pts.dst[2], depth_prev, scale, pts.tie,
                    grid=grid)
    decided = delta != 0
    # the other motion told apart within the evidence's half-life: what the pair calls
    # static may be it
    other = jnp.maximum(apart.astype(jnp.float32), params.evidence_decay * state.other)
    held = ((other > 0.5) & (prior > moving_logodds(params)) & ~decided & (pair_delta < 0)
            & ~switched)
    other_pose = jnp.where(apart, T_w_kf @ invert_pose(T_other), T_w_c)
    state = SeparationState(challenge=jnp.where(switched, 0.0, score), other=other)
    return state, SeparationOut(switched=switched, T_w_c=jnp.where(switched, other_pose, T_w_c),
                                other_pose=other_pose, delta=delta, decided=decided, held=held)


def _other_motion(pts: Points, left, thr, *, iters: int):
    """``(T, ok)``: the motion of the points ``left`` (n,) bool, fit under Cauchy's
    weights (scale the inlier test ``thr``) refit ``iters`` times from the least-squares
    fit, so that a few points of neither motion among them do not pull it off both."""
    w = (pts.valid & left).astype(jnp.float32)
    T, ok = fit_rigid_cols(pts.src, pts.dst, w)
    for _ in range(iters):
        d2 = residuals(T, pts.src, pts.dst, pts.noise)[0]
        T, ok = fit_rigid_cols(pts.src, pts.dst, w * cauchy(d2, thr)[1])
    return T, ok


def _spread(each, cell, z_kf, depth, scale: NoiseScale, tie, *, grid):
    """(n,) each cell's evidence from the keyframe points ``each`` (m,): the largest in size
    of those in its 3 x 3 neighbourhood (``cell`` (m,) the cell each lies in, -1 none) whose
    depth in this image ``z_kf`` (m,) the cell's own ``depth`` (n,) matches within the
    two-reading test ``tie`` (one surface: a box's evidence stays off the wall behind it)."""
    n = depth.shape[0]
    at = jnp.where((cell >= 0) & (each != 0), cell, n)
    placed = jnp.zeros((n,), jnp.float32).at[at].set(each, mode="drop")
    placed_z = jnp.zeros((n,), jnp.float32).at[at].set(z_kf, mode="drop")
    near = neighbourhood(placed, 0.0, grid=grid)  # (n, 9)
    near_z = neighbourhood(placed_z, 0.0, grid=grid)
    s2 = scale.depth_coeff ** 2 * (depth ** 4)[:, None] + scale.depth_coeff ** 2 * near_z ** 4
    dz = depth[:, None] - near_z
    same = (near != 0) & (depth[:, None] > 0) & (dz * dz <= tie * s2)
    near = jnp.where(same, near, 0.0)
    pick = jnp.argmax(jnp.abs(near), axis=-1)
    return jnp.take_along_axis(near, pick[:, None], axis=-1)[:, 0]
