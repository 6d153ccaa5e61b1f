"""Moving evidence (jaxvo.core.evidence): the log-odds filter against a float64 loop, its
bound at any confidence, each point's evidence against SciPy's Gaussian log-ratio, the
neighbourhood's agreement, hidden cells, and the identifiers reported exactly where cells
move."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from temporal_frames import CFG, N, jit_evidence, params

from jaxvo.config import Params, params_as_arrays


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
        e = jit_evidence(e, jnp.asarray(delta, jnp.float32), jnp.asarray(measured), jnp.zeros(N, bool), prm)
        want = np.clip(0.8 * want + np.where(measured, delta, 0.0), -6.0, 6.0)
    # float32 over 12 frames: 1e-5 absolute on values up to 6
    np.testing.assert_allclose(np.asarray(e), want, atol=1e-5)
    # the unmeasured cells decayed only: 0.8**12 of their start
    e0 = np.asarray(jnp.asarray(rng.uniform(-6, 6, N), jnp.float32))
    e = jnp.asarray(e0)
    for _ in range(12):
        e = jit_evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.zeros(N, bool), jnp.zeros(N, bool), prm)
    np.testing.assert_allclose(np.asarray(e), e0 * 0.8**12, rtol=1e-5, atol=1e-7)
    # a steady push saturates at the clamp, not beyond
    e = jnp.zeros(N, jnp.float32)
    for _ in range(20):
        e = jit_evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
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
            e = jit_evidence(e, jnp.full((N,), 3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
        assert np.all(np.asarray(e) > float(moving_logodds(prm))), conf
        # and a cell that stops loses the flag within a few frames of static evidence
        for frames in range(1, 20):
            e = jit_evidence(e, jnp.full((N,), -3.0, jnp.float32), jnp.ones(N, bool), jnp.zeros(N, bool), prm)
            if np.all(np.asarray(e) <= float(moving_logodds(prm))):
                break
        assert frames <= 2, (conf, frames)


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
    got = np.asarray(jit_evidence(e, delta, measured, hidden, prm))
    np.testing.assert_allclose(got, [decay * 4.0 + 1.0, 4.0, decay * 4.0, -3.0], rtol=1e-6)
