"""The dual-mode grid model of the temporal labels, and its compensation (thesis section
4.2, eqs. 4.4-4.9), device side.

Every grid cell holds two simple Gaussian models of its identifier (an apparent and a
candidate one, section 4.2.1), updated with the matched measurement of label matching
(:mod:`jaxvo.core.identifiers`); the temporal label of a cell is its apparent model's.

Anchoring (docs/architecture.md): the labels of a step live on the grid of the *previous*
image of the pair (the points whose flow was measured). The models enter a step aligned
with that grid, are updated there, and are then compensated forward to the current image's
grid with the grid flow (section 4.2.2, :func:`carry_weights`), ready for the next step;
the moving evidence and the window of label matching move with them.

Design decisions where the thesis leaves room:

* After a swap the demoted model is cleared, as in the model the thesis builds on
  (Yi et al. 2013, ref. [20]); keeping it would let a single erroneous label swap back.
  The swap is checked only on frames where the candidate was updated.
* Compensation reads the flow forward: each previous cell's models move to where its
  point went, and a cell without flow moves as its identifier's valid cells do on average
  (the thesis leaves such cells open; see :func:`splat_weights`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import StepOptions
from jaxvo.core.geometry import masked_median
from jaxvo.core.identifiers import relabel


class GridModelState(NamedTuple):
    """The dual-mode simple Gaussian model of every grid cell (section 4.2)."""

    app_prob: jax.Array  # (n, max_ids) float32 apparent model's probability vector
    app_age: jax.Array  # (n,) float32 apparent model's age, 0 = empty, <= max_age
    cand_prob: jax.Array  # (n, max_ids) float32 candidate model's probability vector
    cand_age: jax.Array  # (n,) float32 candidate model's age, 0 = empty
    ids: jax.Array  # (n,) int32 temporal label map, 0 = unknown


def init_grid_model(*, cfg: StepOptions, grid: tuple[int, int]) -> GridModelState:
    """Empty models (age 0), every cell unknown."""
    n, m = grid[0] * grid[1], cfg.max_ids
    return GridModelState(
        app_prob=jnp.zeros((n, m), jnp.float32),
        app_age=jnp.zeros((n,), jnp.float32),
        cand_prob=jnp.zeros((n, m), jnp.float32),
        cand_age=jnp.zeros((n,), jnp.float32),
        ids=jnp.zeros((n,), jnp.int32),
    )


# --------------------------------------------------------------------------------------
# Dual-mode simple Gaussian model (section 4.2.1)
# --------------------------------------------------------------------------------------


def _blend(prob, age, meas_1h, max_age):
    """thesis eqs. (4.4), (4.5); with age 0 this is the direct initialisation."""
    a = age[:, None]
    new_prob = a / (a + 1.0) * prob + 1.0 / (a + 1.0) * meas_1h
    return new_prob, jnp.minimum(age + 1.0, max_age)


def _update_models(state: GridModelState, meas, max_age, *, cfg: StepOptions):
    """Apply the update criteria of section 4.2.1 with the matched label ``meas`` (n,).

    Both models are initialised directly where empty; the apparent model is updated where
    its label equals the measurement, the candidate where the apparent model is not; they
    swap when the candidate saturates (``max_age``) or outgrows the apparent model.

    Returns the new ``(app_prob, app_age, cand_prob, cand_age, ids)``.
    """
    m = cfg.max_ids
    has = meas > 0
    meas_1h = jax.nn.one_hot(meas - 1, m, dtype=jnp.float32)
    app_empty = state.app_age <= 0
    app_label = jnp.argmax(state.app_prob, axis=1) + 1
    # apparent: initialised when empty, updated when its label equals the measurement
    app_touch = has & (app_empty | (app_label == meas))
    # candidate: initialised / updated when the apparent model is not
    cand_touch = has & ~app_touch

    app_p, app_a = _blend(state.app_prob, state.app_age, meas_1h, max_age)
    cand_p, cand_a = _blend(state.cand_prob, state.cand_age, meas_1h, max_age)
    app_p = jnp.where(app_touch[:, None], app_p, state.app_prob)
    app_a = jnp.where(app_touch, app_a, state.app_age)
    cand_p = jnp.where(cand_touch[:, None], cand_p, state.cand_prob)
    cand_a = jnp.where(cand_touch, cand_a, state.cand_age)

    # swap when the candidate saturates or outgrows the apparent model; the demoted model
    # is cleared (as in [20]) so a lone erroneous label cannot swap it straight back
    swap = cand_touch & ((cand_a >= max_age) | (cand_a > app_a))
    app_p = jnp.where(swap[:, None], cand_p, app_p)
    app_a = jnp.where(swap, cand_a, app_a)
    cand_p = jnp.where(swap[:, None], 0.0, cand_p)
    cand_a = jnp.where(swap, 0.0, cand_a)

    # temporal label: only where the apparent model was initialised / updated (or replaced)
    label = (jnp.argmax(app_p, axis=1) + 1).astype(jnp.int32)
    ids = jnp.where(app_touch | swap, label, state.ids)
    return app_p, app_a, cand_p, cand_a, ids


def update_grid_model(state: GridModelState, matched, params, *, cfg: StepOptions,
                      permutation=None) -> GridModelState:
    """One frame of the grid model with the matched measurement ``matched`` (n,) int32
    (:func:`jaxvo.core.identifiers.matched_labels`, 0 = none) on the previous image's grid
    (``params.max_age`` frames); ``permutation`` (max_ids,) (the background choice's)
    renumbers the models' identifiers first. Compensation to the current image's grid is
    :func:`carry_model`'s."""
    if permutation is not None:
        state = state._replace(app_prob=state.app_prob[:, permutation],
                               cand_prob=state.cand_prob[:, permutation],
                               ids=relabel(state.ids, permutation))
    return GridModelState(*_update_models(state, matched, params.max_age, cfg=cfg))


# --------------------------------------------------------------------------------------
# Model compensation (section 4.2.2)
# --------------------------------------------------------------------------------------


def _fill_displacement(disp, flow_valid, ids, *, cfg: StepOptions):
    """(n, 2) displacement of every cell, pixels: its own where its flow is valid, else the
    mean of its identifier's valid cells, else the median of all valid cells."""
    ok = flow_valid & jnp.all(jnp.isfinite(disp), axis=1)
    d_safe = jnp.where(ok[:, None], disp, 0.0)
    med = jnp.stack([masked_median(d_safe[:, i], ok, precision_bits=12) for i in (0, 1)])
    fill = jnp.broadcast_to(med, d_safe.shape)
    id_1h = jax.nn.one_hot(ids - 1, cfg.max_ids, dtype=jnp.float32) * ok[:, None]
    count = id_1h.sum(axis=0)
    mean = (id_1h.T @ d_safe) / jnp.maximum(count, 1.0)[:, None]
    slot = jnp.clip(ids - 1, 0, cfg.max_ids - 1)
    own = (ids > 0) & (count[slot] > 0)
    fill = jnp.where(own[:, None], mean[slot], fill)
    return jnp.where(ok[:, None], d_safe, fill)


def splat_weights(disp, flow_valid, ids, *, cfg: StepOptions, grid: tuple[int, int]):
    """Where each previous cell's model goes: thesis eqs. (4.6)-(4.9) with the flow read
    forward.

    Previous cell ``j`` moves to ``p_j + d_j`` (its own displacement, or its identifier's
    mean where its flow is invalid, see :func:`_fill_displacement`); a cell-sized square
    there overlaps at most four current cells, with the overlap areas as weights. Each
    current cell then averages what lands on it, weighted by overlap (eqs. 4.6-4.9); a cell
    nothing lands on (newly uncovered, or new in view) is empty. Read forward, a moving
    object's model moves with the object: looking back from each current cell with the
    displacement measured at the same previous cell gave the cells an object had just
    entered the background's model alone (docs/report/core_decisions.md). A cell the object has
    just entered still receives the background it covers
    too, and a tie of the two labels goes to the lower identifier, so its label may lag a
    frame.

    Returns ``(dst (n, 4) int32 current cells, w (n, 4) float32 overlap, 0 outside the grid)``.
    """
    rows, cols = grid
    n = rows * cols
    d = _fill_displacement(disp, flow_valid, ids, cfg=cfg) / cfg.cell
    r = (jnp.arange(n) // cols).astype(jnp.float32) + d[:, 1]
    c = (jnp.arange(n) % cols).astype(jnp.float32) + d[:, 0]
    r = jnp.clip(r, -1.0, rows)
    c = jnp.clip(c, -1.0, cols)
    r0, c0 = jnp.floor(r), jnp.floor(c)
    fr, fc = r - r0, c - c0
    rr = jnp.stack([r0, r0, r0 + 1, r0 + 1], axis=1).astype(jnp.int32)
    cc = jnp.stack([c0, c0 + 1, c0, c0 + 1], axis=1).astype(jnp.int32)
    w = jnp.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], axis=1)
    in_grid = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
    w = jnp.where(in_grid, w, 0.0).astype(jnp.float32)
    dst = jnp.clip(rr, 0, rows - 1) * cols + jnp.clip(cc, 0, cols - 1)
    return dst.astype(jnp.int32), w


def _splat(values, dst, w, total):
    """Overlap-weighted average of ``values`` (n, ...) landing on each cell (0 where nothing
    lands)."""
    n = values.shape[0]
    ww = w.reshape((n, 4) + (1,) * (values.ndim - 1))
    acc = jnp.zeros_like(values).at[dst.reshape(-1)].add(
        (ww * values[:, None]).reshape((n * 4,) + values.shape[1:]))
    t = total.reshape((n,) + (1,) * (values.ndim - 1))
    return jnp.where(t > 0, acc / jnp.where(t > 0, t, 1.0), 0.0)


def _splat_labels(labels, dst, w, num: int):
    """Categorical maps (..., n) int32 moved forward: each cell takes the label of most
    overlap landing on it (0: none)."""
    n = labels.shape[-1]
    onehot = jax.nn.one_hot(labels - 1, num, dtype=jnp.float32)  # (..., n, num)
    acc = jnp.zeros(labels.shape + (num,), jnp.float32)
    contrib = w[..., None] * onehot[..., :, None, :]  # (..., n, 4, num)
    acc = acc.at[..., dst.reshape(-1), :].add(contrib.reshape(labels.shape[:-1] + (n * 4, num)))
    best = jnp.argmax(acc, axis=-1)
    return jnp.where(jnp.max(acc, axis=-1) > 0, best + 1, 0).astype(jnp.int32)


class Carry(NamedTuple):
    """Where each previous cell's content goes on the current image's grid
    (:func:`carry_weights`)."""

    dst: jax.Array  # (n, 4) int32 current cells each previous cell lands on
    w: jax.Array  # (n, 4) float32 overlap with each, 0 outside the grid
    total: jax.Array  # (n,) float32 overlap landing on each current cell


def carry_weights(disp, flow_valid, ids, *, cfg: StepOptions, grid: tuple[int, int]) -> Carry:
    """The compensation of one step: :func:`splat_weights` and what lands on each cell."""
    dst, w = splat_weights(disp, flow_valid, ids, cfg=cfg, grid=grid)
    total = jnp.zeros((ids.shape[0],), jnp.float32).at[dst.reshape(-1)].add(w.reshape(-1))
    return Carry(dst, w, total)


def carry_values(values, carry: Carry):
    """Values (n, ...) carried to the current image's grid (overlap-weighted average)."""
    return _splat(values, carry.dst, carry.w, carry.total)


def carry_labels(labels, carry: Carry, num: int):
    """Label maps (..., n) int32 carried to the current image's grid (most overlap)."""
    return _splat_labels(labels, carry.dst, carry.w, num)


def carry_model(state: GridModelState, carry: Carry, *, cfg: StepOptions) -> GridModelState:
    """The models carried forward to the current image's grid (section 4.2.2)."""
    return GridModelState(
        app_prob=carry_values(state.app_prob, carry),
        app_age=carry_values(state.app_age, carry),
        cand_prob=carry_values(state.cand_prob, carry),
        cand_age=carry_values(state.cand_age, carry),
        ids=carry_labels(state.ids, carry, cfg.max_ids),
    )
