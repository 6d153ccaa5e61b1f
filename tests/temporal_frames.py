"""What the tests of the temporal stages share (``test_identifiers``, ``test_grid_model``,
``test_background``, ``test_evidence``, ``test_temporal``): segmentations built by hand on
a 12 x 16 grid, a small NamedTuple standing in for the spatial stage's ``Segmentation``
(only the documented fields), and one jitted frame of the temporal stage (parameters
passed as float32 arrays), compiled once for every file that runs it.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.config import Config, Params, params_as_arrays
from jaxvo.core.evidence import update_evidence
from jaxvo.core.identifiers import identify, measured_labels
from jaxvo.core.temporal import TemporalInputs, init_temporal, update_temporal

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


TRACES = {"count": 0}  # traces of the shared step (each file's `step` fixture)


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
    return update_temporal(
        state, TemporalInputs(labels, disp, valid, segment_ids, explained, evidence_delta),
        prm, cfg=CFG, grid=GRID)


def _counted_update(state, seg, disp, valid, prm):
    TRACES["count"] += 1  # runs only while tracing
    return temporal_frame(state, seg, disp, valid, prm)


@functools.cache
def jitted_frame():
    """:func:`temporal_frame` jitted once for every test file: the ``step`` fixtures."""
    return jax.jit(_counted_update)


# jitted so each test compiles once instead of dispatching op by op
jit_evidence = jax.jit(update_evidence)


def random_state(seed):
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
