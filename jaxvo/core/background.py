"""The background of each frame: which segment's motion is the camera's (device side).

The thesis gives identifier 1 to the region that covers most of the image, so an object
covering more than half the view took the background's. Here the background is not left to
the overlap of eq. (4.1): each identifier accumulates its segment's support as the
background (:func:`background_support`: the surface its motion explains, each point
weighted by what earlier frames say of it), the choice weighs it by the frame's consistency
with the predicted camera motion, and the chosen identifier becomes 1 by one permutation of
the identifiers (:func:`choose_background`: the background is re-acquired in that frame,
never lost), which the later stages apply to their own states (``BackgroundOut.permutation``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Config, Params
from jaxvo.core.evidence import explained_segments, moving_logodds
from jaxvo.core.geometry import tiny
from jaxvo.core.identifiers import STATIC_ID, relabel, swap_perm
from jaxvo.core.noise import Points, residuals_many


class BackgroundState(NamedTuple):
    """Each identifier's support as the background (carried by the pipeline)."""

    score: jax.Array  # (max_ids,) float32 accumulated over frames, decaying


def init_background(*, cfg: Config) -> BackgroundState:
    """No support yet."""
    return BackgroundState(jnp.zeros((cfg.max_ids,), jnp.float32))


def choose_background(state: BackgroundState, segment_ids, support, consistency, initialised,
                      params: Params):
    """The background of this frame: the identifier with the most support as the background
    accumulated over frames, weighted by how well its segment moves as the camera was
    predicted to; it becomes identifier 1.

    ``support`` (S,) is each segment's support this frame (the surface it explains, see
    :func:`background_support`); each identifier's accumulated score decays
    by ``params.evidence_decay`` a frame and adds the support of the segment carrying it.
    ``consistency`` (S,) weighs each segment by this frame's evidence (the predicted
    camera motion, :func:`background_support`): the history says which
    identifier has been the background, the prediction whether its segment still moves as
    the background does, and the choice takes their product. Without the product, the
    history alone kept the background on an object that a first frame had merged with it
    (docs/report/core_decisions.md).
    The background is the segment present now with the highest weighted score (the segment
    of most weighted support when no segment has an identifier). When its identifier is not
    1, the two identifiers swap (the background is re-acquired in this frame, never lost):
    in the scores here, and by the permutation returned in every later stage's state.
    ``initialised`` () bool: some segment had an identifier before (a swap then
    re-acquires the background).

    Returns ``(state, segment_ids, background () int32 spatial label 1..S or 0,
    reacquired () bool, permutation (max_ids,) int32)``.
    """
    s, m = segment_ids.shape[0], state.score.shape[0]
    present = segment_ids > 0
    add = jnp.zeros((m,), jnp.float32).at[jnp.clip(segment_ids - 1, 0, m - 1)].add(
        jnp.where(present, support, 0.0))
    score = params.evidence_decay * state.score + add
    seg_score = jnp.where(present, score[jnp.clip(segment_ids - 1, 0, m - 1)], -1.0)
    weighted = jnp.where(support > 0, seg_score * consistency, -1.0)
    any_id = jnp.any(present & (support > 0))
    pick = jnp.where(any_id, jnp.argmax(weighted), jnp.argmax(support * consistency))
    has = jnp.any(support > 0)
    background = jnp.where(has, pick + 1, 0).astype(jnp.int32)
    bg_id = jnp.where(has & present[pick], segment_ids[pick], STATIC_ID)
    reacquired = has & (bg_id != STATIC_ID) & initialised
    perm = swap_perm(bg_id, m)
    segment_ids = relabel(segment_ids, perm)
    # a segment without an identifier chosen as the background takes identifier 1 (the
    # segment that had it keeps it only if it is the background)
    segment_ids = jnp.where(jnp.arange(s) == pick, jnp.where(has, STATIC_ID, segment_ids[pick]),
                            jnp.where(has & ~present[pick] & (segment_ids == STATIC_ID), 0,
                                      segment_ids))
    return (BackgroundState(score[perm]), segment_ids.astype(jnp.int32), background, reacquired,
            perm)


class BackgroundOut(NamedTuple):
    """The background choice of one frame (:func:`update_background`)."""

    segment_ids: jax.Array  # (max_segments,) int32 identifier of each spatial segment, 1 = background
    background: jax.Array  # () int32 spatial label of the background segment 1..S, 0 none
    reacquired: jax.Array  # () bool the background took its identifier back this frame
    use: jax.Array  # (n,) float32 each point's weight as background for the ego-motion
    belief: jax.Array  # (n,) float32 each valid point's belief weight (belief_weights)
    d2_seg: jax.Array  # (max_segments, n) float32 normalised residuals under each segment
    # (max_ids,) int32 the identifiers renumbered so that the background's is 1 (identifier
    # j + 1 becomes permutation[j] + 1): every later stage applies it to its own state
    permutation: jax.Array


def belief_weights(prior, params: Params):
    """(n,) how much each point counts as background by what earlier frames say of it: 1
    where its static posterior reaches the confidence (established background),
    ``params.unestablished_weight`` where it is not yet established either way (new in
    view, or its evidence faded), 0 where it is believed to move."""
    L = moving_logodds(params)
    return jnp.where(prior <= -L, 1.0, jnp.where(prior <= L, params.unestablished_weight, 0.0))


def background_support(d2_seg, sizes, weights, z, d2_pred, have_last, thr, unpredicted):
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
    ``unpredicted + f``, ``f`` the share of that surface the predicted motion explains too
    (1 before any ego-motion). :func:`choose_background` accumulates the support per
    identifier and weighs it by the consistency.

    Args:
      d2_seg: (S, n) normalised residuals of every point under each segment's motion;
      sizes: (S,) segment sizes (0 unused); weights: (n,) belief weights (0 invalid);
      z: (n,) depth, metres; d2_pred: (n,) normalised residuals under the predicted
      motion; have_last: () bool a prediction exists; thr: () the inlier test;
      unpredicted: () ``params.unpredicted_support``.
    """
    explained = d2_seg <= thr
    surface = explained * (weights * z * z)[None, :]
    follows = jnp.sum(surface * (d2_pred <= thr)[None, :], axis=1)
    total = jnp.sum(surface, axis=1)
    f = jnp.where(have_last, follows / jnp.maximum(total, tiny()), 1.0)
    used = sizes > 0
    return jnp.where(used, total, 0.0), jnp.where(used, unpredicted + f, 0.0)


def update_background(state: BackgroundState, seg, pts: Points, T_pred, have_last,
                      params: Params, *, cfg: Config, segment_ids, evidence, initialised):
    """The background of this frame and the points the ego-motion may use.

    The segment whose motion explains the most surface that earlier frames established as
    background and that moves as the camera was predicted to (:func:`background_support`,
    :func:`choose_background`; its identifier becomes 1). The ego-motion may use every
    valid point, weighted by its belief, but those in a segment that moves unlike the
    background (Algorithm 1's refinement on all points, for the background; a segment the
    background's motion explains is a piece of the background that fast motion or depth
    distortion split off).

    Args:
      state: the background's scores entering the frame; seg: the spatial
      ``Segmentation``; pts: the frame's points (:func:`jaxvo.core.noise.frame_points`);
      T_pred: (4, 4) the predicted camera motion; have_last: () bool whether it was
      measured; segment_ids: (max_segments,) int32 the segments' identifiers
      (:func:`jaxvo.core.identifiers.identify`); evidence: (n,) float32 each cell's moving
      log-odds entering the frame (:mod:`jaxvo.core.evidence`); initialised: () bool some
      segment had an identifier before.

    Returns:
      ``(state, BackgroundOut)``; ``BackgroundOut.permutation`` renumbers the identifiers
      of the later stages' states so that the background's is 1.
    """
    valid = pts.valid
    d2_all = residuals_many(jnp.concatenate([T_pred[None], seg.motions]), pts.src, pts.dst,
                            pts.noise)[0]
    d2_pred, d2_seg = d2_all[0], d2_all[1:]
    z = jnp.maximum(pts.src[2], pts.dst[2])
    belief = jnp.where(valid, belief_weights(evidence, params), 0.0)
    support, consistency = background_support(d2_seg, seg.sizes, belief, z, d2_pred,
                                              have_last, pts.thr, params.unpredicted_support)
    state, segment_ids, bg, reacquired, perm = choose_background(
        state, segment_ids, support, consistency, initialised, params)
    bgi = jnp.maximum(bg - 1, 0)
    static_seg = (explained_segments(seg.labels, d2_seg[bgi], valid, pts.thr, cfg=cfg)
                  | (jnp.arange(1, cfg.max_segments + 1) == bg))
    in_moving_seg = (seg.labels > 0) & ~static_seg[jnp.clip(seg.labels - 1, 0, None)]
    use = jnp.where(in_moving_seg, 0.0, belief)
    return state, BackgroundOut(segment_ids, bg, reacquired, use, belief, d2_seg, perm)
