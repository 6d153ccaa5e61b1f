"""Identifiers that persist over time: label matching (thesis section 4.1, eqs. 4.1, 4.2,
Algorithm 3), device side.

The spatial stage numbers its segments afresh every frame; this stage gives them
identifiers that persist. Identifiers are ``1 .. cfg.max_ids``; identifier ``1`` is the
static background and ``0`` means unknown / unlabelled. Probability vectors index
identifier ``j`` at position ``j - 1``.

Design decisions where the thesis leaves room (each also noted where it is implemented):

* The identifier maps of the matching window are the matched measurements ``G`` of
  Algorithm 3; cells without a measurement carry the grid's retained temporal label, so a
  region that is temporarily unmeasured keeps its identifier for the matching ("how long grid
  retains its identifier", section 4.1).
* ``N_j`` of eq. (4.1) counts identifier ``j``'s cells among those measured now (see
  :func:`label_correlation`).
* The score of eq. (4.2) divides by the size of *all* current segments, so an unmatched
  segment counts as correlation 0 and a window frame that matches more of the image wins.
* A new identifier is the least observed (frames with a segment carrying it) among the free
  ones; the background identifier ``1`` is preferred whenever it is free (first frame), so
  the largest unmatched segment takes it.
* The segments the ego-motion explains are measured as identifier 1
  (:func:`matched_labels`); which identifier is the background is the background choice's
  (:mod:`jaxvo.core.background`), which hands this stage a permutation of the identifiers.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.status import Status

_NEVER = -(2**30)  # last_seen of an identifier never observed: always free
STATIC_ID = 1  # thesis section 4.1: identifier 1 is the static background
_BIG = 1e30  # sort key of masked-out lanes (finite, so no inf - inf can appear)


class IdentifierState(NamedTuple):
    """The identifiers in use and the window of Algorithm 3 (carried by the pipeline)."""

    # window of Algorithm 3 (tMinSize), aligned with the grid of the grid model
    history: jax.Array  # (match_window, n) int32 identifier maps, most recent first
    history_valid: jax.Array  # (match_window,) bool slot holds a past frame
    obs_count: jax.Array  # (max_ids,) int32 frames in which each identifier was observed
    last_seen: jax.Array  # (max_ids,) int32 update index of the last observation
    frame: jax.Array  # () int32 number of updates so far
    initialised: jax.Array  # () bool some segment has received an identifier


def init_identifiers(*, cfg: StepOptions, grid: tuple[int, int]) -> IdentifierState:
    """No identifier in use, an empty matching window."""
    n, m = grid[0] * grid[1], cfg.max_ids
    return IdentifierState(
        history=jnp.zeros((cfg.match_window, n), jnp.int32),
        history_valid=jnp.zeros((cfg.match_window,), bool),
        obs_count=jnp.zeros((m,), jnp.int32),
        last_seen=jnp.full((m,), _NEVER, jnp.int32),
        frame=jnp.zeros((), jnp.int32),
        initialised=jnp.zeros((), bool),
    )


# --------------------------------------------------------------------------------------
# Label matching (section 4.1)
# --------------------------------------------------------------------------------------


def label_correlation(seg_labels, id_map, *, num_segments: int, num_ids: int):
    """Correlation coefficients between current segments and the identifiers of one frame.

    thesis eq. (4.1): ``C_ij = N_ij / sqrt(N_i N_j)``; 0 where a segment or an identifier is
    absent (no division by zero). ``N_j`` counts identifier ``j``'s cells among the cells
    measured now (``seg_labels > 0``): the window's maps also carry the retained labels of
    unmeasured cells, and counting those made the correlation fall with the share of
    cells measured: under fast motion no segment was matched for frames in a row
    (docs/report/core_decisions.md).

    Args:
      seg_labels: (n,) int32 current segment per grid cell, 0 = none, 1..num_segments.
      id_map: (n,) int32 identifier per grid cell of a past frame, 0 = none, 1..num_ids.
      num_segments, num_ids: static sizes.

    Returns:
      ``(corr (num_segments, num_ids) float32, n_seg (num_segments,) float32,
      n_id (num_ids,) float32)`` with the point counts ``N_i`` and ``N_j``.
    """
    seg_1h = jax.nn.one_hot(seg_labels - 1, num_segments, dtype=jnp.float32)
    id_1h = jax.nn.one_hot(id_map - 1, num_ids, dtype=jnp.float32)
    # N_j counts the identifier's cells among those measured now (a segment label > 0)
    id_1h = id_1h * (seg_labels > 0)[:, None].astype(jnp.float32)
    n_ij = seg_1h.T @ id_1h
    n_seg = seg_1h.sum(axis=0)
    n_id = id_1h.sum(axis=0)
    denom2 = n_seg[:, None] * n_id[None, :]
    ok = denom2 > 0
    corr = jnp.where(ok, n_ij / jnp.sqrt(jnp.where(ok, denom2, 1.0)), 0.0)
    return corr, n_seg, n_id


def match_segments(corr, n_seg, min_corr):
    """Match pairs of one window frame and their score (Algorithm 3 lines 5-7).

    Each segment takes the identifier of highest correlation along its row; a match needs
    ``corr >= min_corr``; when several segments pick the same identifier the strongest
    correlation wins (ties: the lower segment number) and the others stay unmatched.

    Args:
      corr: (S, M) float32 correlations of eq. (4.1).
      n_seg: (S,) float32 grid points of each current segment ``N_i``.
      min_corr: () weakest correlation that counts as a match (may be traced).

    Returns:
      ``(assign (S,) int32 identifier per segment, 0 = unmatched, score () float32)``, the
      score of eq. (4.2): ``sum_i C_i,m(i) N_i / sum_i N_i`` over the matched pairs, the
      denominator running over all current segments.
    """
    s = corr.shape[0]
    best = jnp.argmax(corr, axis=1)
    cbest = jnp.max(corr, axis=1)
    ok = (n_seg > 0) & (cbest >= min_corr) & (cbest > 0)
    idx = jnp.arange(s)
    same = best[:, None] == best[None, :]
    # [i, j]: segment j takes the identifier from segment i
    beats = (cbest[None, :] > cbest[:, None]) | (
        (cbest[None, :] == cbest[:, None]) & (idx[None, :] < idx[:, None])
    )
    lost = jnp.any(same & ok[None, :] & beats & (idx[None, :] != idx[:, None]), axis=1)
    win = ok & ~lost
    assign = jnp.where(win, best + 1, 0).astype(jnp.int32)
    total = n_seg.sum()
    score = jnp.sum(jnp.where(win, cbest, 0.0) * n_seg) / jnp.maximum(total, 1.0)
    return assign, score


def carried(ids, num_ids: int):
    """(num_ids,) bool the identifiers that ``ids`` (S,) int32 (identifier per segment, 0
    none) hold."""
    return jnp.any(jax.nn.one_hot(ids - 1, num_ids, dtype=bool), axis=0)


def _forgotten(state: IdentifierState, retention):
    """(max_ids,) bool: identifiers unobserved for ``retention`` frames before this one; such
    an identifier may be given to a new object (section 4.1)."""
    return (state.frame - state.last_seen).astype(jnp.float32) - 1.0 >= retention


def _assign_identifiers(state: IdentifierState, seg_labels, params: Params, *, cfg: StepOptions):
    """Algorithm 3 and the identifier management of section 4.1.

    Returns ``(segment_ids (S,) int32, n_seg (S,) float32, given (max_ids,) bool)``:
    ``given`` marks the identifiers given anew this frame (to a new object).
    """
    s, m = cfg.max_segments, cfg.max_ids

    def one_frame(id_map):
        corr, n_seg, _ = label_correlation(seg_labels, id_map, num_segments=s, num_ids=m)
        return match_segments(corr, n_seg, params.min_match_corr)

    assign_w, score_w = jax.vmap(one_frame)(state.history)  # (W, S), (W,)
    score_w = jnp.where(state.history_valid, score_w, -1.0)
    # first maximum = the most recent frame on ties (Algorithm 3 line 8 uses '>')
    best_w = jnp.argmax(score_w)
    assign = jnp.where(score_w[best_w] > 0, assign_w[best_w], 0)

    n_seg = jax.nn.one_hot(seg_labels - 1, s, dtype=jnp.float32).sum(axis=0)
    used = carried(assign, m)
    free = ~used & _forgotten(state, params.id_retention)
    unmatched = (n_seg > 0) & (assign == 0)

    # unmatched segments, largest first ...
    seg_order = jnp.argsort(jnp.where(unmatched, -n_seg, _BIG), stable=True)
    seg_rank = jnp.argsort(seg_order, stable=True)
    # ... receive free identifiers, least observed first; the background identifier 1 goes
    # first whenever it is free, so the region covering most of the image takes it
    id_key = jnp.where(free, state.obs_count.astype(jnp.float32), _BIG)
    id_key = id_key.at[0].set(jnp.where(free[0], -1.0, id_key[0]))
    id_order = jnp.argsort(id_key, stable=True)
    num_free = jnp.sum(free)
    new_id = jnp.where(
        unmatched & (seg_rank < num_free),
        id_order[jnp.clip(seg_rank, 0, m - 1)] + 1,
        0,
    )
    segment_ids = jnp.where(assign > 0, assign, new_id).astype(jnp.int32)
    given = carried(new_id, m)
    return segment_ids, n_seg, given


def measured_labels(seg, flow_valid, *, cfg: StepOptions):
    """(n,) int32 the spatial labels of the cells measured this frame (0 elsewhere): a
    segmentation that failed, or a cell without valid flow, measures nothing."""
    labels = jnp.asarray(seg.labels, jnp.int32)
    ok = (jnp.asarray(seg.status) == Status.OK) & flow_valid & (labels > 0)
    return jnp.where(ok & (labels <= cfg.max_segments), labels, 0)


def identify(state: IdentifierState, labels, params: Params, *, cfg: StepOptions):
    """(max_segments,) int32 the identifier of each spatial segment (Algorithm 3, section
    4.1), from the measured ``labels`` (n,) (:func:`measured_labels`); 0 when no identifier
    was free."""
    return identify_new(state, labels, params, cfg=cfg)[0]


def identify_new(state: IdentifierState, labels, params: Params, *, cfg: StepOptions):
    """:func:`identify`'s identifiers, and which identifiers (max_ids,) bool were given
    anew this frame: to a new object, the identifier's past being another object's or
    none."""
    segment_ids, _, given = _assign_identifiers(state, labels, params, cfg=cfg)
    return segment_ids, given


# --------------------------------------------------------------------------------------
# The background's identifier, and the frame's update
# --------------------------------------------------------------------------------------


def relabel(x, perm):
    """Identifier maps ``x`` (any shape, 0 = none) under the permutation ``perm`` (m,)."""
    m = perm.shape[0]
    return jnp.where(x > 0, perm[jnp.clip(x - 1, 0, m - 1)] + 1, 0).astype(x.dtype)


def swap_perm(k, m):
    """(m,) the permutation of identifiers 1..m (as indices 0..m-1) swapping 1 and ``k``."""
    idx = jnp.arange(m)
    return jnp.where(idx == 0, k - 1, jnp.where(idx == k - 1, 0, idx))


def permute_identifiers(state: IdentifierState, perm) -> IdentifierState:
    """The state with identifiers renumbered by ``perm`` (m,) in the window and the counts."""
    return state._replace(history=relabel(state.history, perm),
                          obs_count=state.obs_count[perm], last_seen=state.last_seen[perm])


def matched_labels(labels, segment_ids, explained, *, cfg: StepOptions):
    """This frame's measurement of every cell after label matching: ``(segment_ids
    (max_segments,) int32, matched (n,) int32)``, the segments the ego-motion ``explained``
    (max_segments,) bool measured as identifier 1 (pieces of the background that noise
    split off), each measured cell (``labels`` (n,) > 0) its segment's identifier."""
    s = cfg.max_segments
    segment_ids = jnp.where(explained & (segment_ids > 0), STATIC_ID, segment_ids)
    matched = jnp.where(labels > 0, segment_ids[jnp.clip(labels - 1, 0, s - 1)], 0)
    return segment_ids, matched


def update_identifiers(state: IdentifierState, seen, id_map, *, permutation=None
                       ) -> IdentifierState:
    """One frame of the identifiers: those ``seen`` (max_ids,) bool this frame counted, and
    ``id_map`` (n,) int32 (the matched measurement, the grid's label where unmeasured)
    pushed into the window of Algorithm 3; ``permutation`` (max_ids,) (the background
    choice's, :class:`jaxvo.core.background.BackgroundOut`) renumbers the state first.
    The window stays on the grid of the previous image; the temporal stage carries it
    forward with the grid model (:func:`jaxvo.core.temporal.update_temporal`)."""
    if permutation is not None:
        state = permute_identifiers(state, permutation)
    history = jnp.concatenate([id_map[None], state.history[:-1]], axis=0)
    history_valid = jnp.concatenate([jnp.ones((1,), bool), state.history_valid[:-1]])
    return IdentifierState(
        history=history,
        history_valid=history_valid,
        obs_count=state.obs_count + seen.astype(jnp.int32),
        last_seen=jnp.where(seen, state.frame, state.last_seen),
        frame=state.frame + 1,
        initialised=state.initialised | jnp.any(seen),
    )
