"""The background of each frame: which segment's motion is the camera's (device side).

The thesis gives identifier 1 to the region that covers most of the image, so an object
covering more than half the view took the background's. Here a mover cannot win by size:

* each segment's prior is the surface its motion explains, each point weighted by what
  earlier frames established of it (:func:`background_support`, :func:`belief_weights`:
  the moving evidence, :mod:`jaxvo.core.evidence`, carries every cell's history), and how
  well it moves as the camera was predicted to;
* the background is what lies behind: at the boundaries between motions the static side
  is the farther one (:func:`depth_order`, :func:`order_loglik`); for the points of a
  segment in front of another motion that their own motion already says is moving, this is
  moving evidence that accumulates over frames (:mod:`jaxvo.core.evidence`), never a vote
  in one frame's choice (docs/report/core_decisions.md);
* points the occlusion memory holds nearer than what was seen there
  (:mod:`jaxvo.core.occlusion`) are occluders: never the background's;
* a segment made mostly of known movers is no candidate, and where no segment is one, no
  background is in view: the camera's motion is carried, with its own status.

The chosen segment's identifier becomes 1 by one permutation of the identifiers
(:func:`choose_background`: the background is re-acquired in that frame, never lost),
which the later stages apply to their own states (``BackgroundOut.permutation``).

The belief and the consistency carry what earlier frames decided, under the background
chosen then: a choice made while two motions were still one (a near mover over most of the
first frame) would feed itself. So the commitment stays open to a challenge that does not
depend on it (:func:`challenge_loglik`, :class:`BackgroundState`): every frame in which
another identifier's motion is told apart from the background's, which of the two explains
the larger surface speaks for one of them, and a one-sided sequential test (Page's CUSUM of
those log-likelihood ratios) switches the background to that identifier once the sum
crosses the confidence of every test. Each identifier's motions are chained into the pose
the camera would have were that motion its own (:func:`follow_chains`), from the frame the
identifier was given to its object (its chain and its challenge start there): after a
switch the pose continues from the winner's chain, and the earlier poses back to that frame
are redrawn along it (:func:`jaxvo.core.pipeline.revised_poses`). A switch discards what
was established under the old choice (``BackgroundOut.forget``: the two motions' moving
evidence; the occlusion memory starts afresh).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.evidence import explained_segments, moving_logodds, neighbourhood
from jaxvo.core.geometry import invert_pose, tiny
from jaxvo.core.identifiers import STATIC_ID, IdentifierState, identify_new, relabel, swap_perm
from jaxvo.core.noise import NoiseScale, residuals_many
from jaxvo.core.points import Points
from jaxvo.core.robust import MOST, enough_points, explains
from jaxvo.core.spatial import Segmentation
from jaxvo.status import Status


def depth_order(labels, z, sigma, explained, tie, *, grid: tuple[int, int]):
    """``(behind (S, S), front (S, S))`` float32: for each two segments ``a``, ``b``, the
    decisive neighbour pairs of points that move unlike each other where ``a``'s point lies
    behind ``b``'s, and where it lies in front.

    The background is what lies behind: along the boundary between the static scene and a
    mover, the static side is the farther one. Each valid grid point is compared with the
    valid points of its 3 x 3 neighbourhood (:func:`jaxvo.core.evidence.neighbourhood`) in
    another segment, where the two move decisively unlike each other: neither is explained
    by the other's segment's motion (``explained`` (S, n) bool, each point within the
    inlier test of each segment's motion). Two pieces of one rigid body (a static scene
    split where the depth's distortion exceeds its noise, or a segment that took in some
    background beside a mover) say nothing of which is the background. A pair is
    decisive when the depth difference exceeds the depth noise of both readings at the
    two-motion test ``tie`` (``chi2_1(confidence)``). Nothing depends on the motions'
    sizes, nor on which motion the camera's was before.

    Args:
      labels: (n,) int32 spatial segments of the valid points (0 none or invalid); z: (n,)
      depth of each grid point, metres; sigma: (n,) its depth noise, metres; explained:
      (S, n) bool (S: the segments' count); tie: () the test, noise units squared.
    """
    s = explained.shape[0]
    near_lab = neighbourhood(labels, 0, grid=grid)  # (n, 9)
    near_z = neighbourhood(z, 0.0, grid=grid)
    near_s = neighbourhood(sigma, 0.0, grid=grid)
    i = jnp.broadcast_to(jnp.clip(labels - 1, 0, s - 1)[:, None], near_lab.shape)
    j = jnp.clip(near_lab - 1, 0, s - 1)
    # the point under its neighbour's segment's motion, the neighbour under the point's
    mine = jnp.take_along_axis(explained.T, j, axis=1)  # (n, 9)
    near_explained = jnp.stack([neighbourhood(e, False, grid=grid) for e in explained])
    theirs = jnp.take_along_axis(near_explained, i[None], axis=0)[0]  # (n, 9)
    other = (labels[:, None] > 0) & (near_lab > 0) & (near_lab != labels[:, None])
    other = other & ~mine & ~theirs
    dz = z[:, None] - near_z
    decisive = other & (dz * dz > tie * (sigma[:, None] ** 2 + near_s * near_s))
    zero = jnp.zeros((s, s), jnp.float32)
    behind = zero.at[i, j].add(jnp.where(decisive & (dz > 0), 1.0, 0.0))
    front = zero.at[i, j].add(jnp.where(decisive & (dz < 0), 1.0, 0.0))
    return behind, front


def order_loglik(behind, front, params: Params):
    """(S,) float32 what each segment's depth order (:func:`depth_order`) says of its
    motion being the background's, against the order being random (as where movers border
    movers): where a segment is the background, each decisive pair with another motion has
    it behind with probability ``p = params.order_reliability``, ``log(2 p)`` a pair behind
    and ``log(2 (1 - p))`` a pair in front; their sum, within ``+-params.evidence_step`` as
    every evidence of one frame (the pairs along one boundary are one observation of how
    two surfaces lie, which the bound keeps from counting as many)."""
    p = jnp.asarray(params.order_reliability, jnp.float32)
    total = (jnp.sum(behind, axis=1) * jnp.log(2.0 * p)
             + jnp.sum(front, axis=1) * jnp.log(2.0 * (1.0 - p)))
    return jnp.clip(total, -params.evidence_step, params.evidence_step)


def choose_background(segment_ids, support, consistency, initialised, *, max_ids: int,
                      candidate=None):
    """The background of this frame among the ``candidate`` (S,) bool segments: the one of
    most support times consistency; it becomes identifier 1.

    Each segment's prior is its ``support`` (S,) (the surface its motion explains, each
    point weighted by its belief, :func:`background_support`) times its ``consistency``
    (S,) with the predicted camera motion: the belief carries what earlier frames
    established of each cell (motion, depth order and the occlusion memory, through the
    moving evidence), the prediction says whether the segment still moves as the
    background did. Without the consistency, the belief alone kept the background on an
    object that a first frame had merged with it (docs/report/core_decisions.md). No
    candidate with support: no background in view (0). When the background's identifier
    is not 1, the two identifiers swap (the background is re-acquired in this frame, never
    lost), by the permutation returned for every later stage's state; a segment without an
    identifier takes 1. ``initialised`` () bool: some segment had an identifier before (a
    swap then re-acquires the background); ``max_ids``: the identifiers' count (static).

    Returns ``(segment_ids, background () int32 spatial label 1..S or 0, reacquired ()
    bool, permutation (max_ids,) int32)``.
    """
    s, m = segment_ids.shape[0], max_ids
    present = segment_ids > 0
    prior = jnp.where(support > 0, support * consistency, -1.0)
    usable = prior > 0
    if candidate is not None:
        usable = usable & candidate
    pick = jnp.argmax(jnp.where(usable, prior, -1.0))
    has = jnp.any(usable)
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
    return segment_ids.astype(jnp.int32), background, reacquired, perm


class BackgroundState(NamedTuple):
    """What the background choice carries from frame to frame (:func:`update_background`)."""

    # (max_ids,) float32 for each identifier, the evidence that its motion and not the
    # background's (identifier 1, always 0 here) is the camera's: a CUSUM of this frame's
    # log-likelihood ratios (challenge_loglik), decaying as the moving evidence does
    challenge: jax.Array
    # (max_ids, 4, 4) float32 the last image's camera pose were each identifier's motion
    # the camera's: its segments' motions chained (follow_chains) since the identifier was
    # given to its object; identifier 1's is the committed pose. A switch continues from
    # the winner's, and the past poses are redrawn along it (pipeline.revised_poses)
    chains: jax.Array


def init_background(T_w_c0, *, cfg: StepOptions) -> BackgroundState:
    """No challenge to any identifier; every chain at the first pose ``T_w_c0`` (4, 4)."""
    return BackgroundState(challenge=jnp.zeros((cfg.max_ids,), jnp.float32),
                           chains=jnp.broadcast_to(T_w_c0, (cfg.max_ids, 4, 4)))


def follow_chains(chains, segment_ids, motions, T_pred, T_w_prev, *, cfg: StepOptions):
    """``(start (max_ids, 4, 4), chains (max_ids, 4, 4))``: the last image's pose under each
    identifier (``chains`` (max_ids, 4, 4) as carried, identifier 1's replaced by the
    committed pose ``T_w_prev``) and this image's, each moved by the motion ``motions``
    (S, 4, 4) of the segment that carries the identifier (``segment_ids`` (S,)), or by the
    predicted camera motion ``T_pred`` where none does (out of view: it stays with the
    camera)."""
    m = cfg.max_ids
    start = chains.at[0].set(T_w_prev)
    carries = (segment_ids[:, None] == jnp.arange(1, m + 1)[None, :]).astype(jnp.float32)
    own = jnp.einsum("sm,sij->mij", carries, motions)
    motion = jnp.where(jnp.any(carries > 0, axis=0)[:, None, None], own, T_pred[None])
    return start, start @ jax.vmap(invert_pose)(motion)


def challenge_loglik(segment_ids, explained, member, surface, behind, front, params: Params, *,
                     cfg: StepOptions):
    """(max_ids,) float32 this frame's log-likelihood ratio, for each identifier, that its
    motion is the camera's rather than the background's (identifier 1), from what does not
    depend on which of the two was chosen before.

    Counted only where the two motions are told apart in this frame: most of neither's
    points (``member`` (S, n) bool) lie within the other's inlier test (``explained`` (S, n)
    bool, every point under every segment's motion), so that what two motions explain alike
    (the first frames of a near mover carried with the camera) is evidence for neither.
    Then the thesis's "the background is the largest region", made independent of the
    choice: the odds ``surface_k / surface_1`` of the surfaces the two motions explain
    (``surface`` (S,), square metres, unweighted by belief), a view that changes as the
    camera moves; within ``+-params.evidence_step``, as every evidence of one frame.

    The depth order at the two motions' common boundary (``behind``, ``front`` (S, S),
    :func:`depth_order`) only vetoes: a motion whose points lie in front of the
    background's in more decisive pairs than behind it occludes the world and cannot take
    its place (the static scene never comes nearer than itself); lying behind is no
    evidence for it, as a mover partly behind the static scene (a box behind a table) lies
    behind it there (docs/report/cover_carried.md). Without the veto a near box covering
    most of the view took the background from a room split into two pieces, each smaller.
    ``segment_ids`` (S,) int32: the identifiers of the segments before the choice."""
    m = cfg.max_ids
    is_bg = segment_ids == STATIC_ID
    c = jnp.argmax(is_bg)
    apart = (~explains(explained[c][None, :], member, MOST)
             & ~explains(explained, member[c][None, :], MOST))
    llr = surface_loglik(surface, surface[c], params)
    occludes = front[:, c] > behind[:, c]
    counted = jnp.any(is_bg) & apart & ~occludes & (segment_ids > STATIC_ID) & (surface > 0)
    idx = jnp.clip(segment_ids - 1, 0, m - 1)
    return jnp.zeros((m,), jnp.float32).at[idx].add(jnp.where(counted, llr, 0.0))


def surface_loglik(surface, surface_bg, params: Params):
    """The log-likelihood ratio that a motion explaining ``surface`` (square metres) and not
    the background's explaining ``surface_bg`` is the camera's: the thesis's "the background
    is the largest region" as the odds of the two surfaces, within ``+-params.evidence_step``
    as every evidence of one frame (:func:`challenge_loglik`,
    :func:`jaxvo.core.separation.update_separation`)."""
    size = jnp.log(jnp.maximum(surface, tiny()) / jnp.maximum(surface_bg, tiny()))
    return jnp.clip(size, -params.evidence_step, params.evidence_step)


def page_cusum(score, llr, params: Params):
    """One frame of Page's CUSUM, ``S <- max(0, decay S + llr)`` (``params.evidence_decay``,
    as the moving evidence fades), and whether it crossed ``logit(params.confidence)``: a
    false switch at most as likely as a false moving cell."""
    score = jnp.maximum(params.evidence_decay * score + llr, 0.0)
    return score, score > moving_logodds(params)


def challenge(state: BackgroundState, llr, params: Params):
    """``(challenge (max_ids,), winner () int32)``: one frame of the CUSUM per identifier
    (:func:`page_cusum`) and the identifier whose sum crossed the bound (the largest; 0
    none)."""
    score = page_cusum(state.challenge, llr, params)[0].at[0].set(0.0)
    best = jnp.argmax(score)
    winner = jnp.where(score[best] > moving_logodds(params), best + 1, 0).astype(jnp.int32)
    return score, winner


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
    status: jax.Array  # () int32 Status.OK, or NO_BACKGROUND: no segment can be the background
    # (n,) float32 each point's log-likelihood ratio, moving over static, from its segment's
    # depth order where that lies in front of another motion (order_loglik), 0 elsewhere;
    # jaxvo.core.evidence counts it for the points the ego-motion does not explain
    in_front: jax.Array
    occluded: jax.Array  # (n,) bool points the occlusion memory holds nearer than what was seen
    # (n,) bool the points of the two swapped motions, whose moving evidence was established
    # under the old background: it is discarded
    forget: jax.Array
    # (4, 4) float32 the committed pose of the last image: as entering, or after a switch
    # the new background's chain (BackgroundState.chains), which the ego-motion continues
    T_w_prev: jax.Array
    # () int32 the identifier (numbered as entering the frame) the background switched to,
    # 0 none
    winner: jax.Array
    chains: jax.Array  # (max_ids, 4, 4) BackgroundState.chains after this frame
    # (max_ids,) bool the identifiers given anew this frame (numbered as entering it): their
    # chains and challenges start here, and a redraw of the past along one stops here
    given: jax.Array

    @property
    def switched(self):
        """() bool the challenge switched the background this frame (a winner): the
        occlusion memory, kept under the old one, is discarded."""
        return self.winner > 0


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
    (1 before any ego-motion). Their product is each segment's prior as the background
    (:func:`choose_background`).

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


class BackgroundInputs(NamedTuple):
    """What the background choice of one frame reads (:func:`update_background`)."""

    seg: Segmentation  # the frame's spatial segmentation (jaxvo.core.spatial)
    pts: Points  # the frame's points and their noise (jaxvo.core.points.frame_points)
    T_pred: jax.Array  # (4, 4) float32 the predicted camera motion T_cur_prev
    have_last: jax.Array  # () bool whether T_pred was measured (else identity)
    # (n,) int32 the spatial segments measured this frame
    # (jaxvo.core.identifiers.measured_labels; 0 = none)
    labels: jax.Array
    # the identifiers entering the frame (TemporalState.identifiers): the segments are
    # identified against its window (Algorithm 3, jaxvo.core.identifiers.identify)
    identifiers: IdentifierState
    evidence: jax.Array  # (n,) float32 each cell's moving log-odds entering the frame
    scale: NoiseScale  # the sensor noise (the depth readings' noise of the depth order)
    T_w_c: jax.Array  # (4, 4) float32 the committed pose of the last image (EgoState.T_w_c)
    # (n,) bool the points the occlusion memory holds nearer than what was seen there
    # (jaxvo.core.occlusion); None: none
    occluded: jax.Array | None = None


def update_background(state: BackgroundState, inputs: BackgroundInputs, params: Params, *,
                      cfg: StepOptions, grid: tuple[int, int]):
    """The background of this frame and the points the ego-motion may use.

    Among the segments not made mostly of known movers (established moving, or held
    nearer than what was seen there), the one whose motion explains the most surface that
    earlier frames established as background, moving as the camera was predicted to
    (:func:`background_support`, :func:`choose_background`). This frame's depth order
    (:func:`depth_order`, :func:`order_loglik`) is returned as ``in_front`` for the moving
    evidence, not used in the choice. A segment made mostly of known movers is a
    candidate still where its motion explains enough points established as background (a
    segment that took in the background beside a mover). Where no segment is a candidate
    no background is in view: the status says so and the camera's motion is carried.

    Unless the challenge (:func:`_challenged`) switches it to an identifier the evidence of
    several frames prefers, chosen as in a first frame (no belief, no prediction).

    The ego-motion may use every valid point, weighted by its belief, but those in a
    segment that moves unlike the background (Algorithm 1's refinement on all points, for
    the background; a segment the background's motion explains is a piece of the
    background that fast motion or depth distortion split off) and the occluders.

    Args:
      state: the challenge carried (:class:`BackgroundState`, identifiers as entering);
      inputs: the frame's :class:`BackgroundInputs`; params: numeric settings; cfg: static
      settings; grid: static ``(rows, cols)``.

    Returns:
      ``(BackgroundState, BackgroundOut)``; the output's ``permutation`` renumbers the
      identifiers of the later stages' states so that the background's is 1.
    """
    (seg, pts, T_pred, have_last, labels, identifiers, evidence, scale, T_w_c,
     occluded) = inputs
    segment_ids, given = identify_new(identifiers, labels, params, cfg=cfg)
    valid = pts.valid
    d2_all = residuals_many(jnp.concatenate([T_pred[None], seg.motions]), pts.src, pts.dst,
                            pts.noise)[0]
    d2_pred, d2_seg = d2_all[0], d2_all[1:]
    z = jnp.maximum(pts.src[2], pts.dst[2])
    z_prev = pts.src[2]
    explained = (d2_seg <= pts.thr) & valid
    behind, front = depth_order(jnp.where(valid, seg.labels, 0), z_prev,
                                scale.depth_coeff * z_prev * z_prev, explained, pts.tie,
                                grid=grid)
    member = (seg.labels[None, :] == jnp.arange(1, cfg.max_segments + 1)[:, None]) & valid
    ch = _challenged(state, segment_ids, given, seg, valid, explained, member, behind, front,
                     z, T_pred, T_w_c, identifiers.initialised, params, cfg=cfg)
    switched, winner, evidence = ch.switched, ch.winner, jnp.where(ch.forget, 0.0, evidence)
    occluded = (jnp.zeros_like(valid) if occluded is None else occluded & valid) & ~switched
    belief = jnp.where(valid & ~occluded, belief_weights(evidence, params), 0.0)
    support, consistency = background_support(d2_seg, seg.sizes, belief, z, d2_pred,
                                              have_last & ~switched, pts.thr,
                                              params.unpredicted_support)
    order = order_loglik(behind, front, params)
    mover = (evidence > moving_logodds(params)) | occluded
    candidate = (~explains(mover[None, :], member, MOST)
                 | enough_points(explained & (belief >= 1.0), params))
    candidate = jnp.where(switched, segment_ids == winner, candidate)
    segment_ids, bg, reacquired, perm = choose_background(
        segment_ids, support, consistency, identifiers.initialised, max_ids=cfg.max_ids,
        candidate=candidate)
    bgi = jnp.maximum(bg - 1, 0)
    static_seg = (explained_segments(seg.labels, d2_seg[bgi], valid, pts.thr, cfg=cfg)
                  | (jnp.arange(1, cfg.max_segments + 1) == bg))
    in_moving_seg = (seg.labels > 0) & ~static_seg[jnp.clip(seg.labels - 1, 0, None)]
    use = jnp.where(in_moving_seg, 0.0, belief)
    status = jnp.where((bg == 0) & (seg.num_segments > 0), jnp.int32(Status.NO_BACKGROUND),
                       jnp.int32(Status.OK))
    own = order[jnp.clip(seg.labels - 1, 0, cfg.max_segments - 1)]
    in_front = jnp.where((seg.labels > 0) & valid & (own < 0), -own, 0.0)
    # the challenge and the chains follow the identifiers' renumbering; the new
    # background's challenge is 0
    score = jnp.where(switched, 0.0, ch.score[perm]).at[0].set(0.0)
    T_w_prev = jnp.where(switched, ch.start[jnp.maximum(winner - 1, 0)], T_w_c)
    chains = ch.chains[perm]
    return BackgroundState(challenge=score, chains=chains), BackgroundOut(
        segment_ids=segment_ids, background=bg, reacquired=reacquired, use=use, belief=belief,
        d2_seg=d2_seg, permutation=perm, status=status, in_front=in_front, occluded=occluded,
        forget=ch.forget, T_w_prev=T_w_prev,
        winner=jnp.where(switched, winner, 0).astype(jnp.int32), chains=chains, given=given)


class _Challenge(NamedTuple):
    """One frame of the challenge to the background (:func:`_challenged`), identifiers as
    entering the frame."""

    score: jax.Array  # (max_ids,) the CUSUM of each identifier after this frame
    winner: jax.Array  # () int32 the identifier whose sum crossed the bound, 0 none
    switched: jax.Array  # () bool the background switches to the winner in this frame
    start: jax.Array  # (max_ids, 4, 4) the last image's pose under each identifier
    chains: jax.Array  # (max_ids, 4, 4) this image's
    forget: jax.Array  # (n,) bool the two swapped motions' points (BackgroundOut.forget)


def _challenged(state: BackgroundState, segment_ids, given, seg: Segmentation, valid,
                explained, member, behind, front, z, T_pred, T_w_c, initialised,
                params: Params, *, cfg: StepOptions) -> _Challenge:
    """The challenge of one frame (:func:`challenge_loglik`, :func:`challenge`), whether the
    background switches (a winner in view, once identifiers exist), the identifiers' chains
    (:func:`follow_chains`) and, on a switch, the points of the two swapped motions, whose
    evidence the old choice established: a switch chooses as a first frame would (other
    movers keep their evidence). An identifier ``given`` anew (max_ids,) names a new
    object: its challenge starts at 0 and its chain at the committed pose. Arguments as
    :func:`update_background` computes them."""
    surface = jnp.sum(explained * (z * z)[None, :], axis=1)
    state = BackgroundState(challenge=jnp.where(given, 0.0, state.challenge),
                            chains=jnp.where(given[:, None, None], T_w_c, state.chains))
    score, winner = challenge(state, challenge_loglik(
        segment_ids, explained, member, surface, behind, front, params, cfg=cfg), params)
    switched = (winner > 0) & jnp.any(segment_ids == winner) & initialised
    start, chains = follow_chains(state.chains, segment_ids, seg.motions, T_pred, T_w_c,
                                  cfg=cfg)
    swapped = (segment_ids == winner) | (segment_ids == STATIC_ID)
    forget = switched & valid & (seg.labels > 0) & swapped[
        jnp.clip(seg.labels - 1, 0, cfg.max_segments - 1)]
    return _Challenge(score, winner, switched, start, chains, forget)
