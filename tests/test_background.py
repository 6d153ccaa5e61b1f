"""The background choice's evidence of which motion lies behind (jaxvo.core.background):
depth order at the boundaries between motions, its log-likelihood, and the choice and the
"no background in view" state built on them."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.config import Config, Params
from jaxvo.core.background import (
    choose_background,
    depth_order,
    order_loglik,
)

CFG = Config()
S, M = CFG.max_segments, CFG.max_ids
GRID = (6, 8)
N = GRID[0] * GRID[1]


def _pad(values, fill=0.0, dtype=jnp.float32):
    return jnp.asarray(list(values) + [fill] * (S - len(values)), dtype)


@functools.partial(jax.jit, static_argnames=("grid",))
def _order(labels, z, sigma, explained, tie, *, grid):
    return depth_order(labels, z, sigma, explained, tie, grid=grid, cfg=CFG)


def _order_reference(labels, z, sigma, explained, tie, grid):
    """Every cell against each of its 8 neighbours, in plain Python (float64)."""
    rows, cols = grid
    behind = np.zeros((S, S))
    front = np.zeros((S, S))
    for i in range(rows * cols):
        r, c = divmod(i, cols)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                rr, cc = r + dr, c + dc
                if (dr, dc) == (0, 0) or not (0 <= rr < rows and 0 <= cc < cols):
                    continue
                j = rr * cols + cc
                a, b = labels[i], labels[j]
                if a == 0 or b == 0 or a == b:
                    continue
                if explained[b - 1, i] or explained[a - 1, j]:
                    continue  # not decisively unlike: one explained by the other's motion
                dz = z[i] - z[j]
                if dz * dz <= tie * (sigma[i] ** 2 + sigma[j] ** 2):
                    continue
                (behind if dz > 0 else front)[a - 1, b - 1] += 1
    return behind, front


def test_depth_order_counts_the_decisive_pairs_between_motions_as_a_loop_does():
    """Random segments, depths and explanations on a small grid: the counts of pairs where
    each segment lies behind / in front of each other equal a plain loop's."""
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 4, N).astype(np.int32)
    z = rng.uniform(0.5, 4.0, N).astype(np.float32)
    sigma = (1.5e-3 * z * z).astype(np.float32)
    explained = rng.random((S, N)) < 0.4
    tie = 6.63
    behind, front = _order(jnp.asarray(labels), jnp.asarray(z), jnp.asarray(sigma),
                           jnp.asarray(explained), jnp.float32(tie), grid=GRID)
    want_b, want_f = _order_reference(labels, z, sigma, explained, tie, GRID)
    np.testing.assert_array_equal(np.asarray(behind), want_b)  # counts: exact
    np.testing.assert_array_equal(np.asarray(front), want_f)
    # every pair is seen from both sides: a behind b as often as b in front of a
    np.testing.assert_array_equal(want_b, want_f.T)


def test_a_near_mover_lies_in_front_and_pieces_of_one_body_say_nothing():
    """A near box (segment 2, 1 m) on a far wall (segment 1, 3 m): the wall is behind at
    every boundary pair. The same scene where either side's motion explains the other's
    points (one rigid body split in two, or a segment that took in the other's surface)
    gives no pair; a depth step within the noise neither."""
    labels = np.ones(GRID, np.int32)
    labels[1:4, 2:5] = 2
    z = np.where(labels == 2, 1.0, 3.0).astype(np.float32)
    sigma = (1.5e-3 * z * z).astype(np.float32)
    unlike = np.zeros((S, N), bool)
    unlike[0] = labels.ravel() == 1  # each motion explains its own points only
    unlike[1] = labels.ravel() == 2
    args = (jnp.asarray(labels.ravel()), jnp.asarray(z.ravel()), jnp.asarray(sigma.ravel()))
    behind, front = _order(*args, jnp.asarray(unlike), jnp.float32(6.63), grid=GRID)
    # the 3 x 3 box and its ring of 16 wall cells, 8-connected: each ring corner touches 1
    # box cell, each ring side 2 + 3 + 2: 32 pairs
    assert float(behind[0, 1]) == 32 and float(front[1, 0]) == 32
    assert float(jnp.sum(behind)) == 32 and float(jnp.sum(front)) == 32
    one_body = np.ones((S, N), bool)
    behind, front = _order(*args, jnp.asarray(one_body), jnp.float32(6.63), grid=GRID)
    assert float(jnp.sum(behind)) == 0 and float(jnp.sum(front)) == 0
    one_way = unlike.copy()
    one_way[1] = True  # the box's motion explains the wall too: not decisively unlike
    behind, front = _order(*args, jnp.asarray(one_way), jnp.float32(6.63), grid=GRID)
    assert float(jnp.sum(behind)) == 0 and float(jnp.sum(front)) == 0
    flat = jnp.asarray(np.where(labels == 2, 3.001, 3.0).astype(np.float32).ravel())
    behind, _ = _order(args[0], flat, args[2], jnp.asarray(unlike), jnp.float32(6.63),
                       grid=GRID)
    assert float(jnp.sum(behind)) == 0


def test_order_is_log_2p_a_pair_behind_and_log_2_1mp_in_front_within_a_frames_bound():
    """Against the closed form: a segment's evidence is the sum over its decisive pairs,
    within the bound of one frame's evidence."""
    p = 0.85
    behind = np.zeros((S, S), np.float32)
    front = np.zeros((S, S), np.float32)
    behind[0, 1], front[0, 2] = 3, 1  # segment 1: 3 pairs behind, 1 in front
    front[1, 0] = 3  # segment 2: in front of segment 1 three times
    behind[2, 0] = 1
    lb, lf = np.log(2 * p), np.log(2 * (1 - p))
    ev = order_loglik(jnp.asarray(behind), jnp.asarray(front),
                      Params(order_reliability=p, evidence_step=100.0))
    np.testing.assert_allclose(np.asarray(ev)[:3], [3 * lb + lf, 3 * lf, lb], rtol=1e-6)
    assert np.all(np.asarray(ev)[3:] == 0)
    ev = order_loglik(jnp.asarray(behind), jnp.asarray(front), Params())
    assert float(jnp.max(jnp.abs(ev))) <= Params().evidence_step


def _choose(ids, support, candidate=None, **kw):
    return choose_background(_pad(ids, 0, jnp.int32), _pad(support), _pad([1.1] * len(ids)),
                             jnp.bool_(True), Params(**kw), max_ids=M,
                             candidate=None if candidate is None else _pad(candidate, False, bool))


def test_no_background_in_view_when_no_segment_can_be_it():
    """Two segments made mostly of known movers (not candidates): no background, no
    identifier changes, nothing re-acquired; one candidate among them is the background
    whatever its support; a segment without an identifier chosen takes identifier 1."""
    ids, background, reacquired, _ = _choose([2, 3], [10.0, 8.0], candidate=[False, False])
    assert int(background) == 0 and not bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 3])
    ids, background, reacquired, _ = _choose([2, 3], [10.0, 1.0], candidate=[False, True])
    assert int(background) == 2 and bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    ids, background, *_ = _choose([1, 0], [1.0, 10.0])
    assert int(background) == 2
    np.testing.assert_array_equal(np.asarray(ids)[:2], [0, 1])
