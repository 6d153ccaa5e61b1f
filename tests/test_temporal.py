"""The temporal stage's join (jaxvo.core.temporal): the evidence added where cells have
flow and carried with the models, no retrace across frames, the same results inside
``lax.scan`` and under ``vmap`` as frame by frame, and no NaN from an empty or failed
measurement. Scenes from ``temporal_frames``; each stage alone has its own file
(``test_identifiers``, ``test_grid_model``, ``test_background``, ``test_evidence``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from temporal_frames import (
    CELL,
    CFG,
    GRID,
    TRACES,
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
    temporal_frame,
)

from jaxvo.core.temporal import TemporalOut, TemporalState, init_temporal


@pytest.fixture(scope="module")
def step():
    return jitted_frame()


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


def test_update_temporal_adds_the_evidence_of_cells_with_flow_and_carries_it():
    upd = jax.jit(lambda st, seg, d, v, prm, ev: temporal_frame(
        st, seg, d, v, prm, evidence_delta=ev))
    rng = np.random.default_rng(11)
    state, *_ = random_state(12)
    valid = rng.random(N) < 0.7
    delta = jnp.asarray(rng.uniform(-3, 3, N), jnp.float32)
    disp = jnp.tile(jnp.array([[CELL, 0.0]], jnp.float32), (N, 1))  # one cell right
    prm = params()
    new, out = upd(state, make_seg(scene([])), disp, jnp.asarray(valid), prm, delta)
    want = jit_evidence(state.evidence, delta, jnp.asarray(valid), jnp.zeros(N, bool), prm)
    # the same decay-and-add in two compiled programs: XLA may fuse a * x + d into one
    # fused multiply-add in one and not the other, so equal within float32 rounding (1e-6)
    np.testing.assert_allclose(np.asarray(out.evidence), np.asarray(want), rtol=1e-6,
                               atol=1e-6)
    # ... and the state carries it one cell right (the first column receives nothing)
    got = np.asarray(new.evidence).reshape(GRID)
    np.testing.assert_allclose(got[:, 1:], np.asarray(want).reshape(GRID)[:, :-1], rtol=1e-6)
    assert np.all(got[:, 0] == 0.0)


def test_update_does_not_retrace_across_frames(step):
    a = (3, 8, 4, 9)
    run(step, [scene([a])] * 2, params())
    before = TRACES["count"]
    run(
        step,
        [scene([a]), np.ones(GRID, np.int32), scene([a, (9, 12, 1, 4)])] * 2,
        params(max_age=7.0, id_retention=4.0),
    )
    assert TRACES["count"] == before == 1


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
