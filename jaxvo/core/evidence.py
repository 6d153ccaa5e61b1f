"""The moving evidence of every grid cell: a binary Bayes filter in log-odds (device side).

Besides the identifiers, every cell carries the log-odds that it moves (``evidence`` of
:class:`jaxvo.core.temporal.TemporalState`, (n,) float32, relative to the prior: 0 = no
evidence either way; compensated with the grid model). Each frame adds the evidence of the
cell's own motion under the ego-motion (:func:`moving_evidence`), which decays
(:func:`update_evidence`), and a cell is reported moving once its posterior exceeds the
confidence of the tests (:func:`moving_logodds`): the one notion of moving that every
output follows (:func:`reported_ids`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.identifiers import STATIC_ID
from jaxvo.core.noise import residuals
from jaxvo.core.points import Points
from jaxvo.core.robust import MOST, explains


def moving_logodds(params: Params):
    """The log-odds above which a cell is reported moving: its posterior exceeds the
    confidence of the tests (``logit(confidence)``)."""
    p = jnp.asarray(params.confidence, jnp.float32)
    return jnp.log(p) - jnp.log1p(-p)


def explained_segments(seg_labels, d2, valid, thr, *, cfg: StepOptions):
    """(S,) bool the segments most (:data:`jaxvo.core.robust.MOST`) of whose valid points the
    motion behind ``d2`` (n,) explains within the inlier test ``thr``."""
    member = (seg_labels[None, :] == jnp.arange(1, cfg.max_segments + 1)[:, None]) & valid
    return explains((d2 <= thr)[None, :], member, MOST)


def evidence_delta(seg_labels, d2_ego, d2_seg, explained, valid, params: Params, *,
                   grid: tuple[int, int]):
    """(n,) float32 this frame's log-likelihood ratio, moving over static, of every point.

    Static: the point follows the ego-motion, its residual ``d2_ego`` chi-square with 3
    degrees of freedom. Moving: it follows its own segment's motion, where that segment
    moves unlike the background (not ``explained``): the Gaussian log-ratio
    ``(d2_ego - d2_own) / 2``, which a slow object's points build up over frames though
    each alone stays within the noise. A point outside such a segment is weighed by how
    well the noise explains its residual: against residuals
    ``k = params.evidence_effect`` times the noise, ``-3 log k + d2 (1 - 1/k^2) / 2``.
    A large residual there counts as motion only where its neighbourhood agrees (spatial
    coherence, :func:`neighbourhood_agreement`), so a mover that no segment separates (a
    person: many small parts, none rigid) gains evidence over frames, while a lone large
    residual (a depth edge, a mistracked point) stays an outlier: counted on its own, it
    put cells of static real scenes in motion (docs/report/core_decisions.md). Every ratio is kept
    within ``+-params.evidence_step``: one frame cannot shift the odds by more than that.
    """
    s = d2_seg.shape[0]
    lab = jnp.clip(seg_labels - 1, 0, s - 1)
    own = jnp.take_along_axis(d2_seg, lab[None, :], axis=0)[0]
    in_moving = (seg_labels > 0) & ~explained[lab]
    ratio = static_loglik(d2_ego, params)
    agreed = jnp.minimum(ratio, jnp.maximum(neighbourhood_agreement(ratio, valid, grid=grid),
                                            0.0))
    residual = jnp.where(ratio > 0, agreed, ratio)
    delta = jnp.where(in_moving, 0.5 * (d2_ego - own), residual)
    delta = jnp.clip(delta, -params.evidence_step, params.evidence_step)
    return jnp.where(valid, delta, 0.0).astype(jnp.float32)


def static_loglik(d2, params: Params):
    """(n,) the log-likelihood ratio, moving over static, of points with normalised residuals
    ``d2`` (n,) under the camera's motion, where no other motion is known for them: against
    residuals ``k = params.evidence_effect`` times the noise, ``-3 log k + d2 (1 - 1/k^2) /
    2`` (:func:`evidence_delta`, :func:`jaxvo.core.separation.update_separation`)."""
    k2 = params.evidence_effect ** 2
    return -1.5 * jnp.log(k2) + 0.5 * d2 * (1.0 - 1.0 / k2)


def neighbourhood(values, fill, *, grid: tuple[int, int]):
    """(n, 9) each cell's 3 x 3 neighbourhood (itself included, row by row) of ``values``
    (n,) on the row-major ``grid``; ``fill`` beyond the grid's edge. The one neighbourhood
    of the grid that every stage reads (the evidence's agreement, the mask's growth)."""
    rows, cols = grid
    p = jnp.pad(values.reshape(rows, cols), 1, constant_values=fill)
    return jnp.stack([p[dr:dr + rows, dc:dc + cols].reshape(-1)
                      for dr in range(3) for dc in range(3)], axis=-1)


def neighbourhood_agreement(values, valid, *, grid: tuple[int, int]):
    """(n,) what the valid cells of each cell's 3 x 3 neighbourhood on the ``grid`` agree
    on: the lower quartile of their ``values`` (n,), so that with 9 measured cells 7 must
    reach it; -inf where fewer than 5 are measured (too few to agree). The median (5 of 9)
    flagged static real frames as moving where the lower quartile did not, and the lower
    quartile covered more of the people (docs/report/core_decisions.md).
    """
    near = neighbourhood(jnp.where(valid, values, jnp.inf), jnp.inf, grid=grid)  # (n, 9)
    count = jnp.sum(jnp.isfinite(near), axis=-1)
    median = jnp.take_along_axis(jnp.sort(near, axis=-1),
                                 jnp.maximum(count - 1, 0)[:, None] // 4, axis=-1)[:, 0]
    return jnp.where(count >= 5, median, -jnp.inf)


class EvidenceInputs(NamedTuple):
    """What one frame's moving evidence reads (:func:`moving_evidence`)."""

    seg_labels: jax.Array  # (n,) int32 the spatial segments of the pair (0 none)
    pts: Points  # the frame's points and their noise
    T_cur_prev: jax.Array  # (4, 4) float32 the ego-motion
    d2_seg: jax.Array  # (max_segments, n) float32 normalised residuals under each segment
    ok: jax.Array  # () bool the ego-motion was measured (else no evidence)
    # (n,) float32 the depth order's log-likelihood ratio, moving over static
    # (BackgroundOut.in_front); None: none
    in_front: jax.Array | None = None
    # (n,) bool the points the occlusion memory holds nearer than what was seen; None: none
    occluded: jax.Array | None = None


class EvidenceOut(NamedTuple):
    """One frame's evidence of each point's own motion (:func:`moving_evidence`)."""

    explained: jax.Array  # (max_segments,) bool the segments the ego-motion explains
    delta: jax.Array  # (n,) float32 each point's log-likelihood ratio, moving over static


def moving_evidence(inputs: EvidenceInputs, params: Params, *, cfg: StepOptions,
                    grid: tuple[int, int]) -> EvidenceOut:
    """This frame's evidence of each point's own motion under the ego-motion ``T_cur_prev``:
    an :class:`EvidenceOut`, the segments the ego-motion explains
    (:func:`explained_segments`) and every point's log-likelihood ratio
    (:func:`evidence_delta`); none where the frame is not ``ok``. A measurement without a
    state of its own: the cells' log-odds it feeds are filtered (:func:`update_evidence`)
    and carried with the other per-cell maps (:mod:`jaxvo.core.temporal`).

    Where a point lies adds to it, an independent measurement (where each point lies, not
    how it moves): ``in_front`` (n,), the depth order's log-likelihood ratio of a point
    whose segment lies in front of another motion (:class:`jaxvo.core.background.
    BackgroundOut`; within ``+-params.evidence_step``), for the points whose own motion is
    already as sure a sign of moving as one frame gives (:func:`evidence_delta` at
    ``params.evidence_step``: they do not follow the camera, and their neighbourhood
    agrees): it strengthens that evidence, it does not make it (a static surface in front
    of a mover follows the camera; where noise splits a static scene, which piece lies in
    front is chance); ``occluded`` (n,) bool, the points the occlusion memory holds
    nearer than what was seen there, ``params.evidence_step`` each (the static scene never
    comes nearer than itself).

    ``inputs``: :class:`EvidenceInputs`; ``cfg``, ``grid``: static."""
    seg_labels, pts, T_cur_prev, d2_seg, ok, in_front, occluded = inputs
    d2_ego = residuals(T_cur_prev, pts.src, pts.dst, pts.noise)[0]
    explained = explained_segments(seg_labels, d2_ego, pts.valid, pts.thr, cfg=cfg)
    delta = evidence_delta(seg_labels, d2_ego, d2_seg, explained, pts.valid & ok, params,
                           grid=grid)
    if in_front is not None:
        decided = delta >= params.evidence_step  # as sure as one frame's motion can be
        delta = delta + jnp.where(pts.valid & decided, in_front, 0.0)
    if occluded is not None:
        delta = delta + jnp.where(pts.valid & occluded, params.evidence_step, 0.0)
    return EvidenceOut(explained=explained & ok, delta=delta)


def update_evidence(evidence, delta, measured, hidden, params: Params):
    """One frame of the moving evidence of every cell: a binary Bayes filter in log-odds.

    ``evidence`` is the log-odds that the cell moves, relative to the prior; each frame it
    decays by ``params.evidence_decay`` (so old evidence fades and a cell can change its
    mind) and a measured cell adds this frame's log-likelihood ratio ``delta``. A cell the
    sensor cannot see (``hidden``: no depth reading, as an object nearer than the depth
    range) keeps its evidence unchanged until it is seen again: nothing was learnt of it
    (else an approaching object fades from the mask, docs/report/core_decisions.md). The sum is
    kept within ``+-(logit(confidence) + params.evidence_margin)``, so that a cell can
    pass the moving test at any confidence and a long history cannot outweigh a change
    for longer than about ``bound / |delta|`` frames.

    Args:
      evidence: (n,) float32 compensated log-odds; delta: (n,) float32 this frame's
        log-likelihood ratios (moving over static); measured, hidden: (n,) bool.
    """
    e = params.evidence_decay * evidence + jnp.where(measured, delta, 0.0)
    e = jnp.where(hidden & ~measured, evidence, e)
    bound = moving_logodds(params) + params.evidence_margin
    return jnp.clip(e, -bound, bound).astype(jnp.float32)


def reported_ids(ids, matched, moving, *, cfg: StepOptions):
    """(n,) int32 the identifiers every output reports: an object's identifier (>= 2)
    exactly where the cell is reported moving (``moving`` (n,) bool, its evidence), so that
    the identifiers, the masks, the overlays and the scores agree on what moves.

    Which object a moving cell is: its temporal identifier ``ids`` (n,) where that names
    an object, else this frame's matched measurement ``matched`` (n,), else ``max_ids + 1``
    (moving, not yet named). A cell that is not moving reports the background (1) where
    its identifier names an object (a region the object has left keeps the object's
    identifier in the grid model until the model is updated there; a stopped object), else
    its own identifier (0 unknown, 1 static).
    """
    name = jnp.where(ids >= 2, ids, jnp.where(matched >= 2, matched, cfg.max_ids + 1))
    return jnp.where(moving, name, jnp.where(ids >= 2, STATIC_ID, ids)).astype(jnp.int32)
