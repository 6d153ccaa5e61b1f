"""The background's choice (jaxvo.core.background): accumulated support against this
frame's, a segment that does not move as predicted, no identifiers at all, the swap that
renumbers every later stage's state, the belief weights and the support against
hand-computed sums."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from temporal_frames import CFG, N, params, random_state

from jaxvo.config import Params, params_as_arrays
from jaxvo.core.background import BackgroundState, choose_background
from jaxvo.core.grid_model import update_grid_model
from jaxvo.core.identifiers import permute_identifiers, swap_perm

_choose = jax.jit(choose_background)

S = CFG.max_segments
M = CFG.max_ids


def _seg_vec(values, fill=0, dtype=jnp.float32):
    return jnp.asarray(list(values) + [fill] * (S - len(values)), dtype)


def _bg_state(bg_score):
    score = np.zeros(M, np.float32)
    score[: len(bg_score)] = bg_score
    return BackgroundState(jnp.asarray(score))


def choose(bg_score, ids, support, consistency, initialised=True, **kw):
    """``choose_background`` without its permutation: ``(state, ids, background,
    reacquired)``."""
    return _choose(_bg_state(bg_score), _seg_vec(ids, dtype=jnp.int32), _seg_vec(support),
                   _seg_vec(consistency), jnp.bool_(initialised), params(**kw))[:4]


def test_the_identifier_with_the_most_accumulated_support_becomes_the_background():
    """Identifier 2's segment has as much support as identifier 1's this frame but more
    over the past frames (decayed by evidence_decay): it is the background; the two
    identifiers swap, and the run re-acquired its background."""
    state, ids, background, reacquired = choose([5.0, 20.0], [1, 2], [10.0, 10.0], [1.1, 1.1],
                                                evidence_decay=0.9)
    assert int(background) == 2 and bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    # the scores, decayed and added to, swap with the identifiers (float32: 1e-6)
    np.testing.assert_allclose(np.asarray(state.score)[:3], [0.9 * 20 + 10, 0.9 * 5 + 10, 0],
                               rtol=1e-6)
    # the history of identifier 1 wins when the supports are equal to its advantage
    _, ids, background, reacquired = choose([20.0, 5.0], [1, 2], [10.0, 10.0], [1.1, 1.1])
    assert int(background) == 1 and not bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [1, 2])
    # identifier 1 keeps it on a first frame too, where nothing is re-acquired
    _, _, background, reacquired = choose([5.0, 20.0], [1, 2], [10.0, 10.0], [1.1, 1.1],
                                          initialised=False)
    assert int(background) == 2 and not bool(reacquired)


def test_a_segment_that_does_not_move_as_predicted_loses_the_background_despite_history():
    """An object that a first frame merged with the background carries its history; once
    its segment does not move as the camera was predicted to (consistency near 0), the
    segment that does takes the background in the same frame."""
    _, ids, background, reacquired = choose([100.0, 0.0], [1, 2], [10.0, 10.0], [1e-3, 1.1])
    assert int(background) == 2 and bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    # with the consistency of both, history decides (the prediction says nothing)
    _, _, background, _ = choose([100.0, 0.0], [1, 2], [10.0, 10.0], [1.1, 1.1])
    assert int(background) == 1


def test_without_identifiers_the_most_supported_segment_is_the_background():
    """No segment has an identifier (none was free): the segment of most weighted support
    takes identifier 1; no support at all: no background, nothing changes."""
    _, ids, background, reacquired = choose([0.0], [0, 0, 0], [5.0, 8.0, 2.0], [1.1, 1.1, 1.1])
    assert int(background) == 2 and not bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:3], [0, 1, 0])
    state, ids, background, reacquired = choose([3.0, 4.0], [2, 1], [0.0, 0.0], [0.0, 0.0])
    assert int(background) == 0 and not bool(reacquired)
    np.testing.assert_array_equal(np.asarray(ids)[:2], [2, 1])
    np.testing.assert_allclose(np.asarray(state.score)[:2], [2.7, 3.6], rtol=1e-6)


def test_the_swap_relabels_every_map_model_and_count_consistently():
    """Choosing identifier 3 exchanges identifiers 1 and 3 everywhere: the background's
    scores, and by its permutation in each later stage's own state the label maps, the
    window, both models' probability vectors and the observation counts; everything else
    is untouched."""
    rng = np.random.default_rng(8)
    state, prob, _, ids, _ = random_state(9)
    state = state._replace(identifiers=state.identifiers._replace(
        history=jnp.asarray(rng.integers(0, M + 1, (CFG.match_window, N)), jnp.int32),
        obs_count=jnp.asarray(rng.integers(0, 50, M), jnp.int32),
        last_seen=jnp.asarray(rng.integers(-5, 30, M), jnp.int32),
        frame=jnp.int32(30), initialised=jnp.bool_(True),
    ))
    score0 = np.r_[50.0, 1.0, 10.0, np.zeros(M - 3)].astype(np.float32)
    seg_ids = _seg_vec([1, 3, 2], dtype=jnp.int32)
    bg, new_ids, background, reacquired, perm_out = _choose(
        BackgroundState(jnp.asarray(score0)), seg_ids, _seg_vec([5.0, 60.0, 1.0]),
        _seg_vec([0.1, 1.1, 0.1]), jnp.bool_(True), params())
    assert int(background) == 2 and bool(reacquired)
    perm = np.arange(M + 1)
    perm[[1, 3]] = [3, 1]  # identifier -> identifier, 0 stays 0
    np.testing.assert_array_equal(np.asarray(perm_out), perm[1:] - 1)
    np.testing.assert_array_equal(np.asarray(new_ids)[:3], [3, 1, 2])
    score = 0.9 * score0 + np.r_[5.0, 1.0, 60.0, np.zeros(M - 3)]
    cols = perm[1:] - 1  # column j of the new vectors is column cols[j] of the old
    np.testing.assert_allclose(np.asarray(bg.score), score[cols], rtol=1e-6)
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
