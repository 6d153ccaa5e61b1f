"""Motion spatial segmentation of grid flow (thesis chapter 3, Algorithms 1 and 2), pure JAX.

``segment`` turns the (n, 3) point pairs of one frame pair into rigid-motion segments:

1. hypothesis search (Algorithm 1): ``H`` fixed trips of a ``lax.scan`` carrying a ``done``
   flag (the thesis's ``while h < H and mean(S) > S_min``, and also done once at most
   ``N_threshold`` valid points are inliers of no hypothesis: no segment is left to find;
   ``s_min = 0`` turns both early stops off). Each trip draws
   ``cfg.num_candidates`` minimal samples at once: a seed point weighted by the entropy ``S``
   (inverse-CDF sampling), and ``m - 1`` valid points at random grid offsets within
   ``cfg.sample_radius`` cells of it. A sample whose own points fit its motion is verified;
   the first verified one is refined on all points with a fixed number of trips and becomes a
   hypothesis; the entropy is updated with eq. (3.1).
2. clustering (section 3.3, Algorithm 2): DBSCAN on the Jaccard distance between hypothesis
   inlier sets; each cluster's motion is refined on all points; clusters whose refined motions
   explain mostly the same points are merged (the smaller is dropped: the thesis repeats
   clustering and refining until the clusters settle), clusters with at most
   ``N_threshold`` points are dropped; the rest are ordered by size.
3. labelling: each valid point takes the kept segment that explains it best (smallest
   residual among those it is an inlier of), else 0.

Inlier rule: the sensor noise model (:mod:`jaxvo.core.noise`). A point is an inlier of ``T``
when the Mahalanobis length ``d2`` of its residual ``T p_prev - p_cur`` (eq. 2.19 with the
depth noise along the viewing ray and the tracker's pixel noise across it) is within
``chi2_3(params.confidence)``, the same test at every depth; a minimal sample of ``m``
points fits one motion when their ``d2`` sum within ``chi2_(3m - 6)(confidence)`` (``3 m``
coordinates, 6 fitted). The entropy of eq. (3.1) keeps the thesis's raw squared distance
``E`` in m^2, so that its ``lambda`` and ``delta`` mean what they mean there.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxvo.core.cluster import dbscan, jaccard_distance, overlaps
from jaxvo.core.noise import PointNoise, mahalanobis, residuals, residuals_many, transfer_many
from jaxvo.core.points import Points, frame_points
from jaxvo.core.procrustes import fit_rigid_cols
from jaxvo.core.robust import chi2_quantile, explains
from jaxvo.status import Status

# Stand-in for "no hypothesis explains this point" in residual minima (m^2 and noise
# units): finite so that no inf - inf can appear, large enough that exp(-lambda * _FAR) is 0.
_FAR = 1e6
# Grid offsets drawn around a seed, of which the first m - 1 valid ones are used.
_NEIGHBOUR_DRAWS = 12


class Segmentation(NamedTuple):
    """Rigid-motion segments of one frame pair (docs/architecture.md)."""

    labels: jax.Array  # (n,) int32: 0 = unlabelled, 1..max_segments; 1 = largest segment
    motions: jax.Array  # (max_segments, 4, 4) float32: T_cur_prev of each segment
    sizes: jax.Array  # (max_segments,) int32: points per segment, 0 where unused
    num_segments: jax.Array  # () int32
    hyp_labels: jax.Array  # (n,) int32: best hypothesis 1..H before clustering, 0 none
    num_hypotheses: jax.Array  # () int32
    status: jax.Array  # () int32: a Status code


class _SearchState(NamedTuple):
    entropy: jax.Array  # (n,) float32: S of eq. (3.1), 0 at invalid points
    err_min: jax.Array  # (n,) float32: min_h E_ih, m^2 (_FAR before any hypothesis)
    d2_min: jax.Array  # (n,) float32: min_h d2_ih, noise units (_FAR before any)
    count: jax.Array  # () int32: hypotheses found so far (h of Algorithm 1)
    done: jax.Array  # () bool: the while condition of Algorithm 1 line 3 has failed


class _Hypothesis(NamedTuple):
    motion: jax.Array  # (4, 4) float32: T_cur_prev, identity where not found
    d2: jax.Array  # (n,) float32: normalised residuals, noise units
    inliers: jax.Array  # (n,) bool: valid points within the inlier test
    found: jax.Array  # () bool


class _Clusters(NamedTuple):
    """Algorithm 2's refined clusters, one slot each (:func:`_cluster`)."""

    motions: jax.Array  # (C, 4, 4) float32 each cluster's refined motion T_cur_prev
    d2: jax.Array  # (C, n) float32 every point's normalised residual under each motion
    inliers: jax.Array  # (C, n) bool the points within each motion's inlier test
    keep: jax.Array  # (C,) bool the slots kept as segments


def _res(T, pts: Points):
    """``(d2, e2)``: normalised and raw squared residuals of every point under ``T``."""
    return residuals(T, pts.src, pts.dst, pts.noise)


def _entropy(err_min, valid, params):
    # thesis eq. (3.1). The thesis prints S_i = 1 - min_h exp(-lambda E_ih - delta), but its
    # intent (a point explained by some hypothesis is not sampled again) needs the best
    # hypothesis, max_h exp(-lambda E_ih - delta) = exp(-lambda min_h E_ih - delta).
    s = 1.0 - jnp.exp(-params.lam * err_min - params.delta)
    return jnp.where(valid, s, 0.0)


def _mean_valid(x, valid):
    nv = jnp.sum(valid)
    return jnp.sum(jnp.where(valid, x, 0.0)) / jnp.maximum(nv, 1)


def refine_motion(motion, nmax, pts: Points, iters, bound):
    """Algorithm 1 lines 9-16 as ``iters`` fixed trips.

    Each trip evaluates the motion on all points and, while the inlier count grows, refits
    on the inliers (0/1 weights); once it stops growing the motion is frozen.

    A point counts as an inlier only if the motion explains it better than the hypotheses
    found before (its residual is below ``bound``, their smallest residual). Without this, a
    sample drawn on a slow object is refined into the camera's motion: the far background,
    whose noise is larger than the object's motion per frame, joins the object's inliers,
    outnumbers them, and the refit follows the background.

    Returns ``(motion, d2 (n,), e2 (n,), inliers (n,))``.
    """

    def inliers(motion):
        d2, e2 = _res(motion, pts)
        return d2, e2, pts.valid & (d2 <= pts.thr) & (d2 < bound)

    def trip(carry, _):
        motion, nmax, done = carry
        _, _, inl = inliers(motion)
        count = jnp.sum(inl).astype(jnp.int32)
        improve = (count > nmax) & ~done
        refit, ok = fit_rigid_cols(pts.src, pts.dst, inl.astype(jnp.float32))
        motion = jnp.where(improve & ok, refit, motion)
        nmax = jnp.where(improve, count, nmax)
        return (motion, nmax, done | ~improve), None

    (motion, _, _), _ = lax.scan(trip, (motion, nmax, jnp.bool_(False)), None, length=iters)
    d2, e2, inl = inliers(motion)
    return motion, d2, e2, inl


def _inverse_cdf(weights, u):
    """Flat indices of the cells of ``weights`` (rows, cols) where the cumulative sum of the
    row-major weights first exceeds ``u`` (K,) times their total: cells drawn with
    probability proportional to their weight (never a weight-0 cell, but for rounding at
    a row's end).

    In two levels, a row by the cumulative row sums, then a cell by the cumulative sums
    along it, each cumulative sum a product with a triangular matrix: about half the time
    of ``jnp.cumsum`` and ``jnp.searchsorted``, on every search trip
    (docs/report/core_decisions.md).
    """
    rows, cols = weights.shape
    row_sum = jnp.sum(weights, axis=1)
    # full float32 products: an accelerator's default (TF32, bf16) would blur the sums
    row_cdf = jnp.matmul(row_sum, jnp.triu(jnp.ones((rows, rows), weights.dtype)),
                         precision="highest")
    target = u * row_cdf[-1]
    r = jnp.minimum(jnp.sum(row_cdf[None, :] <= target[:, None], axis=1), rows - 1)
    within = target - (row_cdf[r] - row_sum[r])
    cell_cdf = jnp.matmul(weights[r], jnp.triu(jnp.ones((cols, cols), weights.dtype)),
                          precision="highest")  # (K, cols)
    c = jnp.minimum(jnp.sum(cell_cdf <= within[:, None], axis=1), cols - 1)
    return r * cols + c


def _draw_samples(key, entropy, valid, *, cfg, grid):
    """Indices (K, m) of ``K = cfg.num_candidates`` minimal samples; column 0 is the seed.

    The seed is drawn with probability proportional to the entropy by inverting its CDF
    (:func:`_inverse_cdf`). The other ``m - 1`` points are the first
    valid cells among ``_NEIGHBOUR_DRAWS`` uniform grid offsets within ``cfg.sample_radius``
    cells of it (offset 0 excluded, clipped to the grid); with fewer, the sample repeats the
    seed, and a sample that repeats a cell (also two equal draws) fails its check.

    Taking the first ``m - 1`` offsets as drawn, a sample needed all of them valid: with a
    fifth of the grid valid (motion blur) one sample in 125 qualified, and most trips found
    no hypothesis.
    """
    rows, cols = grid
    k, m = cfg.num_candidates, cfg.sample_size
    r = cfg.sample_radius
    side = 2 * r + 1
    draws = max(_NEIGHBOUR_DRAWS, m - 1)
    # One draw of random bits serves both the seed uniforms (top 24 bits) and the offsets
    # (modulo bias below 1e-8 for the few dozen offsets of a radius of a few cells).
    bits = jax.random.bits(key, (k, 1 + draws))
    u = (bits[:, 0] >> 8).astype(jnp.float32) * (1.0 / (1 << 24))
    seed = _inverse_cdf(entropy.reshape(rows, cols), u)
    off = (bits[:, 1:] % jnp.uint32(side * side - 1)).astype(jnp.int32)
    off = off + (off >= side * side // 2)  # skip the seed's own cell
    rr = jnp.clip(seed[:, None] // cols + off // side - r, 0, rows - 1)
    cc = jnp.clip(seed[:, None] % cols + off % side - r, 0, cols - 1)
    cand = rr * cols + cc  # (K, draws)
    usable = valid[cand]
    rank = jnp.cumsum(usable, axis=1) - 1
    slot = jnp.arange(m - 1)
    pick = usable[:, None, :] & (rank[:, None, :] == slot[None, :, None])  # (K, m-1, draws)
    # a slot left without a usable cell repeats the seed, so the sample fails its check
    chosen = jnp.where(
        jnp.any(pick, axis=2),
        jnp.take_along_axis(cand, jnp.argmax(pick, axis=2), axis=1),
        seed[:, None],
    )
    return jnp.concatenate([seed[:, None], chosen], axis=1)


def _search_step(state, key, pts: Points, params, *, cfg, grid, batch_axis=None):
    """One trip of Algorithm 1 (lines 4-20), a no-op once ``state.done``.

    The work sits under ``lax.cond`` on ``done``: a fixed trip count still, but a frame that
    is explained early skips the remaining trips' work. Under ``vmap`` a per-frame
    predicate turns the cond into a select (both branches run); with ``batch_axis`` naming
    the vmapped frame axis, the predicate is "every frame of the batch is done", which
    stays a real cond, and the work of a trip runs for the whole batch or not at all (it
    is a no-op for the frames already done).
    """
    n = pts.valid.shape[0]

    def skip(state, key):
        eye = jnp.eye(4, dtype=jnp.float32)
        none = _Hypothesis(
            eye, jnp.full((n,), _FAR, jnp.float32), jnp.zeros((n,), bool), jnp.bool_(False)
        )
        return state, none

    def work(state, key):
        return _search_work(state, key, pts, params, cfg=cfg, grid=grid)

    if batch_axis is None:
        all_done = state.done
    else:
        all_done = lax.psum((~state.done).astype(jnp.int32), batch_axis) == 0
    return lax.cond(all_done, skip, work, state, key)


def _search_work(state, key, pts: Points, params, *, cfg, grid):
    m = cfg.sample_size
    valid = pts.valid
    idx = _draw_samples(key, state.entropy, valid, cfg=cfg, grid=grid)  # (K, m)
    earlier = jnp.tril(jnp.ones((m, m), bool), -1)
    dup = jnp.any((idx[:, :, None] == idx[:, None, :]) & earlier, axis=2)
    w = valid[idx] & ~dup
    src, dst = pts.src[:, idx], pts.dst[:, idx]  # (3, K, m)
    noise = PointNoise(pts.noise.ray[:, idx], pts.noise.w_lat[idx], pts.noise.w_ray[idx])
    motions, ok = jax.vmap(fit_rigid_cols, in_axes=(1, 1, 0))(src, dst, w.astype(jnp.float32))
    d2, _ = jax.vmap(residuals, in_axes=(0, 1, 1, PointNoise(1, 0, 0)))(motions, src, dst, noise)
    # Algorithm 1 lines 7-8: the m points must all be valid, distinct and fit one motion:
    # 3 m coordinates less the 6 the fit took leave chi-square with 3 m - 6 degrees of freedom
    fits = jnp.sum(d2, axis=1) <= chi2_quantile(3 * m - 6, params.confidence)
    verified = ok & jnp.all(w, axis=1) & fits
    first = jnp.argmax(verified)
    # a frame already done finds nothing: in a batched trip (batch_axis) the work runs for
    # every frame of the call, and must leave the finished ones as they are
    found = jnp.any(verified) & ~state.done

    motion, d2_all, e2_all, inl = refine_motion(motions[first], jnp.int32(m), pts,
                                                cfg.refine_iters, state.d2_min)
    eye = jnp.eye(4, dtype=motion.dtype)
    hyp = _Hypothesis(
        motion=jnp.where(found, motion, eye),
        d2=jnp.where(found, d2_all, _FAR),
        inliers=inl & found,
        found=found,
    )
    err_min = jnp.where(found, jnp.minimum(state.err_min, e2_all), state.err_min)
    d2_min = jnp.where(found, jnp.minimum(state.d2_min, d2_all), state.d2_min)
    entropy = _entropy(err_min, valid, params)
    count = state.count + found.astype(jnp.int32)
    # Also done when no segment is left to find: Algorithm 2 drops segments of at most
    # N_threshold points, and no more valid points than that lie outside every hypothesis.
    unexplained = jnp.sum(valid & (d2_min > pts.thr))
    done = (
        state.done | (count >= cfg.num_hypotheses) | (_mean_valid(entropy, valid) < params.s_min)
        | ((unexplained <= params.min_segment_points) & (params.s_min > 0))
    )
    return _SearchState(entropy, err_min, d2_min, count, done), hyp


def _cluster_refine(start, active, pts: Points, *, cfg):
    """Algorithm 2 lines 3-11 for all clusters at once, by alternating assignment.

    Each trip gives every point to one active cluster motion it is an inlier of (see
    :func:`_assign`) and refits every motion on its own points. Refining the clusters
    jointly rather than one by one keeps a slow object's motion from being pulled into the
    background's (see :func:`refine_motion`).

    Args:
      start: (C, 4, 4) starting motions (one member hypothesis per cluster slot).
      active: (C,) bool, slots that hold a cluster.

    Returns:
      motions (C, 4, 4), residuals (C, n) in noise units, inliers (C, n) bool (every point
      each motion explains), own (C, n) bool (the points assigned to each cluster).
    """

    def assign(motions):
        d2 = residuals_many(motions, pts.src, pts.dst, pts.noise)[0]
        inl = active[:, None] & pts.valid[None, :] & (d2 <= pts.thr)
        best, has = _assign(d2, inl, active, pts.tie, by_fit=True)
        own = (jnp.arange(motions.shape[0])[:, None] == best[None, :]) & has[None, :]
        return d2, inl, own

    def trip(motions, _):
        _, _, own = assign(motions)
        refit, ok = jax.vmap(lambda w: fit_rigid_cols(pts.src, pts.dst, w))(
            own.astype(jnp.float32))
        return jnp.where((ok & active)[:, None, None], refit, motions), None

    motions, _ = lax.scan(trip, start, None, length=cfg.cluster_refine_iters)
    d2, inl, own = assign(motions)
    return motions, jnp.where(active[:, None], d2, _FAR), inl, own


def _assign(d2, inliers, keep, tie, *, by_fit=False):
    """Per point: index of the kept segment it belongs to, and whether there is one.

    A point takes the segment that explains it best, except that a near tie (a residual
    within ``tie``, chi-square with 1 degree of freedom at the test's confidence, of the
    smallest: the point alone cannot tell the two motions apart) goes to the segment with
    the most inliers. Far points are noisy, so both an object's and the background's
    motion explain a far wall; by residual alone, noise handed a share of it to the object
    (docs/report/core_decisions.md).

    With ``by_fit``, a tie is first decided between each two segments over all the points
    tied between them: the one whose residuals there sum lower wins them (noise averages
    out over a region, a motion's systematic offset does not); among the segments a point
    is tied between, it goes to the one that wins against most of the others, then to the
    one with the most inliers. The joint cluster refinement uses it: a near object's
    motion that also explains the far wall within the wall's noise has the most inliers,
    and by size alone it took the wall from the wall's own motion and refitted to a motion
    between the two (docs/report/core_decisions.md). The final labelling keeps the size
    rule: on real frames under fast motion the background splits into regional fits, each
    a little better on its own region, and the size rule keeps their points together.

    ``d2``/``inliers`` (C, n), ``keep`` (C,), ``tie`` () noise units.
    """
    cand = inliers & keep[:, None]
    e = jnp.where(cand, d2, _FAR * 10)
    e_min = jnp.min(e, axis=0)
    near = cand & (e <= e_min + tie)
    size = jnp.sum(cand, axis=1)
    rank = jnp.broadcast_to(size[:, None].astype(jnp.float32), near.shape)
    if by_fit:
        both = near[:, None, :] & near[None, :, :]  # (C, C, n) tied between a and b
        gap = jnp.sum(jnp.where(both, e[:, None, :] - e[None, :, :], 0.0), axis=2)
        wins = (gap < 0).astype(jnp.float32) @ near.astype(jnp.float32)  # (C, n)
        rank = wins * (d2.shape[1] + 1.0) + rank  # wins first, inlier count second
    best = jnp.argmax(jnp.where(near, rank, -1.0), axis=0)
    return best, jnp.any(cand, axis=0)


def _same_motion(motions_a, own_a, motions_b, pts: Points, params):
    """(A, B) bool: motion ``b`` moves more than ``1 - eps`` of ``a``'s own points to where
    motion ``a`` does, within ``params.same_place`` of the inlier test: the same motion found
    twice (``eps = params.cluster_eps``).

    Comparing the motions where ``a``'s points are (not inlier-set overlap) keeps a small
    object whose motion differs from the camera's by less than the noise at depth.
    ``motions_a`` (A, 4, 4), ``motions_b`` (B, 4, 4); ``own_a`` (A, n) bool. The gap
    ``T_a p - T_b p`` is ``(T_a - T_b) p``: all pairs at once.
    """

    a, b = motions_a.shape[0], motions_b.shape[0]
    diff = (motions_a[:, None] - motions_b[None, :]).reshape(a * b, 4, 4)
    gap = mahalanobis(transfer_many(diff, pts.src), pts.noise).reshape(a, b, -1)
    return explains(gap <= params.same_place * pts.thr, own_a[:, None, :],
                    1.0 - params.cluster_eps, strict=True)


def _leftover_segment(motions, d2_c, inl_c, keep, left, pts: Points, params):
    """One more segment from the valid points no kept segment explains, when they move
    together and unlike every kept segment.

    Joint refinement can lose a whole object: a hypothesis that explains a slow object and
    part of the background at once wins the near ties, and refitting pulls it onto the
    background; the object's points are then inliers of no segment
    (docs/report/core_decisions.md). A fit on the leftover points, refined
    once on its inliers among them, is kept in a free slot if it has more than
    ``min_segment_points`` inliers and is not a kept motion again (:func:`_same_motion`).

    Returns:
      ``(motions, d2_c, inl_c, keep)`` with the new segment in slot ``slot`` when added,
      ``slot``, and ``new`` (n,) bool: its points (all False when none was added). They are
      inliers of no other kept segment, so they are its points in the labelling too.
    """
    inl = left
    for _ in range(2):
        motion, ok = fit_rigid_cols(pts.src, pts.dst, inl.astype(jnp.float32))
        d2 = _res(motion, pts)[0]
        inl = left & (d2 <= pts.thr) & ok
    again = _same_motion(motion[None], inl[None], motions, pts, params)[0]
    slot = jnp.argmin(keep)  # the first free slot
    add = ~jnp.all(keep) & (jnp.sum(inl) > params.min_segment_points) & ~jnp.any(keep & again)
    at = add & (jnp.arange(keep.shape[0]) == slot)
    motions = jnp.where(at[:, None, None], motion, motions)
    d2_c = jnp.where(at[:, None], d2, d2_c)
    inl_c = jnp.where(at[:, None], inl, inl_c)
    return motions, d2_c, inl_c, keep | at, slot, inl & add


def _counts(best, has, c):
    return jnp.sum((best[None, :] == jnp.arange(c)[:, None]) & has[None, :], axis=1)


def segment(key, pts_prev, pts_cur, valid, params, *, cfg, grid, focal=525.0, scale=None,
            batch_axis=None):
    """Segment one frame pair's grid flow into rigid motions (Algorithms 1 and 2).

    Args:
      key: PRNG key.
      pts_prev: (n, 3) previous-frame points, metres (n = rows * cols, row-major grid).
      pts_cur: (n, 3) the same points in the current frame, metres.
      valid: (n,) bool; points that are non-finite or have non-positive depth count as invalid.
      params: :class:`jaxvo.config.Params`; numeric fields may be traced arrays.
      cfg: :class:`jaxvo.config.Config` (static).
      grid: (rows, cols) static.
      focal: () the camera's focal length, pixels (:class:`jaxvo.host.frontend.flow.GridFlow` ``focal``).
      scale: the sensor noise (:class:`jaxvo.core.noise.NoiseScale`), by default the starting
        values of ``params`` (the pipeline passes its current one).
      batch_axis: the name of a ``vmap`` axis over frames (or a tuple of names), when
        called under one: the search then skips a trip only once every frame of the batch
        is done (see :func:`_search_step`); the results are the same.

    Returns:
      :class:`Segmentation` (see :func:`segment_points`, which this calls on the frame's
      :func:`jaxvo.core.points.frame_points`).
    """
    n = grid[0] * grid[1]
    if pts_prev.shape != (n, 3) or pts_cur.shape != (n, 3) or valid.shape != (n,):
        raise ValueError(f"segment: expected ({n}, 3) points and ({n},) valid for grid {grid}")
    pts = frame_points(pts_prev, pts_cur, valid, params, focal=focal, scale=scale)
    return segment_points(key, pts, params, cfg=cfg, grid=grid, batch_axis=batch_axis)


def segment_points(key, pts: Points, params, *, cfg, grid, batch_axis=None) -> Segmentation:
    """:func:`segment` on a frame's points as the pipeline builds them once
    (:func:`jaxvo.core.points.frame_points`).

    Returns:
      :class:`Segmentation`. A frame that fails (too few valid points, no verified sample,
      no segment of more than ``params.min_segment_points`` points) has a non-OK status, all
      labels 0 and identity motions; nothing is NaN.
    """
    n_valid = jnp.sum(pts.valid)
    too_few = (n_valid < max(cfg.sample_size, 3)) | (n_valid <= params.min_segment_points)
    num_hyp, hyps = _search(key, pts, params, too_few, cfg=cfg, grid=grid,
                            batch_axis=batch_axis)
    hyp_best = jnp.argmin(jnp.where(hyps.inliers, hyps.d2, _FAR * 10), axis=0)
    hyp_labels = jnp.where(jnp.any(hyps.inliers, axis=0), hyp_best + 1, 0).astype(jnp.int32)
    clusters = _cluster(hyps, pts, params, cfg=cfg)
    status = jnp.where(
        too_few,
        jnp.int32(Status.TOO_FEW_FLOW),
        jnp.where(num_hyp == 0, jnp.int32(Status.NO_HYPOTHESIS), jnp.int32(Status.OK)),
    )
    return _label(clusters, pts, params, status, cfg=cfg)._replace(
        hyp_labels=hyp_labels, num_hypotheses=num_hyp.astype(jnp.int32))


def _search(key, pts: Points, params, too_few, *, cfg, grid, batch_axis):
    """Algorithm 1: the hypothesis search, ``H`` fixed trips with a ``done`` flag.

    Returns ``(count () int32, hypotheses)``: a :class:`_Hypothesis` stacked over ``H``."""
    n, valid = pts.valid.shape[0], pts.valid
    entropy0 = valid.astype(jnp.float32)
    state0 = _SearchState(
        entropy=entropy0,
        err_min=jnp.full((n,), _FAR, jnp.float32),
        d2_min=jnp.full((n,), _FAR, jnp.float32),
        count=jnp.int32(0),
        done=too_few | ~(_mean_valid(entropy0, valid) > params.s_min),
    )

    def step(state, k):
        return _search_step(state, k, pts, params, cfg=cfg, grid=grid, batch_axis=batch_axis)

    state, hyps = lax.scan(step, state0, jax.random.split(key, cfg.num_hypotheses))
    return state.count, hyps


def _representatives(hyps: _Hypothesis, params, *, cfg):
    """Algorithm 2's clusters (DBSCAN on the Jaccard distance between the hypotheses'
    inlier sets) and one member to stand for each.

    At most ``max_segments`` clusters can be output, so only that many are refined, each
    from one member. Members are taken in order of inlier count; a member whose inliers
    lie mostly (more than ``1 - eps``) inside an already chosen member's is a partial
    re-discovery of that motion and is passed over, so that the next member of its
    cluster (possibly a small moving object chained to it through a bridging hypothesis)
    can stand for the cluster instead.

    Returns ``(top (C,) hypothesis index of each slot, active (C,) bool)``.
    """
    big_h = cfg.num_hypotheses
    inter = overlaps(hyps.inliers)  # (H, H) shared inlier counts
    labels_h, _ = dbscan(
        jaccard_distance(hyps.inliers, inter), hyps.found, params.cluster_eps,
        params.cluster_min_samples,
    )
    size_h = jnp.diagonal(inter)
    covered = inter / jnp.maximum(size_h[:, None], 1)  # (k, j)
    by_size = jnp.argsort(-jnp.where(hyps.found, size_h, -1), stable=True)

    def choose(i, carry):
        chosen, taken = carry  # (H,) hypotheses chosen, (H,) clusters that have one
        h = by_size[i]
        lab = jnp.maximum(labels_h[h], 0)
        ok = (
            (labels_h[h] >= 0)
            & ~taken[lab]
            & ~jnp.any(chosen & (covered[h] > 1.0 - params.cluster_eps))
        )
        return chosen.at[h].set(ok), taken.at[lab].set(taken[lab] | ok)

    chosen, _ = lax.fori_loop(
        0, big_h, choose, (jnp.zeros((big_h,), bool), jnp.zeros((big_h,), bool))
    )
    top = jnp.argsort(jnp.where(chosen, -size_h, 1), stable=True)[:min(big_h, cfg.max_segments)]
    members = jax.nn.one_hot(top, big_h, dtype=bool) & chosen[top][:, None]
    return top, jnp.any(members, axis=1)


def _cluster(hyps: _Hypothesis, pts: Points, params, *, cfg):
    """Algorithm 2: each cluster's motion refined on all points, then the clusters that
    found the same motion twice merged (the smaller dropped: the thesis repeats clustering
    and refining until the clusters settle) and those of at most ``min_segment_points``
    points dropped.

    Returns :class:`_Clusters`.
    """
    n_slots = min(cfg.num_hypotheses, cfg.max_segments)
    top, active = _representatives(hyps, params, cfg=cfg)
    motions, d2_c, inl_c, own_c = _cluster_refine(hyps.motion[top], active, pts, cfg=cfg)
    n_c = jnp.sum(own_c, axis=1)
    big_enough = active & (n_c > params.min_segment_points)

    # Merge: the same motion found twice (cluster k duplicates a larger kept cluster j) ...
    same = _same_motion(motions, own_c, motions, pts, params)  # (k, j)
    # ... and k's motion explains most of j's own points: a near object's motion can move
    # the far wall's points to within the wall's wide noise of where the wall's motion
    # does, but the wall's motion does not explain the object (docs/report/core_decisions.md)
    same = same & explains(inl_c[:, None, :], own_c[None, :, :], 1.0 - params.cluster_eps,
                           strict=True)
    order = jnp.argsort(-n_c, stable=True)

    def merge(k, keep):
        c = order[k]
        dup = jnp.any(keep & same[c])
        return keep.at[c].set(big_enough[c] & ~dup)

    keep = lax.fori_loop(0, n_slots, merge, jnp.zeros((n_slots,), bool))
    return _Clusters(motions, d2_c, inl_c, keep)


def _label(clusters: _Clusters, pts: Points, params, status, *, cfg) -> Segmentation:
    """Labelling: each valid point takes the kept segment that explains it best; segments
    left too small are dropped, one more may be found among the points none explains
    (:func:`_leftover_segment`); segments are numbered by size. ``status`` is the search's
    (OK becomes NO_SEGMENT when no segment is left). The search's own outputs
    (``hyp_labels``, ``num_hypotheses``) are left for the caller to fill in."""
    motions, d2_c, inl_c, keep = clusters
    n_slots, max_seg = keep.shape[0], cfg.max_segments
    best, has = _assign(d2_c, inl_c, keep, pts.tie)
    keep = keep & (_counts(best, has, n_slots) > params.min_segment_points)
    best, has = _assign(d2_c, inl_c, keep, pts.tie)
    motions, d2_c, inl_c, keep, slot, new = _leftover_segment(
        motions, d2_c, inl_c, keep, pts.valid & ~has, pts, params
    )
    best = jnp.where(new, slot, best)
    has = (has | new) & pts.valid
    sizes = jnp.where(keep, _counts(best, has, n_slots), 0)
    rank_order = jnp.argsort(-sizes, stable=True)  # slot of label 1, 2, ...
    rank = jnp.argsort(rank_order)  # label - 1 of each slot
    num_seg = jnp.sum(keep).astype(jnp.int32)
    status = jnp.where((status == Status.OK) & (num_seg == 0), jnp.int32(Status.NO_SEGMENT),
                       status)
    ok = status == Status.OK
    labels = jnp.where(has & ok, rank[best] + 1, 0).astype(jnp.int32)
    eye = jnp.eye(4, dtype=jnp.float32)
    used = keep[rank_order] & ok
    out_motions = jnp.broadcast_to(eye, (max_seg, 4, 4)).at[:n_slots].set(
        jnp.where(used[:, None, None], motions[rank_order], eye))
    out_sizes = jnp.zeros((max_seg,), jnp.int32).at[:n_slots].set(
        jnp.where(used, sizes[rank_order], 0).astype(jnp.int32))
    return Segmentation(
        labels=labels,
        motions=out_motions,
        sizes=out_sizes,
        num_segments=jnp.where(ok, num_seg, 0).astype(jnp.int32),
        hyp_labels=jnp.zeros_like(labels),
        num_hypotheses=jnp.int32(0),
        status=status,
    )
