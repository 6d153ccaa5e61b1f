"""Motion temporal segmentation (thesis chapter 4): the per-cell stages on the flow grid,
updated in turn and carried forward together (device side).

The temporal state is three stages' states, each updated by its own module:

* the identifiers and the window of label matching (:mod:`jaxvo.core.identifiers`,
  section 4.1, Algorithm 3);
* the moving evidence of every cell (:mod:`jaxvo.core.evidence`);
* the dual-mode grid model (:mod:`jaxvo.core.grid_model`, section 4.2, eqs. 4.4-4.9).

The background choice (:mod:`jaxvo.core.background`) runs before the ego-motion, with its
own state; it hands this stage a permutation of the identifiers, which each stage applies
to its own state. All three states are anchored on the grid of the *previous* image of the
pair during a step and are carried forward to the current image's grid at its end, with
one compensation (section 4.2.2, :func:`jaxvo.core.grid_model.carry_weights`). The output
``ids`` are on the grid of the previous image of the pair, like ``matched`` and the
segmentation, so they index the same point pairs the ego-motion stage uses.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.evidence import update_evidence
from jaxvo.core.grid_model import (
    GridModelState,
    carry_labels,
    carry_model,
    carry_values,
    carry_weights,
    init_grid_model,
    update_grid_model,
)
from jaxvo.core.identifiers import (
    IdentifierState,
    carried,
    init_identifiers,
    matched_labels,
    update_identifiers,
)


class TemporalState(NamedTuple):
    """The per-cell stages' states, on one grid (carried by the pipeline)."""

    identifiers: IdentifierState  # identifiers in use, the window of Algorithm 3
    evidence: jax.Array  # (n,) float32 log-odds that the cell moves (jaxvo.core.evidence)
    model: GridModelState  # the dual-mode grid model; model.ids the temporal label map


class TemporalOut(NamedTuple):
    ids: jax.Array  # (n,) int32 temporal identifier per grid cell: 0 unknown, 1 static background
    matched: jax.Array  # (n,) int32 the measurement after label matching (Fig. 5.1 "Group")
    segment_ids: jax.Array  # (max_segments,) int32 identifier given to each spatial segment
    evidence: jax.Array  # (n,) float32 log-odds that the cell moves, after this frame


def init_temporal(*, cfg: StepOptions, grid: tuple[int, int]) -> TemporalState:
    """Empty grid models (age 0), no identifier in use, empty matching window, no evidence.

    Args:
      cfg: static configuration (``max_ids``, ``match_window``).
      grid: ``(rows, cols)`` of the flow grid.
    """
    return TemporalState(init_identifiers(cfg=cfg, grid=grid),
                         jnp.zeros((grid[0] * grid[1],), jnp.float32),
                         init_grid_model(cfg=cfg, grid=grid))


class TemporalInputs(NamedTuple):
    """What one frame of the temporal stage reads (:func:`update_temporal`); grid arrays on
    the grid of the previous image of the pair."""

    # (n,) int32 the spatial segments measured this frame
    # (jaxvo.core.identifiers.measured_labels; 0 = none, 1..max_segments)
    labels: jax.Array
    disp: jax.Array  # (n, 2) float32 uv_cur - uv_prev of each grid point, pixels
    flow_valid: jax.Array  # (n,) bool; cells with invalid flow carry no measurement
    # (max_segments,) int32 the identifiers given to the segments
    # (jaxvo.core.identifiers.identify, after the background choice)
    segment_ids: jax.Array
    # (max_segments,) bool the segments whose points the background motion explains; they
    # are measured as identifier 1
    explained: jax.Array
    # (n,) float32 log-likelihood ratios (moving over static) of this frame's measurement
    # of each cell (jaxvo.core.evidence.moving_evidence)
    evidence_delta: jax.Array
    # (n,) float32 the previous image's depth at each cell (a cell without a reading, 0, is
    # hidden and keeps its evidence); None: every cell seen
    depth_prev: jax.Array | None = None
    # (max_ids,) int32 the background choice's renumbering of the identifiers
    # (jaxvo.core.background.BackgroundOut); None: none
    permutation: jax.Array | None = None
    # (n,) bool cells whose evidence was established under a background switched this frame
    # (jaxvo.core.background.BackgroundOut.forget): discarded first; None: none
    forget: jax.Array | None = None
    # (n,) bool cells whose measurement this frame cannot tell their explanations apart
    # (jaxvo.core.separation.SeparationOut.held): they keep their evidence; None: none
    held: jax.Array | None = None


def update_temporal(state: TemporalState, inputs: TemporalInputs, params: Params, *,
                    cfg: StepOptions, grid: tuple[int, int]) -> tuple[TemporalState, TemporalOut]:
    """One frame of motion temporal segmentation (Algorithm 3, eqs. 4.1-4.9).

    Args:
      state: aligned with the grid of the previous image of the pair.
      inputs: the frame's :class:`TemporalInputs`.
      params: ``max_age`` (frames), ``evidence_decay``, ``evidence_margin``,
        ``confidence``; floats or traced arrays.
      cfg, grid: static.

    Returns:
      ``(state, out)``: the state compensated to the current image's grid, and a
      :class:`TemporalOut` on the previous image's grid (the grid of ``labels``).
    """
    (labels, disp, flow_valid, segment_ids, explained, evidence_delta, depth_prev,
     permutation, forget, held) = inputs
    # 4.1: the segments' identifiers; those the ego-motion explains are the background
    seen = carried(segment_ids, cfg.max_ids)
    segment_ids, matched = matched_labels(labels, segment_ids, explained, cfg=cfg)
    # 4.2.1: the grid models with the matched label as measurement
    model = update_grid_model(state.model, matched, params, cfg=cfg, permutation=permutation)
    hidden = jnp.zeros_like(flow_valid) if depth_prev is None else ~(depth_prev > 0)
    prior = state.evidence if forget is None else jnp.where(forget, 0.0, state.evidence)
    measured = flow_valid
    if held is not None:  # nothing learnt: kept as a hidden cell keeps its evidence
        measured, hidden = flow_valid & ~held, hidden | held
    evidence = update_evidence(prior, evidence_delta, measured, hidden, params)
    # the window keeps this frame's identifier map; unmeasured cells keep the grid's label
    identifiers = update_identifiers(state.identifiers, seen,
                                     jnp.where(matched > 0, matched, model.ids),
                                     permutation=permutation)
    out = TemporalOut(ids=model.ids, matched=matched.astype(jnp.int32),
                      segment_ids=segment_ids, evidence=evidence)

    # 4.2.2: every per-cell map carried to the current image's grid for the next step
    carry = carry_weights(disp, flow_valid, model.ids, cfg=cfg, grid=grid)
    identifiers = identifiers._replace(
        history=carry_labels(identifiers.history, carry, cfg.max_ids))
    return TemporalState(identifiers, carry_values(evidence, carry),
                         carry_model(model, carry, cfg=cfg)), out
