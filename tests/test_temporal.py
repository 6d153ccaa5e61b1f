"""Tests of the temporal stages: label matching (thesis 4.1, jaxvo.core.identifiers), the
dual-mode grid model (4.2.1) and its forward-splat compensation (4.2.2,
jaxvo.core.grid_model), the background's choice (jaxvo.core.background), the moving evidence
(jaxvo.core.evidence) and their join (jaxvo.core.temporal).

Segmentations are built by hand on a 12 x 16 grid; a small NamedTuple stands in for the
spatial stage's ``Segmentation`` (only the documented fields). One jitted update is shared by
most tests (parameters passed as float32 arrays), so the module compiles it once.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.config import Config, Params, params_as_arrays
from jaxvo.core.background import BackgroundState, choose_background
from jaxvo.core.evidence import update_evidence
from jaxvo.core.grid_model import splat_weights, update_grid_model
from jaxvo.core.identifiers import (
    identify,
    label_correlation,
    match_segments,
    measured_labels,
    permute_identifiers,
    swap_perm,
)
from jaxvo.core.temporal import TemporalOut, TemporalState, init_temporal, update_temporal

CFG = Config()
GRID = (12, 16)
ROWS, COLS = GRID
N = ROWS * COLS
CELL = CFG.cell


class FakeSeg(NamedTuple):
    labels: jax.Array  # (n,) int32
    sizes: jax.Array  # (max_segments,) int32
    num_segments: jax.Array  # () int32
    status: jax.Array  # () int32


def make_seg(lab2d, status=0) -> FakeSeg:
    lab = np.asarray(lab2d, np.int32).ravel()
    sizes = np.bincount(lab, minlength=CFG.max_segments + 1)[1:].astype(np.int32)
    return FakeSeg(
        labels=jnp.asarray(lab),
        sizes=jnp.asarray(sizes),
        num_segments=jnp.int32(np.count_nonzero(sizes)),
        status=jnp.int32(status),
    )


def params(**kw) -> Params:
    return params_as_arrays(Params()._replace(**kw))


_TRACES = {"count": 0}


def temporal_frame(state, seg, disp, valid, prm, *, segment_ids=None, explained=None,
                   evidence_delta=None):
    """One frame of the temporal stage alone: the segments' identifiers by Algorithm 3
    (``identify``, no background choice), no segment explained by the background, no
    evidence, unless given."""
    labels = measured_labels(seg, valid, cfg=CFG)
    if segment_ids is None:
        segment_ids = identify(state.identifiers, labels, prm, cfg=CFG)
    if explained is None:
        explained = jnp.zeros((CFG.max_segments,), bool)
    if evidence_delta is None:
        evidence_delta = jnp.zeros(valid.shape, jnp.float32)
    return update_temporal(state, labels, disp, valid, prm, cfg=CFG, grid=GRID,
                           segment_ids=segment_ids, explained=explained,
                           evidence_delta=evidence_delta)


def _counted_update(state, seg, disp, valid, prm):
    _TRACES["count"] += 1  # runs only while tracing
    return temporal_frame(state, seg, disp, valid, prm)


@pytest.fixture(scope="module")
def step():
    return jax.jit(_counted_update)


# the helpers are jitted so each test compiles once instead of dispatching op by op
_correlation = jax.jit(label_correlation, static_argnames=("num_segments", "num_ids"))
_match = jax.jit(match_segments)
_splat_weights = jax.jit(splat_weights, static_argnames=("cfg", "grid"))
_choose = jax.jit(choose_background)
_evidence = jax.jit(update_evidence)


def zero_disp():
    return jnp.zeros((N, 2), jnp.float32), jnp.ones((N,), bool)


def run(step, frames, prm, state=None):
    """frames: list of label images, or (labels, disp, valid) triples. Returns states, outs."""
    state = init_temporal(cfg=CFG, grid=GRID) if state is None else state
    outs = []
    for fr in frames:
        if isinstance(fr, tuple):
            lab, disp, valid = fr
        else:
            lab, (disp, valid) = fr, zero_disp()
        state, out = step(state, make_seg(lab), disp, valid, prm)
        outs.append(jax.tree.map(np.asarray, out))
    return state, outs


def region_ids(out_field, mask):
    """The identifiers a boolean (rows, cols) region carries in a (n,) output."""
    return set(np.unique(np.asarray(out_field).reshape(GRID)[mask]).tolist())


def scene(objects):
    """Label image: background 1, objects (r0, r1, c0, c1) numbered 2, 3, ... in order."""
    lab = np.ones(GRID, np.int32)
    for k, (r0, r1, c0, c1) in enumerate(objects):
        lab[r0:r1, c0:c1] = k + 2
    return lab


def box(r0, r1, c0, c1):
    m = np.zeros(GRID, bool)
    m[r0:r1, c0:c1] = True
    return m


# ---------------------------------------------------------------- eqs. (4.1), (4.2)


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


# ---------------------------------------------------------------- identifiers (4.1)


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


# ---------------------------------------------------------------- grid model (4.2.1)


def test_single_frame_erroneous_labels_are_filtered(step):
    """A background patch that joins the object's segment for one frame, and a patch of the
    object labelled background in the same frame: the matched measurement carries both
    errors, the temporal labels neither (the candidate model is one frame old against an
    apparent model of five, eqs. 4.4-4.5)."""
    a = (3, 8, 4, 9)
    good = scene([a])
    bad = good.copy()
    bad[9:11, 12:14] = 2  # a background patch joins the object's segment
    bad[3:5, 4:6] = 1  # part of the object is labelled background
    frames = [good] * 5 + [bad] + [good] * 3
    _, outs = run(step, frames, params(max_age=30.0))
    assert region_ids(outs[5].matched, box(9, 11, 12, 14)) == {2}
    assert region_ids(outs[5].matched, box(3, 5, 4, 6)) == {1}
    for k, out in enumerate(outs):
        np.testing.assert_array_equal(out.ids.reshape(GRID), good, err_msg=str(k))


@pytest.mark.parametrize("moving_frames", [10, 3])
def test_stopped_object_becomes_static_within_max_age(step, moving_frames):
    """Bound: the object's apparent age is min(T, max_age) after T moving frames; the candidate
    gains one per background frame and swaps when it exceeds that age or reaches max_age, so
    the cells turn static after min(T + 1, ceil(max_age)) <= ceil(max_age) frames."""
    max_age = 6.0
    a = (3, 8, 4, 9)
    stopped = 12
    frames = [scene([a])] * moving_frames + [np.ones(GRID, np.int32)] * stopped
    _, outs = run(step, frames, params(max_age=max_age))
    bound = min(moving_frames + 1, int(np.ceil(max_age)))
    for j in range(stopped):
        out = outs[moving_frames + j]
        assert region_ids(out.matched, box(*a)) == {1}
        want = {2} if j + 1 < bound else {1}
        assert region_ids(out.ids, box(*a)) == want, (j, out.ids.reshape(GRID))

    # after the swap the old model is cleared: one stray object label does not swap back
    frames = frames + [scene([a])] + [np.ones(GRID, np.int32)] * 2
    _, outs = run(step, frames, params(max_age=max_age))
    for out in outs[-3:]:
        assert region_ids(out.ids, box(*a)) == {1}


def test_unmeasured_cells_keep_their_identifier(step):
    """Cells without a measurement (no valid flow, or label 0) keep the grid's label."""
    a = (3, 8, 4, 9)
    blind = np.ones(GRID, np.int32)
    blind[box(*a)] = 0
    _, outs = run(step, [scene([a])] * 4 + [blind] * 6, params(max_age=15.0))
    for out in outs[4:]:
        assert region_ids(out.ids, box(*a)) == {2}
        assert region_ids(out.matched, box(*a)) == {0}


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


# ---------------------------------------------------------------- compensation (4.2.2)


def _random_state(seed):
    rng = np.random.default_rng(seed)
    prob = rng.random((N, CFG.max_ids)).astype(np.float32)
    prob /= prob.sum(axis=1, keepdims=True)
    age = rng.uniform(1.0, 30.0, N).astype(np.float32)
    ids = rng.integers(1, CFG.max_ids + 1, N).astype(np.int32)
    evidence = rng.uniform(-6.0, 6.0, N).astype(np.float32)
    state = init_temporal(cfg=CFG, grid=GRID)
    state = state._replace(
        model=state.model._replace(
            app_prob=jnp.asarray(prob),
            app_age=jnp.asarray(age),
            cand_prob=jnp.asarray(prob[::-1].copy()),
            cand_age=jnp.asarray(age[::-1].copy()),
            ids=jnp.asarray(ids),
        ),
        evidence=jnp.asarray(evidence),
        identifiers=state.identifiers._replace(
            history=jnp.tile(jnp.asarray(ids), (CFG.match_window, 1))),
    )
    return state, prob, age, ids, evidence


def test_integer_shift_moves_models_exactly_and_drops_what_leaves_the_grid(step):
    state, prob, age, ids, evidence = _random_state(0)
    dr, dc = 1, 2  # the scene moves down one cell, right two cells
    disp = jnp.tile(jnp.array([[dc * CELL, dr * CELL]], jnp.float32), (N, 1))
    no_meas = np.zeros(GRID, np.int32)
    new, _ = step(state, make_seg(no_meas), disp, jnp.ones((N,), bool), params())

    def shifted(x, fill):
        x = np.asarray(x).reshape(GRID + x.shape[1:])
        out = np.full_like(x, fill)
        out[dr:, dc:] = x[: ROWS - dr, : COLS - dc]
        return out.reshape((N,) + x.shape[2:])

    # float32 sums of one overlap of weight 1: 1e-6 relative
    np.testing.assert_allclose(np.asarray(new.model.app_prob), shifted(prob, 0.0), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.asarray(new.model.app_age), shifted(age, 0.0), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(new.model.cand_age), shifted(age[::-1], 0.0), rtol=1e-6)
    # the evidence of a frame without any (decayed, update_evidence) moves with the models
    decayed = _evidence(jnp.asarray(evidence), jnp.zeros(N, jnp.float32), jnp.ones(N, bool),
                        jnp.zeros(N, bool), params())
    np.testing.assert_allclose(np.asarray(new.evidence), shifted(decayed, 0.0), rtol=1e-6,
                               atol=1e-7)
    np.testing.assert_array_equal(np.asarray(new.model.ids), shifted(ids, 0))
    np.testing.assert_array_equal(np.asarray(new.identifiers.history[1]), shifted(ids, 0))
    # what the top row and the left two columns held: nothing lands there, they are empty
    empty = np.ones(GRID, bool)
    empty[dr:, dc:] = False
    assert np.all(np.asarray(new.model.app_age).reshape(GRID)[empty] == 0.0)
    assert np.all(np.asarray(new.model.app_prob).reshape(GRID + (-1,))[empty] == 0.0)
    assert np.all(np.asarray(new.model.ids).reshape(GRID)[empty] == 0)
    # the rest moved off the grid and is dropped: the total age is what stayed on it
    stay = np.zeros(GRID, bool)
    stay[: ROWS - dr, : COLS - dc] = True
    np.testing.assert_allclose(float(np.sum(np.asarray(new.model.app_age))),
                               float(np.sum(age.reshape(GRID)[stay])), rtol=1e-5)


def _overlaps(disp_cells):
    """(n current, n previous) overlap area of each previous cell's unit square, moved by
    its displacement (cells), with each current cell: the reference of the forward splat."""
    r = np.arange(N) // COLS
    c = np.arange(N) % COLS
    tr = r + disp_cells[:, 1]
    tc = c + disp_cells[:, 0]
    ov_r = np.clip(1.0 - np.abs(tr[None, :] - r[:, None]), 0.0, None)
    ov_c = np.clip(1.0 - np.abs(tc[None, :] - c[:, None]), 0.0, None)
    return ov_r * ov_c


def test_fractional_shift_weights_are_overlap_areas(step):
    """Each previous cell lands on at most four current cells with its overlap areas as
    weights (they sum to 1 where the square stays on the grid); each current cell averages
    what lands on it, weighted by overlap (eqs. 4.6-4.9 read forward); a cell nothing lands
    on is empty; identifier maps take the identifier of most overlap."""
    rng = np.random.default_rng(4)
    disp_cells = rng.uniform(-1.5, 1.5, (N, 2))
    disp = jnp.asarray(disp_cells * CELL, jnp.float32)
    dst, w = _splat_weights(disp, jnp.ones((N,), bool), jnp.ones((N,), jnp.int32), cfg=CFG,
                            grid=GRID)
    ref = _overlaps(disp_cells)  # (current, previous)
    got = np.zeros((N, N))
    np.add.at(got, (np.asarray(dst), np.repeat(np.arange(N)[:, None], 4, axis=1)),
              np.asarray(w))
    # float32 overlap products of cell positions below 16: 1e-5
    np.testing.assert_allclose(got, ref, atol=1e-5)
    inside = (np.abs(disp_cells[:, 1] + np.arange(N) // COLS - (ROWS - 1) / 2) <= (ROWS - 1) / 2) \
        & (np.abs(disp_cells[:, 0] + np.arange(N) % COLS - (COLS - 1) / 2) <= (COLS - 1) / 2)
    np.testing.assert_allclose(np.asarray(w).sum(axis=1)[inside], 1.0, atol=1e-5)

    state, prob, age, ids, evidence = _random_state(5)
    new, _ = step(state, make_seg(np.zeros(GRID, np.int32)), disp, jnp.ones((N,), bool),
                  params())
    total = ref.sum(axis=1)
    landed = total > 1e-6
    want_age = np.where(landed, ref @ age / np.where(landed, total, 1.0), 0.0)
    want_prob = np.where(landed[:, None], ref @ prob / np.where(landed, total, 1.0)[:, None], 0.0)
    decayed = np.asarray(_evidence(jnp.asarray(evidence), jnp.zeros(N, jnp.float32),
                                   jnp.ones(N, bool), jnp.zeros(N, bool),
                                   params()))  # a frame without evidence
    want_ev = np.where(landed, ref @ decayed / np.where(landed, total, 1.0), 0.0)
    # averages of a few float32 products: 1e-4 relative (ages up to 30, evidence up to 6)
    np.testing.assert_allclose(np.asarray(new.model.app_age), want_age, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(new.model.app_prob), want_prob, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.asarray(new.evidence), want_ev, rtol=1e-4, atol=1e-4)
    assert not np.all(landed)  # some cells receive nothing ...
    assert np.all(np.asarray(new.model.app_age)[~landed] == 0)  # ... and are empty
    assert np.all(np.asarray(new.model.ids)[~landed] == 0)
    votes = ref @ np.eye(CFG.max_ids)[ids - 1]  # overlap of each identifier landing
    want_ids = np.where(votes.max(axis=1) > 1e-6, votes.argmax(axis=1) + 1, 0)
    clear = np.sort(votes, axis=1)[:, -1] - np.sort(votes, axis=1)[:, -2] > 1e-4
    np.testing.assert_array_equal(np.asarray(new.model.ids)[clear], want_ids[clear])


def test_an_object_moving_with_its_flow_leaves_no_trail(step):
    """Read forward, an object's model moves with it: as it moves a cell a frame, the cells
    it leaves receive nothing and take the measurement (background) at once, and its own
    cells keep its identifier. A cell it enters receives both its model and that of the
    background it covers (whose flow stays put): the tie of eqs. 4.6-4.9 leaves the cell
    with the background for that one frame, and the object's from the next."""
    frames = []
    for k in range(8):
        a = (3, 8, 2 + k, 7 + k)
        disp = np.zeros(GRID + (2,), np.float32)
        disp[box(*a), 0] = CELL  # the object moves one cell right from here
        frames.append((scene([a]), jnp.asarray(disp.reshape(N, 2)), jnp.ones((N,), bool)))
    _, outs = run(step, frames, params(max_age=15.0))
    np.testing.assert_array_equal(outs[0].ids.reshape(GRID), frames[0][0])
    for k in range(1, 8):
        want = scene([(3, 8, 2 + k, 6 + k)])  # all but the column entered in this frame
        np.testing.assert_array_equal(outs[k].ids.reshape(GRID), want, err_msg=str(k))


def test_a_cell_without_flow_moves_with_its_identifier():
    """A cell without valid flow takes the mean displacement of its identifier's valid
    cells (an object two cells down, the background one cell right), not the image's; an
    identifier without any valid cell, and an unknown cell, take the median of all."""
    rng = np.random.default_rng(7)
    r, c = np.arange(N) // COLS, np.arange(N) % COLS
    obj = (r >= 2) & (r < 6) & (c >= 3) & (c < 9)
    ids = np.where(obj, 3, 1).astype(np.int32)
    valid = rng.random(N) < 0.6
    disp = np.where(obj[:, None], [0.0, 2 * CELL], [CELL, 0.0]).astype(np.float32)
    disp[~valid] = np.nan  # garbage where the flow failed
    dst, w = _splat_weights(jnp.asarray(disp), jnp.asarray(valid), jnp.asarray(ids), cfg=CFG,
                            grid=GRID)
    dst, w = np.asarray(dst), np.asarray(w)
    assert np.all(np.isfinite(w))
    # an integer displacement lands on one cell with weight 1
    target = dst[np.arange(N), np.argmax(w, axis=1)]
    np.testing.assert_allclose(w.max(axis=1)[~valid & obj], 1.0, atol=1e-6)
    np.testing.assert_array_equal(target[~valid & obj], ((r + 2) * COLS + c)[~valid & obj])
    sel = ~valid & ~obj & (c < COLS - 1)
    np.testing.assert_array_equal(target[sel], (r * COLS + c + 1)[sel])

    # identifier 4 has no valid cell, identifier 0 is unknown: the median of all valid cells
    # (the background's, one cell right)
    lone = ids.copy()
    lone[obj] = 4
    lone[r == ROWS - 1] = 0
    dst, w = _splat_weights(jnp.asarray(disp), jnp.asarray(valid & ~obj), jnp.asarray(lone),
                            cfg=CFG, grid=GRID)
    dst, w = np.asarray(dst), np.asarray(w)
    target = dst[np.arange(N), np.argmax(w, axis=1)]
    sel = (obj | ((r == ROWS - 1) & ~valid)) & (c < COLS - 1)
    np.testing.assert_array_equal(target[sel], (r * COLS + c + 1)[sel])


# ---------------------------------------------------------------- the background


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
    state, prob, _, ids, _ = _random_state(9)
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


# ---------------------------------------------------------------- moving evidence


def test_evidence_decays_adds_the_measured_delta_and_is_clamped():
    """Against a float64 loop: each frame ``clip(decay * e + delta [measured], +-bound)``
    with ``bound = logit(confidence) + margin``; an unmeasured cell only decays, whatever
    its delta."""
    rng = np.random.default_rng(10)
    # logit(0.99) = 4.59512, so the bound is 6.0 (to float32 rounding)
    prm = params(evidence_decay=0.8, evidence_margin=6.0 - np.log(99.0), confidence=0.99)
    e = jnp.asarray(rng.uniform(-6, 6, N), jnp.float32)
    want = np.asarray(e, np.float64)
    measured = rng.random(N) < 0.5
    for _ in range(12):
        delta = rng.uniform(-3, 3, N)
        e = _evidence(e, jnp.asarray(delta, jnp.float32), jnp.asarray(measured), jnp.zeros(N, bool), prm)
        want = np.clip(0.8 * want + np.where(measured, delta, 0.0), -6.0, 6.0)
    # float32 over 12 frames: 1e-5 absolute on values up to 6
    np.testing.assert_allclose(np.asarray(e), want, atol=1e-5)
    # the unmeasured cells decayed only: 0.8**12 of their start
    e0 = np.asarray(jnp.asarray(rng.uniform(-6, 6, N), jnp.float32))
    e = jnp.asarray(e0)
    for _ in range(12):
        e = _evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.zeros(N, bool), jnp.zeros(N, bool), prm)
    np.testing.assert_allclose(np.asarray(e), e0 * 0.8**12, rtol=1e-5, atol=1e-7)
    # a steady push saturates at the clamp, not beyond
    e = jnp.zeros(N, jnp.float32)
    for _ in range(20):
        e = _evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
    np.testing.assert_allclose(np.asarray(e), 6.0, rtol=1e-6)


def test_the_evidence_bound_lets_a_steady_motion_pass_the_test_at_any_confidence():
    """The bound follows the confidence: with a fixed bound of 6 a cell could never pass
    the moving test at confidence 0.999 (log-odds 6.9); with the bound at logit + margin
    a cell pushed every frame passes it at 0.9, 0.99, 0.999 and 0.9999."""
    from jaxvo.core.evidence import moving_logodds

    for conf in (0.9, 0.99, 0.999, 0.9999):
        prm = params(evidence_decay=0.9, confidence=conf)
        e = jnp.zeros(N, jnp.float32)
        for _ in range(40):
            e = _evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
        assert np.all(np.asarray(e) > float(moving_logodds(prm))), conf
        # and a cell that stops loses the flag within a few frames of static evidence
        for frames in range(1, 20):
            e = _evidence(e, jnp.full((N,), -3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
            if np.all(np.asarray(e) <= float(moving_logodds(prm))):
                break
        assert frames <= 2, (conf, frames)


def test_update_temporal_adds_the_evidence_of_cells_with_flow_and_carries_it():
    upd = jax.jit(lambda st, seg, d, v, prm, ev: temporal_frame(
        st, seg, d, v, prm, evidence_delta=ev))
    rng = np.random.default_rng(11)
    state, *_ = _random_state(12)
    valid = rng.random(N) < 0.7
    delta = jnp.asarray(rng.uniform(-3, 3, N), jnp.float32)
    disp = jnp.tile(jnp.array([[CELL, 0.0]], jnp.float32), (N, 1))  # one cell right
    prm = params()
    new, out = upd(state, make_seg(scene([])), disp, jnp.asarray(valid), prm, delta)
    want = _evidence(state.evidence, delta, jnp.asarray(valid), jnp.zeros(N, bool), prm)
    # the same decay-and-add in two compiled programs: XLA may fuse a * x + d into one
    # fused multiply-add in one and not the other, so equal within float32 rounding (1e-6)
    np.testing.assert_allclose(np.asarray(out.evidence), np.asarray(want), rtol=1e-6,
                               atol=1e-6)
    # ... and the state carries it one cell right (the first column receives nothing)
    got = np.asarray(new.evidence).reshape(GRID)
    np.testing.assert_allclose(got[:, 1:], np.asarray(want).reshape(GRID)[:, :-1], rtol=1e-6)
    assert np.all(got[:, 0] == 0.0)


# ---------------------------------------------------------------- the background choice


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


def test_evidence_delta_signs_and_clip():
    """Against the log-ratio of the two hypotheses' Gaussian densities (SciPy): in a segment
    that moves unlike the background, ``(d2_ego - d2_own) / 2`` (positive where its own
    motion explains the point better); elsewhere static evidence only, the log-ratio of
    noise ``k`` times larger against the model's, never above 0 (a lone large residual is
    an outlier, not motion); within +-evidence_step; 0 where invalid."""
    from scipy.stats import norm

    from jaxvo.core.evidence import evidence_delta

    prm = params_as_arrays(Params())
    k, step_ = float(prm.evidence_effect), float(prm.evidence_step)
    S = CFG.max_segments
    labels = np.array([2, 2, 2, 2, 1, 1, 1, 3, 0, 2])
    d2_ego = np.array([10.0, 4.0, 2.0, 30.0, 0.0, 3.0, 40.0, 5.0, 40.0, 30.0])
    own = np.array([2.0, 2.0, 4.0, 0.5, 0.0, 0.5, 0.5, 0.1, 0.0, 0.5])
    d2_seg = np.full((S, 10), 1e3)
    d2_seg[labels - 1, np.arange(10)] = own
    explained = np.zeros(S, bool)
    explained[[0, 2]] = True  # segments 1 (the background's) and 3 (a piece of it)
    valid = np.r_[np.ones(9, bool), False]
    got = np.asarray(evidence_delta(
        jnp.asarray(labels, jnp.int32), jnp.asarray(d2_ego, jnp.float32),
        jnp.asarray(d2_seg, jnp.float32), jnp.asarray(explained), jnp.asarray(valid), prm,
        grid=(2, 5)))

    def static_only(d2):  # log N(r; 0, k^2 I3) - log N(r; 0, I3) at |r|^2 = d2, capped at 0
        r = np.array([np.sqrt(d2), 0.0, 0.0])
        return min(np.sum(norm.logpdf(r, scale=k)) - np.sum(norm.logpdf(r)), 0.0)

    want = [0.5 * (10 - 2), 0.5 * (4 - 2), 0.5 * (2 - 4), 0.5 * (30 - 0.5)]  # moving segment
    want += [static_only(d) for d in d2_ego[4:9]]  # background, its piece, unlabelled
    want = np.clip(want + [0.0], -step_, step_)
    want[9] = 0.0  # invalid
    # float32 logs and products: 1e-5
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert got[0] == step_ and got[3] == step_  # clipped
    assert got[1] > 0 > got[2]
    assert got[4] == -step_ and -step_ < got[5] < 0 and got[6] == 0.0 and got[8] == 0.0


def test_reported_ids_name_an_object_exactly_where_cells_move():
    from jaxvo.core.evidence import reported_ids

    ids = jnp.asarray([0, 1, 2, 3, 1, 0, 2, 1], jnp.int32)
    matched = jnp.asarray([0, 1, 2, 4, 5, 0, 0, 0], jnp.int32)
    moving = jnp.asarray([False, False, False, True, True, True, True, False])
    got = np.asarray(reported_ids(ids, matched, moving, cfg=CFG))
    # not moving: an object's identifier reports the background; moving: the temporal
    # identifier, else the matched one, else max_ids + 1 (moving, not yet named)
    np.testing.assert_array_equal(got, [0, 1, 1, 3, 5, CFG.max_ids + 1, 2, 1])
    np.testing.assert_array_equal(got >= 2, np.asarray(moving))


# ---------------------------------------------------------------- jax behaviour


def test_update_does_not_retrace_across_frames(step):
    a = (3, 8, 4, 9)
    run(step, [scene([a])] * 2, params())
    before = _TRACES["count"]
    run(
        step,
        [scene([a]), np.ones(GRID, np.int32), scene([a, (9, 12, 1, 4)])] * 2,
        params(max_age=7.0, id_retention=4.0),
    )
    assert _TRACES["count"] == before == 1


STOP_OBJECT = (3, 8, 4, 9)
STOP_FRAMES = [scene([STOP_OBJECT])] * 10 + [np.ones(GRID, np.int32)] * 6


@pytest.fixture(scope="module")
def scanned():
    """The stop scenario as one lax.scan, vmapped over max_age (one compile for two tests)."""
    segs = jax.tree.map(lambda *x: jnp.stack(x), *[make_seg(f) for f in STOP_FRAMES])
    disp = jnp.zeros((len(STOP_FRAMES), N, 2), jnp.float32)
    valid = jnp.ones((len(STOP_FRAMES), N), bool)

    def whole(max_age):
        prm = params()._replace(max_age=max_age)

        def body(st, xs):
            return temporal_frame(st, *xs, prm)

        return jax.lax.scan(body, init_temporal(cfg=CFG, grid=GRID), (segs, disp, valid))

    max_ages = jnp.array([4.0, 8.0], jnp.float32)
    return max_ages, jax.jit(jax.vmap(whole))(max_ages)


def test_usable_inside_scan_and_matches_python_loop(step, scanned):
    max_ages, (states, outs) = scanned
    for b in range(2):
        loop_state, loop_outs = run(step, STOP_FRAMES, params(max_age=float(max_ages[b])))
        assert isinstance(outs, TemporalOut)
        for k, out in enumerate(loop_outs):
            np.testing.assert_array_equal(np.asarray(outs.ids[b, k]), out.ids)
            np.testing.assert_array_equal(np.asarray(outs.matched[b, k]), out.matched)
            np.testing.assert_array_equal(np.asarray(outs.segment_ids[b, k]), out.segment_ids)
        final = jax.tree.map(lambda x, b=b: x[b], states)
        assert isinstance(final, TemporalState)
        # the same arithmetic batched and not: float32 rounding, 1e-6
        np.testing.assert_allclose(
            np.asarray(final.model.app_prob), np.asarray(loop_state.model.app_prob), atol=1e-6
        )


def test_vmap_over_max_age(scanned):
    _, (_, outs) = scanned
    # 6 stopped frames: static after 4 frames with max_age 4, still the object with 8
    assert region_ids(outs.ids[0, -1], box(*STOP_OBJECT)) == {1}
    assert region_ids(outs.ids[1, -1], box(*STOP_OBJECT)) == {2}


def test_all_zero_measurement_gives_no_nan_and_no_update(step):
    state = init_temporal(cfg=CFG, grid=GRID)
    zeros = np.zeros(GRID, np.int32)
    for _ in range(3):
        state, out = step(
            state, make_seg(zeros), jnp.zeros((N, 2), jnp.float32), jnp.zeros((N,), bool), params()
        )
    for leaf in jax.tree.leaves(state) + list(out):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.all(np.isfinite(np.asarray(leaf)))
    assert np.all(np.asarray(out.ids) == 0) and np.all(np.asarray(out.matched) == 0)
    assert np.all(np.asarray(state.model.app_age) == 0) and not bool(state.identifiers.initialised)
    # a failed spatial stage (status != OK) counts as no measurement either
    seg = make_seg(scene([(3, 8, 4, 9)]), status=3)
    state, out = step(state, seg, jnp.zeros((N, 2), jnp.float32), jnp.ones((N,), bool), params())
    assert np.all(np.asarray(out.matched) == 0) and np.all(np.asarray(state.model.app_age) == 0)
    # NaN displacements where the flow is invalid leave everything finite
    disp = jnp.full((N, 2), jnp.nan, jnp.float32)
    state, out = step(state, make_seg(scene([(3, 8, 4, 9)])), disp, jnp.zeros((N,), bool),
                      params())
    for leaf in jax.tree.leaves(state) + list(out):
        if jnp.issubdtype(leaf.dtype, jnp.floating):
            assert np.all(np.isfinite(np.asarray(leaf)))


def test_a_large_residual_counts_as_motion_only_where_its_neighbourhood_agrees():
    """Outside any moving segment: a 3 x 3 block of cells whose residuals the noise cannot
    explain gains evidence of motion (its centre by the block's agreement, its border
    cells, with fewer agreeing neighbours, none); a lone cell with an even larger residual,
    and a block cell whose neighbours are not measured, gain none."""
    from jaxvo.core.evidence import evidence_delta

    prm = params_as_arrays(Params())
    k2 = float(prm.evidence_effect) ** 2
    rows, cols = 8, 8
    d2 = np.full((rows, cols), 1.0)
    d2[1:4, 1:4] = 12.0  # a mover no segment separated
    d2[6, 6] = 80.0  # a lone outlier
    valid = np.ones((rows, cols), bool)
    labels = np.ones(rows * cols, np.int32)  # all in the background segment
    S = CFG.max_segments
    d2_seg = np.full((S, rows * cols), 1e3, np.float32)
    explained = np.zeros(S, bool)
    explained[0] = True

    def run(valid):
        return np.asarray(evidence_delta(
            jnp.asarray(labels), jnp.asarray(d2.reshape(-1), jnp.float32),
            jnp.asarray(d2_seg), jnp.asarray(explained), jnp.asarray(valid.reshape(-1)), prm,
            grid=(rows, cols))).reshape(rows, cols)

    got = run(valid)
    ratio = -1.5 * np.log(k2) + 0.5 * 12.0 * (1 - 1 / k2)
    assert ratio > 0
    np.testing.assert_allclose(got[2, 2], ratio, rtol=1e-5)  # all 9 agree
    assert got[1, 1] == 0.0  # a corner: 4 of its 9 neighbours agree
    assert got[6, 6] == 0.0  # the outlier
    assert np.all(got[d2 == 1.0] < 0)  # explained by the noise: evidence of static
    lone = valid.copy()
    lone[1:4, 1:4] = False
    lone[2, 2] = True  # measured, its neighbours not: nothing to agree with
    assert run(lone)[2, 2] == 0.0


def test_a_hidden_cell_keeps_its_evidence_a_seen_one_decays():
    """No depth reading (hidden from the sensor): the evidence stays as it was until the cell
    is seen again; a cell seen but not measured decays; a measured one decays and adds."""
    prm = params()
    decay = float(prm.evidence_decay)
    e = jnp.asarray([4.0, 4.0, 4.0, -3.0], jnp.float32)
    delta = jnp.asarray([1.0, 1.0, 1.0, 1.0], jnp.float32)
    measured = jnp.asarray([True, False, False, False])
    hidden = jnp.asarray([True, True, False, True])
    got = np.asarray(_evidence(e, delta, measured, hidden, prm))
    np.testing.assert_allclose(got, [decay * 4.0 + 1.0, 4.0, decay * 4.0, -3.0], rtol=1e-6)
