"""The background choice's evidence of which motion lies behind (jaxvo.core.background):
depth order at the boundaries between motions, its log-likelihood, and the choice and the
"no background in view" state built on them."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.config import Config, Params
from jaxvo.core.background import (
    BackgroundState,
    choose_background,
    depth_order,
    order_logodds,
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
                if explained[b - 1, i] and explained[a - 1, j]:
                    continue  # one rigid body: each point explained by the other's motion
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
    every boundary pair. The same scene where each side's motion explains the other's
    points (one rigid body split in two) gives no pair; a depth step within the noise
    neither."""
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
    flat = jnp.asarray(np.where(labels == 2, 3.001, 3.0).astype(np.float32).ravel())
    behind, _ = _order(args[0], flat, args[2], jnp.asarray(unlike), jnp.float32(6.63),
                       grid=GRID)
    assert float(jnp.sum(behind)) == 0


def test_order_loglikelihood_is_log_2p_a_pair_behind_and_log_2_1mp_in_front():
    """Against the closed form, within the frame's bound."""
    p = 0.85
    behind = np.zeros((S, S), np.float32)
    front = np.zeros((S, S), np.float32)
    behind[0, 1], front[0, 2] = 3, 1  # segment 1: 3 pairs behind, 1 in front
    front[1, 0] = 3  # segment 2: in front of segment 1 three times
    behind[2, 0] = 1
    prm = Params(order_reliability=p, evidence_step=100.0)
    got = np.asarray(order_logodds(jnp.asarray(behind), jnp.asarray(front), prm))
    want = [3 * np.log(2 * p) + np.log(2 * (1 - p)), 3 * np.log(2 * (1 - p)), np.log(2 * p)]
    np.testing.assert_allclose(got[:3], want, rtol=1e-6)  # float32
    assert np.all(got[3:] == 0)
    clipped = np.asarray(order_logodds(jnp.asarray(behind), jnp.asarray(front), Params()))
    assert clipped.max() <= Params().evidence_step and clipped.min() >= -Params().evidence_step


def _choose(score, behind, ids, support, order=None, holds=None, **kw):
    state = BackgroundState(jnp.asarray(np.r_[score, np.zeros(M - len(score))], jnp.float32),
                            jnp.asarray(np.r_[behind, np.zeros(M - len(behind))], jnp.float32))
    counts = None
    if order is not None:
        b, f = np.zeros((S, S), np.float32), np.zeros((S, S), np.float32)
        for (a, c), n in order.items():  # a lies behind c n times (c in front of a)
            b[a, c] += n
            f[c, a] += n
        counts = (jnp.asarray(b), jnp.asarray(f))
    return choose_background(state, _pad(ids, 0, jnp.int32), _pad(support), _pad([1.1] * len(ids)),
                             jnp.bool_(True), Params(**kw), counts,
                             None if holds is None else _pad(holds, False, bool))


def test_a_mover_in_front_loses_the_background_whatever_its_size():
    """A box (identifier 1, the last frame's background) explains four times the surface
    of the wall behind it and has the longer history; with the depth order of one frame
    (the wall behind the box at 6 pairs) the wall is the background and takes identifier
    1. Without the depth order, the support decides, as it did before."""
    state, ids, background, reacquired, _, order = _choose(
        [50.0, 10.0], [0.0, 0.0], [1, 2], [40.0, 10.0], order={(1, 0): 6})
    assert int(background) == 2 and bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    assert float(order[1]) > 0 > float(order[0])
    # the log-odds swap with the identifiers: identifier 1 (now the wall's) holds the wall's
    assert float(state.behind[0]) == pytest.approx(float(order[1]))
    assert float(state.behind[1]) == pytest.approx(float(order[0]))
    _, _, background, *_ = _choose([50.0, 10.0], [0.0, 0.0], [1, 2], [40.0, 10.0])
    assert int(background) == 1


def test_no_background_in_view_when_every_motion_is_established_in_front():
    """Two boxes whose identifiers' log-odds were established against them (in front of
    the background earlier), the farther box behind the nearer now: neither is the
    background (the view holds movers only), unless its motion explains enough points
    established as background."""
    _, ids, background, reacquired, *_ = _choose(
        [0.0, 30.0, 20.0], [0.0, -6.0, -6.0], [2, 3], [10.0, 8.0], order={(1, 0): 1})
    assert int(background) == 0 and not bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 3])
    _, _, background, *_ = _choose([0.0, 30.0, 20.0], [0.0, -6.0, -6.0], [2, 3], [10.0, 8.0],
                                   order={(1, 0): 1}, holds=[False, True])
    assert int(background) == 2
    # the evidence accumulates without decay, within the bound
    state, *_ = _choose([30.0, 20.0], [5.5, -6.0], [1, 2], [10.0, 8.0], order={(0, 1): 9})
    bound = float(np.log(99.0)) + Params().evidence_margin
    assert float(state.behind[0]) == pytest.approx(bound, rel=1e-6)
