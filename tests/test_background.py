"""The background's choice (jaxvo.core.background): depth order at the boundaries between
motions and its log-likelihood, the choice among candidates and the "no background in
view" state, the swap that renumbers every later stage's state, the belief weights and the
support against hand-computed sums."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from temporal_frames import N, params, random_state

from jaxvo.config import Config, Params, params_as_arrays
from jaxvo.core.background import (
    BackgroundState,
    challenge,
    challenge_loglik,
    choose_background,
    depth_order,
    order_loglik,
)
from jaxvo.core.grid_model import update_grid_model
from jaxvo.core.identifiers import permute_identifiers, swap_perm

CFG = Config()
S, M = CFG.max_segments, CFG.max_ids
GRID = (6, 8)
N_SMALL = GRID[0] * GRID[1]  # the small grid of the depth-order tests


def _pad(values, fill=0.0, dtype=jnp.float32):
    return jnp.asarray(list(values) + [fill] * (S - len(values)), dtype)


@functools.partial(jax.jit, static_argnames=("grid",))
def _order(labels, z, sigma, explained, tie, *, grid):
    return depth_order(labels, z, sigma, explained, tie, grid=grid)


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
    labels = rng.integers(0, 4, N_SMALL).astype(np.int32)
    z = rng.uniform(0.5, 4.0, N_SMALL).astype(np.float32)
    sigma = (1.5e-3 * z * z).astype(np.float32)
    explained = rng.random((S, N_SMALL)) < 0.4
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
    unlike = np.zeros((S, N_SMALL), bool)
    unlike[0] = labels.ravel() == 1  # each motion explains its own points only
    unlike[1] = labels.ravel() == 2
    args = (jnp.asarray(labels.ravel()), jnp.asarray(z.ravel()), jnp.asarray(sigma.ravel()))
    behind, front = _order(*args, jnp.asarray(unlike), jnp.float32(6.63), grid=GRID)
    # the 3 x 3 box and its ring of 16 wall cells, 8-connected: each ring corner touches 1
    # box cell, each ring side 2 + 3 + 2: 32 pairs
    assert float(behind[0, 1]) == 32 and float(front[1, 0]) == 32
    assert float(jnp.sum(behind)) == 32 and float(jnp.sum(front)) == 32
    one_body = np.ones((S, N_SMALL), bool)
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


def _choose(ids, support, candidate=None):
    return choose_background(_pad(ids, 0, jnp.int32), _pad(support), _pad([1.1] * len(ids)),
                             jnp.bool_(True), max_ids=M,
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


_choose_jit = jax.jit(choose_background, static_argnames=("max_ids",))


def test_a_segment_that_does_not_move_as_predicted_loses_the_background():
    """Two segments with as much support: the one whose surface the predicted camera
    motion does not explain (consistency near 0: an object a first frame merged with the
    background) loses to the one that moves as the camera was predicted to; with the
    consistency of both, the support decides."""
    ids, background, reacquired, _ = choose_background(
        _pad([1, 2], 0, jnp.int32), _pad([10.0, 9.0]), _pad([1e-3, 1.1]), jnp.bool_(True),
        max_ids=M)
    assert int(background) == 2 and bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    _, background, *_ = _choose([1, 2], [10.0, 9.0])
    assert int(background) == 1


def test_the_swap_relabels_every_map_model_and_count_consistently():
    """Choosing identifier 3 exchanges identifiers 1 and 3 everywhere: by its permutation
    in each later stage's own state the label maps, the window, both models' probability
    vectors and the observation counts; everything else is untouched."""
    rng = np.random.default_rng(8)
    state, prob, _, ids, _ = random_state(9)
    state = state._replace(identifiers=state.identifiers._replace(
        history=jnp.asarray(rng.integers(0, M + 1, (CFG.match_window, N)), jnp.int32),
        obs_count=jnp.asarray(rng.integers(0, 50, M), jnp.int32),
        last_seen=jnp.asarray(rng.integers(-5, 30, M), jnp.int32),
        frame=jnp.int32(30), initialised=jnp.bool_(True),
    ))
    seg_ids = _pad([1, 3, 2], 0, jnp.int32)
    new_ids, background, reacquired, perm_out = _choose_jit(
        seg_ids, _pad([5.0, 60.0, 1.0]), _pad([0.1, 1.1, 0.1]), jnp.bool_(True), max_ids=M)
    assert int(background) == 2 and bool(reacquired)
    perm = np.arange(M + 1)
    perm[[1, 3]] = [3, 1]  # identifier -> identifier, 0 stays 0
    np.testing.assert_array_equal(np.asarray(perm_out), perm[1:] - 1)
    np.testing.assert_array_equal(np.asarray(new_ids)[:3], [3, 1, 2])
    cols = perm[1:] - 1  # column j of the new vectors is column cols[j] of the old
    # each later stage renumbers its own state: an update without a measurement only does
    new_id = jax.jit(permute_identifiers)(state.identifiers, perm_out)
    new_model = jax.jit(lambda m, p: update_grid_model(
        m, jnp.zeros((N,), jnp.int32), params(), cfg=CFG, permutation=p))(state.model, perm_out)
    np.testing.assert_array_equal(np.asarray(new_model.ids), perm[ids])
    np.testing.assert_array_equal(np.asarray(new_id.history),
                                  perm[np.asarray(state.identifiers.history)])
    np.testing.assert_array_equal(np.asarray(new_model.app_prob), prob[:, cols])
    np.testing.assert_array_equal(np.asarray(new_model.cand_prob), prob[::-1][:, cols])
    np.testing.assert_array_equal(np.asarray(new_id.obs_count),
                                  np.asarray(state.identifiers.obs_count)[cols])
    np.testing.assert_array_equal(np.asarray(new_id.last_seen),
                                  np.asarray(state.identifiers.last_seen)[cols])
    # a cell's apparent label follows its probability vector
    np.testing.assert_array_equal(np.argmax(np.asarray(new_model.app_prob), axis=1) + 1,
                                  perm[np.argmax(prob, axis=1) + 1])
    for name in ("app_age", "cand_age"):
        np.testing.assert_array_equal(np.asarray(getattr(new_model, name)),
                                      np.asarray(getattr(state.model, name)), err_msg=name)
    for name in ("history_valid", "frame", "initialised"):
        np.testing.assert_array_equal(np.asarray(getattr(new_id, name)),
                                      np.asarray(getattr(state.identifiers, name)), err_msg=name)
    # swapping back restores the state
    back = jax.jit(permute_identifiers)(new_id, swap_perm(3, M))
    for a, b in zip(jax.tree.leaves(back), jax.tree.leaves(state.identifiers)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_belief_weights_follow_the_evidence():
    from jaxvo.core.background import belief_weights

    L = np.log(0.99 / 0.01)  # logit of the confidence, 4.595
    prior = jnp.asarray([-6.0, -L - 1e-3, -L + 1e-3, 0.0, L - 1e-3, L + 1e-3, 6.0], jnp.float32)
    got = np.asarray(belief_weights(prior, params_as_arrays(Params())))
    np.testing.assert_array_equal(got, np.float32([1, 1, 0.1, 0.1, 0.1, 0, 0]))


def test_background_support_is_the_surface_explained_and_its_share_that_follows():
    """Support: the surface (z^2 per point, times its belief) of every point a segment's
    motion explains; consistency: 0.1 plus the share of it the predicted motion explains
    too (1.1 before any ego-motion)."""
    from jaxvo.core.background import background_support

    z = np.r_[np.full(6, 1.0), np.full(4, 3.0)]  # 6 near points, 4 far
    weights = np.r_[np.ones(9), 0.5]
    d2_seg = np.full((3, 10), 100.0)
    d2_seg[0, :6] = 1.0  # segment 1: the near points
    d2_seg[1, 6:] = 1.0  # segment 2: the far points, and two of the near
    d2_seg[1, :2] = 2.0
    d2_pred = np.full(10, 100.0)
    d2_pred[6:] = 0.5  # the prediction explains the far points
    sizes = np.array([6, 4, 0])
    args = [jnp.asarray(a, jnp.float32) for a in (d2_seg, sizes, weights, z, d2_pred)]
    support, consistency = background_support(*args, jnp.bool_(True), jnp.float32(11.345),
                                              jnp.float32(0.1))
    far = 3 * 9.0 + 0.5 * 9.0
    # float32 sums of a few terms: 1e-6 relative
    np.testing.assert_allclose(np.asarray(support), [6.0, far + 2.0, 0.0], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(consistency), [0.1, 0.1 + far / (far + 2.0), 0.0],
                               rtol=1e-6)
    _, consistency = background_support(*args, jnp.bool_(False), jnp.float32(11.345),
                                        jnp.float32(0.1))
    np.testing.assert_allclose(np.asarray(consistency), [1.1, 1.1, 0.0], rtol=1e-6)


def _two_motions(cross: int, *, surfaces):
    """The background (identifier 1, segment 1) and a challenger (identifier 3, segment 2),
    10 points each; the background's motion explains ``cross`` of the challenger's points
    and the challenger's as many of the background's."""
    n = 20
    member = np.zeros((S, n), bool)
    member[0, :10] = member[1, 10:] = True
    explained = member.copy()
    explained[0, 10:10 + cross] = explained[1, :cross] = True
    no_order = jnp.zeros((S, S), jnp.float32)
    return (_pad([1, 3], 0, jnp.int32), jnp.asarray(explained), jnp.asarray(member),
            _pad(surfaces), no_order, no_order)


def test_the_challenge_counts_the_surfaces_of_two_motions_told_apart():
    """Told apart: the challenger's log-likelihood ratio is the log of the surfaces' ratio,
    within the frame's bound, at its identifier; a smaller challenger's is negative; a
    motion that explains most of the other's points (two motions still one, as in the first
    frames of a carried mover) says nothing, nor does a frame without the background."""
    p = Params()
    llr = challenge_loglik(*_two_motions(0, surfaces=[1.0, 2.0]), params(), cfg=CFG)
    expected = np.zeros(M)
    expected[2] = np.log(2.0)
    np.testing.assert_allclose(np.asarray(llr), expected, rtol=1e-5)
    llr = challenge_loglik(*_two_motions(0, surfaces=[1.0, 100.0]), params(), cfg=CFG)
    assert float(llr[2]) == p.evidence_step
    llr = challenge_loglik(*_two_motions(4, surfaces=[4.0, 1.0]), params(), cfg=CFG)
    np.testing.assert_allclose(float(llr[2]), -np.log(4.0), rtol=1e-5)
    llr = challenge_loglik(*_two_motions(5, surfaces=[1.0, 4.0]), params(), cfg=CFG)
    np.testing.assert_array_equal(np.asarray(llr), np.zeros(M))
    ids, explained, member, surface, behind, front = _two_motions(0, surfaces=[1.0, 4.0])
    llr = challenge_loglik(ids.at[0].set(2), explained, member, surface, behind, front,
                           params(), cfg=CFG)
    np.testing.assert_array_equal(np.asarray(llr), np.zeros(M))
    # in front of the background in more decisive pairs than behind: vetoed; behind: counted
    in_front = front.at[1, 0].set(3.0).at[0, 1].set(0.0)
    llr = challenge_loglik(ids, explained, member, surface, behind.at[1, 0].set(2.0),
                           in_front, params(), cfg=CFG)
    np.testing.assert_array_equal(np.asarray(llr), np.zeros(M))
    llr = challenge_loglik(ids, explained, member, surface, behind.at[1, 0].set(4.0),
                           in_front, params(), cfg=CFG)
    np.testing.assert_allclose(float(llr[2]), np.log(4.0), rtol=1e-5)


def test_the_challenge_is_a_cusum_that_switches_past_the_confidence():
    """One frame at the bound does not cross logit(confidence); two in a row do (the
    first decays by evidence_decay); a negative ratio floors the sum at 0, and the
    background's own entry stays 0."""
    p = Params()
    step = np.zeros(M, np.float32)
    step[2] = p.evidence_step
    state = BackgroundState(challenge=jnp.zeros(M, jnp.float32), chains=jnp.zeros((M, 4, 4)))
    score, winner = challenge(state, jnp.asarray(step), params())
    assert int(winner) == 0
    assert float(score[2]) == p.evidence_step
    score, winner = challenge(state._replace(challenge=score), jnp.asarray(step), params())
    assert int(winner) == 3
    np.testing.assert_allclose(float(score[2]), p.evidence_step * (1 + p.evidence_decay))
    score, winner = challenge(state._replace(challenge=score), jnp.asarray(-4 * step),
                              params())
    assert float(score[2]) == 0.0 and int(winner) == 0
    step[0] = 10.0
    score, _ = challenge(state, jnp.asarray(step), params())
    assert float(score[0]) == 0.0


def test_an_identifier_given_anew_starts_its_challenge_and_its_chain_here():
    """Identifier 3 carried a sum past the bound and a chain of the object it named before;
    given anew this frame, its challenge is this frame's ratio alone (no switch) and its
    chain starts from the committed pose; not given anew, the old sum switches at once."""
    from types import SimpleNamespace

    from jaxvo.core.background import _challenged

    ids, explained, member, _, behind, front = _two_motions(0, surfaces=[1.0, 2.0])
    n = explained.shape[1]
    z = jnp.ones(n, jnp.float32).at[10:].set(jnp.sqrt(2.0))  # the challenger's surface 2x
    seg = SimpleNamespace(motions=jnp.broadcast_to(jnp.eye(4), (S, 4, 4)),
                          labels=jnp.where(member[1], 2, 1).astype(jnp.int32))
    committed = np.eye(4, dtype=np.float32)
    committed[0, 3] = -1.0
    state = BackgroundState(challenge=jnp.zeros(M, jnp.float32).at[2].set(10.0),
                            chains=jnp.broadcast_to(7.0 * jnp.eye(4), (M, 4, 4)))

    def challenged(given):
        return _challenged(state, ids, jnp.asarray(given), seg, jnp.ones(n, bool), explained,
                           member, behind, front, z, jnp.eye(4), jnp.asarray(committed),
                           jnp.bool_(True), params(), cfg=CFG)

    fresh = np.zeros(M, bool)
    fresh[2] = True
    ch = challenged(fresh)
    np.testing.assert_allclose(float(ch.score[2]), np.log(2.0), rtol=1e-5)
    assert int(ch.winner) == 0 and not bool(ch.switched)
    np.testing.assert_allclose(np.asarray(ch.start[2]), committed)
    np.testing.assert_allclose(np.asarray(ch.start[1]), 7.0 * np.eye(4))
    ch = challenged(np.zeros(M, bool))
    assert int(ch.winner) == 3 and bool(ch.switched)
    np.testing.assert_allclose(np.asarray(ch.start[2]), 7.0 * np.eye(4))


def test_each_identifier_chain_follows_its_segment_and_identifier_1_the_committed_pose():
    """Identifier 3 carried by segment 2 moves by that segment's motion, identifier 1 starts
    from the committed pose and moves by segment 1's, an identifier out of view moves with
    the predicted camera motion."""
    from jaxvo.core.background import follow_chains
    from jaxvo.core.geometry import invert_pose

    def shift(x):
        T = np.eye(4, dtype=np.float32)
        T[0, 3] = x
        return T

    motions = np.stack([shift(0.1), shift(0.5)] + [np.eye(4, dtype=np.float32)] * (S - 2))
    chains = np.stack([shift(10.0 * (k + 1)) for k in range(M)])
    committed, T_pred = shift(-1.0), shift(0.2)
    start, moved = follow_chains(jnp.asarray(chains), _pad([1, 3], 0, jnp.int32),
                                 jnp.asarray(motions), jnp.asarray(T_pred),
                                 jnp.asarray(committed), cfg=CFG)
    np.testing.assert_allclose(np.asarray(start[0]), committed)
    np.testing.assert_allclose(np.asarray(start[1:]), chains[1:])
    inv = lambda T: np.asarray(invert_pose(jnp.asarray(T)))  # noqa: E731
    np.testing.assert_allclose(np.asarray(moved[0]), committed @ inv(motions[0]), atol=1e-6)
    np.testing.assert_allclose(np.asarray(moved[2]), chains[2] @ inv(motions[1]), atol=1e-6)
    np.testing.assert_allclose(np.asarray(moved[1]), chains[1] @ inv(T_pred), atol=1e-6)
