"""The dual-mode grid model (thesis 4.2.1, jaxvo.core.grid_model): erroneous labels of a
frame filtered, a stopped object static within max_age, unmeasured cells keeping their
identifier; and its forward compensation (4.2.2): integer and fractional shifts against
overlap areas, no trail behind a moving object, a cell without flow moving with its
identifier. Scenes from ``temporal_frames``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from temporal_frames import (
    CELL,
    CFG,
    COLS,
    GRID,
    ROWS,
    N,
    box,
    jit_evidence,
    jitted_frame,
    make_seg,
    params,
    random_state,
    region_ids,
    run,
    scene,
)

from jaxvo.core.grid_model import splat_weights

_splat_weights = jax.jit(splat_weights, static_argnames=("cfg", "grid"))


@pytest.fixture(scope="module")
def step():
    return jitted_frame()


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


def test_integer_shift_moves_models_exactly_and_drops_what_leaves_the_grid(step):
    state, prob, age, ids, evidence = random_state(0)
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
    decayed = jit_evidence(jnp.asarray(evidence), jnp.zeros(N, jnp.float32), jnp.ones(N, bool),
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

    state, prob, age, ids, evidence = random_state(5)
    new, _ = step(state, make_seg(np.zeros(GRID, np.int32)), disp, jnp.ones((N,), bool),
                  params())
    total = ref.sum(axis=1)
    landed = total > 1e-6
    want_age = np.where(landed, ref @ age / np.where(landed, total, 1.0), 0.0)
    want_prob = np.where(landed[:, None], ref @ prob / np.where(landed, total, 1.0)[:, None], 0.0)
    decayed = np.asarray(jit_evidence(jnp.asarray(evidence), jnp.zeros(N, jnp.float32),
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
