"""Tests of jaxvo.temporal: label matching (thesis 4.1) and the dual-mode grid model (4.2).

Segmentations are built by hand on a 12 x 16 grid; a small NamedTuple stands in for the
spatial stage's ``Segmentation`` (only the documented fields). One jitted update is shared by
all tests (parameters passed as float32 arrays), so the module compiles it once.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo.config import Config, Params, params_as_arrays
from jaxvo.temporal import (
    TemporalOut,
    TemporalState,
    _consistent_segments_join_background,
    _prefer_consistent_background,
    compensate_models,
    compensation_weights,
    init_temporal,
    label_correlation,
    match_segments,
    update_temporal,
)

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


def _counted_update(state, seg, disp, valid, prm):
    _TRACES["count"] += 1  # runs only while tracing
    return update_temporal(state, seg, disp, valid, prm, cfg=CFG, grid=GRID)


@pytest.fixture(scope="module")
def step():
    return jax.jit(_counted_update)


# the helpers are jitted so each test compiles once instead of dispatching op by op
_correlation = jax.jit(label_correlation, static_argnames=("num_segments", "num_ids"))
_match = jax.jit(match_segments)
_weights = jax.jit(compensation_weights, static_argnames=("cfg", "grid"))
_compensate = jax.jit(compensate_models)


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


@pytest.mark.parametrize(
    "ids, sizes, consistent, expected",
    [
        # the background follows the prediction: so do two more segments, which join it
        ([1, 3, 4, 2], [400, 60, 30, 50], [True, True, True, False], [1, 1, 1, 2]),
        # the background does not follow it: no segment joins (a sudden camera move)
        ([1, 3, 4, 0], [400, 60, 30, 0], [False, True, True, False], [1, 3, 4, 0]),
        # no segment has the background's identifier: nothing to join
        ([2, 3, 0, 0], [400, 60, 0, 0], [True, True, False, False], [2, 3, 0, 0]),
        # empty segment slots stay empty
        ([1, 0, 0, 0], [400, 0, 0, 0], [True, True, False, False], [1, 0, 0, 0]),
    ],
)
def test_segments_that_move_as_predicted_join_the_background(ids, sizes, consistent, expected):
    got = _consistent_segments_join_background(
        jnp.asarray(ids, jnp.int32), jnp.asarray(sizes, jnp.float32), jnp.asarray(consistent)
    )
    np.testing.assert_array_equal(np.asarray(got), expected)


@pytest.mark.parametrize(
    "ids, sizes, consistent, expected",
    [
        # the matched background does not follow the prediction, a large segment does: swap
        ([1, 3, 0], [400, 500, 0], [False, True, False], [3, 1, 0]),
        # the matched background follows the prediction: matching stands
        ([1, 3, 0], [400, 500, 0], [True, True, False], [1, 3, 0]),
        # nothing follows the prediction (a sudden camera move): matching stands
        ([1, 3, 0], [400, 500, 0], [False, False, False], [1, 3, 0]),
        # the consistent segment is under half the matched one's size: matching stands
        ([1, 3, 2], [400, 150, 40], [False, True, False], [1, 3, 2]),
        # no segment matched the background: the largest consistent one takes it
        ([2, 3, 0], [900, 60, 0], [True, True, False], [1, 3, 0]),
    ],
)
def test_background_identifier_goes_to_the_segment_that_moves_as_predicted(
    ids, sizes, consistent, expected
):
    got = _prefer_consistent_background(
        jnp.asarray(ids, jnp.int32), jnp.asarray(sizes, jnp.float32), jnp.asarray(consistent)
    )
    np.testing.assert_array_equal(np.asarray(got), expected)


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


def test_single_frame_erroneous_label(step):
    """A background patch that joins the object's segment for one frame is filtered out; a
    patch of the object labelled background while the object is seen elsewhere counts as
    vacated and is taken at once, and the object takes it back within two frames."""
    a = (3, 8, 4, 9)
    good = scene([a])
    bad = good.copy()
    bad[9:11, 12:14] = 2  # a background patch joins the object's segment
    bad[3:5, 4:6] = 1  # part of the object is labelled background
    frames = [good] * 5 + [bad] + [good] * 3
    _, outs = run(step, frames, params(max_age=30.0))
    # the matched measurement does carry both errors ...
    assert region_ids(outs[5].matched, box(9, 11, 12, 14)) == {2}
    assert region_ids(outs[5].matched, box(3, 5, 4, 6)) == {1}
    # ... the temporal label only the second, for two frames
    rest = ~box(3, 5, 4, 6)
    for k, out in enumerate(outs):
        ids = out.ids.reshape(GRID)
        np.testing.assert_array_equal(ids[rest], good[rest])
        assert region_ids(out.ids, box(3, 5, 4, 6)) == ({1} if k in (5, 6) else {2}), k


@pytest.mark.parametrize("object_fits_better", [True, False])
def test_a_merged_part_stays_with_an_object_whose_motion_fits_it_better(object_fits_better):
    """Part of a tracked object labelled background while the object is seen elsewhere: with
    residuals where the object's motion explains that part better, it keeps the object's
    identifier; where the background's does, it is vacated at once, as without them."""
    upd = jax.jit(lambda st, seg, d, v, prm, e: update_temporal(
        st, seg, d, v, prm, cfg=CFG, grid=GRID, seg_err=e))
    a = (3, 8, 4, 9)
    good = scene([a])
    bad = good.copy()
    bad[3:5, 4:6] = 1
    part = box(3, 5, 4, 6).ravel()
    err = np.full((CFG.max_segments, N), 1e6, np.float32)
    err[0] = np.where(part, 2e-5 if object_fits_better else 1e-6, 1e-6)  # background segment
    err[1] = np.where(part, 1e-6 if object_fits_better else 2e-5, 1e-6)  # object segment
    seg_err = (jnp.asarray(err), jnp.full((N,), 1e-4, jnp.float32))
    state, prm = init_temporal(cfg=CFG, grid=GRID), params(max_age=30.0)
    disp, valid = zero_disp()
    for lab in [good] * 5 + [bad]:
        state, out = upd(state, make_seg(lab), disp, valid, prm, seg_err)
    assert region_ids(out.matched, box(3, 5, 4, 6)) == {1}
    assert region_ids(out.ids, box(3, 5, 4, 6)) == ({2} if object_fits_better else {1})


@pytest.mark.parametrize("held", [True, False])
def test_a_held_object_merged_into_the_background_keeps_its_identifier(held):
    """A slow object merged into the background segment for many frames: told that its
    points still move apart (``held``), it is measured with its identifier and keeps it;
    without, the background takes its cells within the frames the model allows."""
    upd = jax.jit(lambda st, seg, d, v, prm, h: update_temporal(
        st, seg, d, v, prm, cfg=CFG, grid=GRID, held=h))
    a = (3, 8, 4, 9)
    obj = box(*a).ravel()
    hold = jnp.asarray(np.where(obj, 2, 0) if held else np.zeros(N), jnp.int32)
    state, prm = init_temporal(cfg=CFG, grid=GRID), params(max_age=4.0, id_retention=3.0)
    disp, valid = zero_disp()
    for lab in [scene([a])] * 5 + [scene([])] * 8:
        state, out = upd(state, make_seg(lab), disp, valid, prm, hold)
    assert region_ids(out.matched, box(*a)) == ({2} if held else {1})
    assert region_ids(out.ids, box(*a)) == ({2} if held else {1})
    assert region_ids(out.ids, ~box(*a)) == {1}


@pytest.mark.parametrize("part_follows", [True, False])
def test_a_merged_part_is_vacated_at_once_only_where_its_points_move_as_predicted(part_follows):
    """Part of a tracked object labelled background while the object is seen elsewhere: it
    turns static at once where its own points move as the predicted camera motion says
    (the object has left), not where they do not (the spatial stage merged a still-moving
    part into the background, whose far points allow a wide threshold)."""
    upd = jax.jit(lambda st, seg, d, v, prm, c, f: update_temporal(
        st, seg, d, v, prm, cfg=CFG, grid=GRID, consistent=c, follows=f))
    a = (3, 8, 4, 9)
    good = scene([a])
    bad = good.copy()
    bad[3:5, 4:6] = 1
    part = box(3, 5, 4, 6).ravel()
    consistent = jnp.asarray(np.r_[True, False, np.ones(CFG.max_segments - 2, bool)])
    follows = ~box(*a).ravel() | (part & part_follows)
    state, prm = init_temporal(cfg=CFG, grid=GRID), params(max_age=30.0)
    disp, valid = zero_disp()
    for lab in [good] * 5 + [bad]:
        state, out = upd(state, make_seg(lab), disp, valid, prm, consistent, jnp.asarray(follows))
    assert region_ids(out.matched, box(3, 5, 4, 6)) == {1}
    assert region_ids(out.ids, box(3, 5, 4, 6)) == ({1} if part_follows else {2})


def test_cells_an_object_leaves_turn_static_at_once(step):
    """The thesis's model keeps an object's label in the cells it has left for up to max_age
    frames (a trail); when the object is measured elsewhere, they follow the measurement."""
    frames = [scene([(3, 8, 2 + k, 7 + k)]) for k in range(8)]
    _, outs = run(step, frames, params(max_age=15.0))
    for k in range(1, 8):
        left = box(3, 8, 0, 2 + k)  # every cell the object has left
        assert region_ids(outs[k].ids, left) == {1}, (k, outs[k].ids.reshape(GRID))


@pytest.fixture(scope="module")
def step_predicted():
    def update(state, seg, disp, valid, prm, consistent):
        return update_temporal(state, seg, disp, valid, prm, cfg=CFG, grid=GRID,
                               consistent=consistent)

    return jax.jit(update)


@pytest.mark.parametrize("object_consistent", [False, True])
def test_tracked_object_that_moves_unlike_the_camera_enters_cells_at_once(
    step_predicted, object_consistent
):
    """A tracked object whose segment does not follow the predicted camera motion takes the
    background cells it covers at once; one that does, as the background does, is
    background: it joins identifier 1 (see _consistent_segments_join_background)."""
    a, grown = (3, 8, 4, 9), (3, 8, 4, 12)
    consistent = jnp.asarray(np.r_[True, object_consistent, np.ones(CFG.max_segments - 2, bool)])
    state = init_temporal(cfg=CFG, grid=GRID)
    prm = params(max_age=15.0)
    disp, valid = zero_disp()
    for lab in [scene([a])] * 4 + [scene([grown])]:
        state, out = step_predicted(state, make_seg(lab), disp, valid, prm, consistent)
    new_cells = box(3, 8, 9, 12)
    assert region_ids(out.matched, new_cells) == ({1} if object_consistent else {2})
    assert region_ids(out.ids, new_cells) == ({1} if object_consistent else {2})


@pytest.mark.parametrize("per_point", [False, True])
def test_cells_whose_own_points_follow_the_prediction_are_not_entered_at_once(per_point):
    """The spatial stage merges background into a tracked object's segment (one motion
    explains a near object and a far wall within the wall's wide threshold): the segment as
    a whole moves unlike the predicted camera motion, but the merged cells' own points
    follow it. Told so per point, those cells keep the background in the model (the
    measurement still says the object); without it they are entered at once."""
    upd = jax.jit(lambda st, seg, d, v, prm, c, f: update_temporal(
        st, seg, d, v, prm, cfg=CFG, grid=GRID, consistent=c, follows=f))
    a, merged = (2, 10, 2, 12), (2, 10, 2, 16)
    consistent = jnp.asarray(np.r_[True, False, np.ones(CFG.max_segments - 2, bool)])
    follows = jnp.asarray(~box(*a).ravel() if per_point else np.zeros(N, bool))
    state, prm = init_temporal(cfg=CFG, grid=GRID), params(max_age=15.0)
    disp, valid = zero_disp()
    for lab in [scene([a])] * 4 + [scene([merged])]:
        state, out = upd(state, make_seg(lab), disp, valid, prm, consistent, follows)
    new_cells = box(*merged) & ~box(*a)
    assert region_ids(out.matched, new_cells) == {2}
    assert region_ids(out.ids, new_cells) == ({1} if per_point else {2})
    assert region_ids(out.ids, box(*a)) == {2}


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
    assert bound <= np.ceil(max_age)
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


@pytest.mark.parametrize("unmeasured", [5, 1])
def test_cells_of_a_forgotten_object_follow_the_measurement_at_once(step, unmeasured):
    """An object long tracked (its cells' model at max_age) goes unmeasured, as in a depth
    blind zone or out of view. Once its identifier is unobserved for id_retention frames,
    as long as it takes to free an identifier, a measurement of its cells takes them at
    once; before that, the thesis's wait of up to max_age measured frames holds."""
    a = (3, 8, 4, 9)
    blind = np.ones(GRID, np.int32)
    blind[box(*a)] = 0  # no measurement where the object was
    frames = [scene([a])] * 10 + [blind] * unmeasured + [np.ones(GRID, np.int32)] * 2
    _, outs = run(step, frames, params(max_age=15.0, id_retention=3.0))
    for out in outs[10 : 10 + unmeasured]:
        assert region_ids(out.ids, box(*a)) == {2}  # unmeasured cells keep the identifier
    first = outs[10 + unmeasured]
    assert region_ids(first.matched, box(*a)) == {1}
    # last seen at frame 9: unobserved for 6 frames (>= 3 + 1) at the first measurement after
    # 5 unmeasured frames, for 2 after 1
    assert region_ids(first.ids, box(*a)) == ({1} if unmeasured == 5 else {2})


# ---------------------------------------------------------------- compensation (4.2.2)


def _random_models(seed):
    rng = np.random.default_rng(seed)
    prob = rng.random((N, CFG.max_ids)).astype(np.float32)
    prob /= prob.sum(axis=1, keepdims=True)
    age = rng.uniform(1.0, 30.0, N).astype(np.float32)
    return prob, age


def test_integer_shift_moves_models_exactly_and_resets_outside(step):
    prob, age = _random_models(0)
    ids = np.random.default_rng(1).integers(1, CFG.max_ids + 1, N).astype(np.int32)
    state = init_temporal(cfg=CFG, grid=GRID)._replace(
        app_prob=jnp.asarray(prob),
        app_age=jnp.asarray(age),
        cand_prob=jnp.asarray(prob[::-1].copy()),
        cand_age=jnp.asarray(age[::-1].copy()),
        ids=jnp.asarray(ids),
        history=jnp.tile(jnp.asarray(ids), (CFG.match_window, 1)),
    )
    dr, dc = 1, 2  # the scene moves down one cell, right two cells
    disp = jnp.tile(jnp.array([[dc * CELL, dr * CELL]], jnp.float32), (N, 1))
    no_meas = np.zeros(GRID, np.int32)
    new, _ = step(state, make_seg(no_meas), disp, jnp.ones((N,), bool), params())

    def shifted(x, fill):
        x = np.asarray(x).reshape(GRID + x.shape[1:])
        out = np.full_like(x, fill)
        out[dr:, dc:] = x[: ROWS - dr, : COLS - dc]
        return out.reshape((N,) + x.shape[2:])

    np.testing.assert_allclose(np.asarray(new.app_prob), shifted(prob, 0.0), atol=1e-6)
    np.testing.assert_allclose(np.asarray(new.app_age), shifted(age, 0.0), atol=1e-5)
    np.testing.assert_allclose(np.asarray(new.cand_age), shifted(age[::-1], 0.0), atol=1e-5)
    np.testing.assert_array_equal(np.asarray(new.ids), shifted(ids, 0))
    np.testing.assert_array_equal(np.asarray(new.history[1]), shifted(ids, 0))
    # cells whose previous position is outside the grid start empty
    outside = np.ones(GRID, bool)
    outside[dr:, dc:] = False
    assert np.all(np.asarray(new.app_age).reshape(GRID)[outside] == 0.0)
    assert np.all(np.asarray(new.app_prob).reshape(GRID + (-1,))[outside] == 0.0)


def _reference_weights(disp_cells):
    """Overlap area of a unit square at the source position with every grid cell."""
    r = np.arange(N) // COLS
    c = np.arange(N) % COLS
    sr = r - disp_cells[:, 1]
    sc = c - disp_cells[:, 0]
    ov_r = np.clip(1.0 - np.abs(sr[:, None] - r[None, :]), 0.0, None)
    ov_c = np.clip(1.0 - np.abs(sc[:, None] - c[None, :]), 0.0, None)
    area = ov_r * ov_c  # (n current, n previous)
    inside = (sr >= -0.5) & (sr < ROWS - 0.5) & (sc >= -0.5) & (sc < COLS - 0.5)
    tot = area.sum(axis=1, keepdims=True)
    return np.where(inside[:, None], area / np.where(tot > 0, tot, 1.0), 0.0), inside


def test_fractional_shift_weights_are_normalised_overlap_areas():
    rng = np.random.default_rng(4)
    disp_cells = rng.uniform(-1.5, 1.5, (N, 2))
    disp = jnp.asarray(disp_cells * CELL, jnp.float32)
    idx, w, _, inside = _weights(disp, jnp.ones((N,), bool), cfg=CFG, grid=GRID)
    ref_w, ref_inside = _reference_weights(disp_cells)
    np.testing.assert_array_equal(np.asarray(inside), ref_inside)
    # eq. (4.9): weights of every inside cell sum to 1 (float32 tolerance 1e-6)
    wsum = np.asarray(w).sum(axis=1)
    np.testing.assert_allclose(wsum[ref_inside], 1.0, atol=1e-6)
    assert np.all(wsum[~ref_inside] == 0.0)
    # eqs. (4.6)-(4.8): interpolation equals the brute-force area-weighted sum (tol 1e-5)
    prob, age = _random_models(5)
    got_p, got_a = _compensate(jnp.asarray(prob), jnp.asarray(age), idx, w)
    np.testing.assert_allclose(np.asarray(got_p), ref_w @ prob, atol=1e-5)
    np.testing.assert_allclose(np.asarray(got_a), ref_w @ age, rtol=1e-5, atol=1e-4)


def test_invalid_flow_takes_median_displacement():
    rng = np.random.default_rng(6)
    valid = rng.random(N) < 0.6
    disp = np.zeros((N, 2), np.float32)
    disp[valid, 0] = CELL  # the valid flow: one cell right ...
    outliers = valid & (rng.random(N) < 0.1)
    disp[outliers] = (-5 * CELL, 3 * CELL)  # ... with a minority of outliers
    disp[~valid] = np.nan  # garbage where the flow failed
    _, w, nearest, inside = _weights(jnp.asarray(disp), jnp.asarray(valid), cfg=CFG, grid=GRID)
    assert np.all(np.isfinite(np.asarray(w)))
    r, c = np.arange(N) // COLS, np.arange(N) % COLS
    inv = ~valid
    # invalid cells move with the median (one cell right): source one column to the left
    np.testing.assert_array_equal(np.asarray(inside)[inv], (c >= 1)[inv])
    sel = inv & (c >= 1)
    np.testing.assert_array_equal(np.asarray(nearest)[sel], (r * COLS + c - 1)[sel])
    np.testing.assert_allclose(np.asarray(w)[sel].max(axis=1), 1.0, atol=1e-6)


def test_invalid_flow_moves_with_its_identifier():
    """Given the identifiers, a cell without flow takes the mean displacement of the valid
    cells of its identifier (here an object two cells down), not the image median."""
    rng = np.random.default_rng(7)
    r, c = np.arange(N) // COLS, np.arange(N) % COLS
    obj = (r >= 2) & (r < 6) & (c >= 3) & (c < 9)
    ids = np.where(obj, 3, 1).astype(np.int32)
    valid = rng.random(N) < 0.6
    disp = np.where(obj[:, None], [0.0, 2 * CELL], [CELL, 0.0]).astype(np.float32)
    disp[~valid] = np.nan
    _, _, nearest, inside = _weights(jnp.asarray(disp), jnp.asarray(valid), cfg=CFG, grid=GRID,
                                     ids=jnp.asarray(ids))
    nearest, inside = np.asarray(nearest), np.asarray(inside)
    sel = ~valid & obj & (r >= 2)
    np.testing.assert_array_equal(nearest[sel], ((r - 2) * COLS + c)[sel])
    sel = ~valid & ~obj & (c >= 1)
    np.testing.assert_array_equal(nearest[sel], (r * COLS + c - 1)[sel])
    # an identifier without any valid cell falls back to the median
    lone = ids.copy()
    lone[obj] = 4
    _, _, nearest, _ = _weights(jnp.asarray(disp), jnp.asarray(valid & ~obj), cfg=CFG,
                                grid=GRID, ids=jnp.asarray(lone))
    sel = obj & (c >= 1)
    np.testing.assert_array_equal(np.asarray(nearest)[sel], (r * COLS + c - 1)[sel])


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
            return update_temporal(st, *xs, prm, cfg=CFG, grid=GRID)

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
        np.testing.assert_allclose(
            np.asarray(final.app_prob), np.asarray(loop_state.app_prob), atol=1e-6
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
    assert np.all(np.asarray(state.app_age) == 0) and not bool(state.initialised)
    # a failed spatial stage (status != OK) counts as no measurement either
    seg = make_seg(scene([(3, 8, 4, 9)]), status=3)
    state, out = step(state, seg, jnp.zeros((N, 2), jnp.float32), jnp.ones((N,), bool), params())
    assert np.all(np.asarray(out.matched) == 0) and np.all(np.asarray(state.app_age) == 0)
