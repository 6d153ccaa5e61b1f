"""Label matching (thesis 4.1, jaxvo.core.identifiers): the correlation and score of
eqs. (4.1), (4.2) against hand-computed values, identifiers that persist through permuted
segment numbers, newcomers, brief absences and reuse (Algorithm 3), and the matched
measurement where the background explains a segment. Scenes from ``temporal_frames``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from temporal_frames import (
    CELL,
    CFG,
    GRID,
    N,
    box,
    jitted_frame,
    make_seg,
    params,
    region_ids,
    run,
    scene,
    temporal_frame,
    zero_disp,
)

from jaxvo.core.identifiers import identify_new, label_correlation, match_segments, measured_labels
from jaxvo.core.temporal import init_temporal

_correlation = jax.jit(label_correlation, static_argnames=("num_segments", "num_ids"))
_match = jax.jit(match_segments)


@pytest.fixture(scope="module")
def step():
    return jitted_frame()


def _eight_objects():
    # background + 7 objects of 2 x 3 cells fill all 8 identifiers (max_ids = 8)
    spots = [
        (0, 2, 0, 3),
        (0, 2, 5, 8),
        (0, 2, 10, 13),
        (4, 6, 0, 3),
        (4, 6, 5, 8),
        (4, 6, 10, 13),
        (8, 10, 0, 3),
    ]
    return spots


def test_correlation_and_score_hand_example():
    seg = jnp.array([1, 1, 1, 2, 2, 0, 2, 1], jnp.int32)
    ids = jnp.array([1, 1, 2, 2, 2, 2, 0, 1], jnp.int32)
    corr, n_seg, n_id = _correlation(seg, ids, num_segments=2, num_ids=3)
    # N_1 = 4, N_2 = 3; N^id over the measured cells (seg > 0; cell 5 is not) = 3, 3, 0;
    # N_11 = 3, N_12 = 1, N_21 = 0, N_22 = 2
    want = np.array([[3 / np.sqrt(12), 1 / np.sqrt(12), 0.0], [0.0, 2 / np.sqrt(9), 0.0]])
    np.testing.assert_allclose(np.asarray(corr), want, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(n_seg), [4, 3])
    np.testing.assert_array_equal(np.asarray(n_id), [3, 3, 0])

    assign, score = _match(corr, n_seg, 0.3)
    np.testing.assert_array_equal(np.asarray(assign), [1, 2])
    want_score = (3 / np.sqrt(12) * 4 + 2 / np.sqrt(9) * 3) / 7  # eq. (4.2)
    np.testing.assert_allclose(float(score), want_score, atol=1e-6)

    # below min_match_corr the pair is not a match and counts 0 in the score
    assign, score = _match(corr, n_seg, 0.7)
    np.testing.assert_array_equal(np.asarray(assign), [1, 0])
    np.testing.assert_allclose(float(score), 3 / np.sqrt(12) * 4 / 7, atol=1e-6)


def test_conflict_stronger_correlation_wins():
    seg = jnp.array([1, 1, 1, 2, 2, 0, 2, 1], jnp.int32)
    ids = jnp.array([1, 1, 1, 1, 1, 0, 1, 1], jnp.int32)
    corr, n_seg, _ = _correlation(seg, ids, num_segments=2, num_ids=3)
    # C_11 = 4 / sqrt(4 * 7) = 0.756 beats C_21 = 3 / sqrt(3 * 7) = 0.655
    assign, score = _match(corr, n_seg, 0.3)
    np.testing.assert_array_equal(np.asarray(assign), [1, 0])
    np.testing.assert_allclose(float(score), 4 / np.sqrt(28) * 4 / 7, atol=1e-6)


def test_empty_segments_and_ids_give_zero_not_nan():
    zeros = jnp.zeros((8,), jnp.int32)
    corr, n_seg, _ = _correlation(zeros, zeros, num_segments=4, num_ids=4)
    assign, score = _match(corr, n_seg, 0.3)
    assert np.all(np.asarray(corr) == 0.0)
    assert np.all(np.asarray(assign) == 0) and float(score) == 0.0


def test_correlation_does_not_fall_with_the_share_of_cells_measured():
    """A background segment measured on a tenth of the background's cells still matches
    it (counting every retained cell gave 0.32 for a fifth, 0.22 for a tenth)."""
    n = 1000
    ids = jnp.ones((n,), jnp.int32)
    for share in (1.0, 0.2, 0.1):
        seg = jnp.where(jnp.arange(n) < int(share * n), 1, 0).astype(jnp.int32)
        corr, n_seg, n_id = _correlation(seg, ids, num_segments=2, num_ids=2)
        assert float(n_id[0]) == share * n
        np.testing.assert_allclose(float(corr[0, 0]), 1.0, atol=1e-6)
        assign, _ = _match(corr, n_seg, 0.3)
        assert int(assign[0]) == 1


def test_ids_stable_when_spatial_stage_permutes_segments(step):
    """Two objects move one cell per frame in opposite directions; segment numbers shuffle."""
    rng = np.random.default_rng(3)
    frames, truth = [], []
    for k in range(8):
        a = (2, 6, 1 + k, 6 + k)  # 4 x 5 cells, moves right
        b = (7, 11, 11 - k, 15 - k)  # 4 x 4 cells, moves left
        base = scene([a, b])
        perm = np.concatenate([[0], rng.permutation(3) + 1])
        disp = np.zeros(GRID + (2,), np.float32)
        disp[box(*a), 0] = CELL
        disp[box(*b), 0] = -CELL
        frames.append((perm[base], jnp.asarray(disp.reshape(N, 2)), jnp.ones((N,), bool)))
        truth.append(base)
    _, outs = run(step, frames, params())
    for (lab, _, _), base, out in zip(frames, truth, outs):
        assert region_ids(out.matched, base == 1) == {1}
        assert region_ids(out.matched, base == 2) == {2}  # larger object: next identifier
        assert region_ids(out.matched, base == 3) == {3}
        # segment_ids maps the shuffled segment numbers back to the same identifiers
        for k in (1, 2, 3):
            assert out.segment_ids[lab[base == k][0] - 1] == k


def test_new_object_gets_fresh_identifier_background_stays_one(step):
    a, b = (2, 6, 2, 7), (7, 11, 10, 14)
    frames = [scene([a])] * 4 + [scene([a, b])] * 6
    _, outs = run(step, frames, params(max_age=4.0))
    for out in outs:
        assert region_ids(out.matched, scene([a, b]) == 1) == {1}
        assert region_ids(out.matched, box(*a)) == {2}
    for out in outs[4:]:
        assert region_ids(out.matched, box(*b)) == {3}
    # the grid model takes the new identifier once the candidate saturates: the background
    # apparent model is saturated at max_age = 4, so the 4th frame with b swaps
    assert region_ids(outs[6].ids, box(*b)) == {1}
    assert region_ids(outs[7].ids, box(*b)) == {3}


def test_identify_new_names_the_identifiers_given_to_new_objects(step):
    """The first frame gives the background 1 and the object 2; a frame that matches them
    gives none; a newcomer's identifier is given anew, the others' are not."""
    a, b = (2, 6, 2, 7), (7, 11, 10, 14)
    prm = params()

    def given(state, lab):
        labels = measured_labels(make_seg(lab), jnp.ones(lab.size, bool), cfg=CFG)
        ids, new = identify_new(state.identifiers, labels, prm, cfg=CFG)
        return set((np.flatnonzero(np.asarray(new)) + 1).tolist()), np.asarray(ids)

    state = init_temporal(cfg=CFG, grid=GRID)
    assert given(state, scene([a]))[0] == {1, 2}
    state, _ = run(step, [scene([a])] * 2, prm)
    assert given(state, scene([a]))[0] == set()
    new, ids = given(state, scene([a, b]))
    assert new == {ids[2]} and ids[2] not in (1, 2)


def test_window_matches_the_best_scoring_past_frame(step):
    """A frame where the object merged into the background does not cost its identifier."""
    a = (3, 8, 4, 9)
    frames = [scene([a])] * 3 + [np.ones(GRID, np.int32)] + [scene([a])] * 2
    _, outs = run(step, frames, params())
    assert region_ids(outs[3].matched, box(*a)) == {1}
    # matching the merged frame alone would leave the object unmatched (new identifier);
    # the frame before it scores higher (eq. 4.2) and returns identifier 2
    assert region_ids(outs[4].matched, box(*a)) == {2}
    assert region_ids(outs[5].matched, box(*a)) == {2}


def test_object_absent_briefly_gets_its_identifier_back(step):
    a, b = (2, 6, 2, 7), (7, 11, 10, 14)
    # absent (labelled background) for 3 frames < match_window
    frames = [scene([a])] * 4 + [np.ones(GRID, np.int32)] * 3 + [scene([a])] * 2
    _, outs = run(step, frames, params(id_retention=10.0))
    assert region_ids(outs[-1].matched, box(*a)) == {2}
    assert region_ids(outs[-2].matched, box(*a)) == {2}

    # unmeasured (label 0) for 8 frames > match_window, < id_retention: the grid retains
    # identifier 2 there, so the object gets it back; a newcomer meanwhile does not take it
    hidden = scene([a])
    hidden[box(*a)] = 0
    newcomer = hidden.copy()
    newcomer[box(*b)] = 2
    frames = [scene([a])] * 4 + [hidden] * 5 + [newcomer] * 3 + [scene([a, b])] * 2
    _, outs = run(step, frames, params(id_retention=10.0))
    assert region_ids(outs[9].matched, box(*b)) == {3}
    assert region_ids(outs[-1].matched, box(*a)) == {2}
    assert region_ids(outs[-1].matched, box(*b)) == {3}


def test_identifier_reuse_after_retention_is_least_observed(step):
    spots = _eight_objects()
    newcomer = (9, 12, 12, 16)  # 3 x 4 cells, where no object ever was
    full = scene(spots)
    _, outs = run(step, [full], params())
    ident = {k: int(outs[0].segment_ids[k + 1]) for k in range(7)}  # object k -> identifier
    assert sorted(ident.values()) == list(range(2, 9))

    def without(*gone):
        return scene([s for k, s in enumerate(spots) if k not in gone])

    def with_new(*gone):
        lab = without(*gone)
        lab[box(*newcomer)] = lab.max() + 1
        return lab

    # object 4 observed 2 frames, object 1 observed 4 frames; retention 3 frames
    frames = [full] * 2 + [without(4)] * 2 + [without(4, 1)] * 3 + [with_new(4, 1)] * 2
    _, outs = run(step, frames, params(id_retention=3.0))
    # both free now (unseen >= 3 frames): the newcomer takes the less observed one
    assert region_ids(outs[7].matched, box(*newcomer)) == {ident[4]}
    assert region_ids(outs[8].matched, box(*newcomer)) == {ident[4]}

    # while every identifier is still retained, a newcomer stays unknown (0)
    frames = [full] * 2 + [without(4)] * 2 + [with_new(4)]
    _, outs = run(step, frames, params(id_retention=3.0))
    assert region_ids(outs[4].matched, box(*newcomer)) == {0}


def test_segments_the_background_explains_are_measured_as_background():
    """``explained`` segments (pieces of the background that noise split off) take
    identifier 1 in the measurement; the others keep the identifiers given to them."""
    upd = jax.jit(lambda st, seg, d, v, prm, ids, ex: temporal_frame(
        st, seg, d, v, prm, segment_ids=ids, explained=ex))
    lab = scene([(3, 8, 4, 9), (9, 12, 10, 14)])
    ids = jnp.asarray([1, 5, 4] + [0] * (CFG.max_segments - 3), jnp.int32)
    explained = jnp.asarray([True, False, True] + [False] * (CFG.max_segments - 3))
    disp, valid = zero_disp()
    _, out = upd(init_temporal(cfg=CFG, grid=GRID), make_seg(lab), disp, valid, params(),
                 ids, explained)
    assert region_ids(out.matched, lab == 1) == {1}
    assert region_ids(out.matched, lab == 2) == {5}
    assert region_ids(out.matched, lab == 3) == {1}
    np.testing.assert_array_equal(out.segment_ids[:3], [1, 5, 1])
