"""jaxvo.host.writers.plugin: per-frame dynamic-pixel masks from a run's identifiers (shapes, anchoring)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

import jaxvo
from jaxvo.host.writers.plugin import dynamic_masks, iter_dynamic_masks, mask_png

H, W, CELL = 48, 70, 16  # 3 x 4 cells; a 6-pixel strip right of the last column
ROWS, COLS = H // CELL, W // CELL


class FakeStep(NamedTuple):  # the fields of StepOutput that the masks read
    ids: np.ndarray  # (T, n) int32


class FakeResult(NamedTuple):  # the field of SequenceResult that the masks read
    outputs: FakeStep


def ids_with_moving(cells_per_frame):
    """(T, n) identifiers: static (1) everywhere except the listed (row, col) cells (id 2)."""
    ids = np.ones((len(cells_per_frame), ROWS * COLS), np.int32)
    for k, cells in enumerate(cells_per_frame):
        for r, c in cells:
            ids[k, r * COLS + c] = 2
    return ids


def reference_mask(cells):
    """Pixel blocks of the given cells, drawn by hand; the right strip copies the last column."""
    m = np.zeros((H, W), bool)
    for r, c in cells:
        m[r * CELL:(r + 1) * CELL, c * CELL:(c + 1) * CELL] = True
        if c == COLS - 1:
            m[r * CELL:(r + 1) * CELL, COLS * CELL:] = True
    return m


def test_shapes_dtype_and_anchoring_on_the_previous_image():
    frames = [[(0, 0)], [(1, 1)], [(2, 3)]]
    ids = ids_with_moving(frames)
    masks = dynamic_masks(FakeStep(ids), H, W, CELL, grow=0)
    assert masks.shape == (len(ids) + 1, H, W)  # T pairs -> T + 1 images
    assert masks.dtype == bool
    for k, cells in enumerate(frames):  # image k takes step k's identifiers
        np.testing.assert_array_equal(masks[k], reference_mask(cells))
    # no final state given: the last image takes the last available map
    np.testing.assert_array_equal(masks[-1], reference_mask(frames[-1]))


def test_last_image_takes_the_compensated_final_map():
    ids = ids_with_moving([[(0, 0)], [(0, 1)]])
    final = ids_with_moving([[(1, 2)]])[0]
    masks = dynamic_masks(FakeResult(FakeStep(ids)), H, W, CELL, final_ids=final, grow=0)
    np.testing.assert_array_equal(masks[0], reference_mask([(0, 0)]))
    np.testing.assert_array_equal(masks[1], reference_mask([(0, 1)]))
    np.testing.assert_array_equal(masks[2], reference_mask([(1, 2)]))


def test_unknown_and_static_cells_are_not_dynamic_and_ids_above_two_are():
    ids = np.zeros((1, ROWS * COLS), np.int32)  # 0 = unknown everywhere
    ids[0, 5] = 1
    ids[0, 6] = 7  # any identifier >= 2 is a moving object
    masks = dynamic_masks(ids, H, W, CELL, grow=0)
    np.testing.assert_array_equal(masks[0], reference_mask([(1, 2)]))


def test_grow_dilates_by_whole_cells():
    ids = ids_with_moving([[(1, 1)]])
    masks = dynamic_masks(ids, H, W, CELL, grow=1)
    expected = reference_mask([(r, c) for r in range(3) for c in range(3)])
    np.testing.assert_array_equal(masks[0], expected)


def test_iterator_matches_array_and_a_real_step_output_gives_its_dynamic_cells():
    """A ``StepOutput``'s masks are its ``dynamic`` cells (the moving cells and their
    unmeasured neighbours, jaxvo.core.pipeline.grow_moving), not its identifiers or its
    ``moving`` flags; by default nothing more is grown."""
    from jaxvo.core.noise import NoiseScale
    from jaxvo.core.pipeline import StepOutput

    ids = ids_with_moving([[(0, 2)], [(2, 0), (2, 1)]])
    dynamic = ids_with_moving([[(0, 2), (0, 3)], [(2, 0), (2, 1), (1, 1)]]) >= 2
    n = ROWS * COLS
    zeros_i, zeros_b = np.zeros((2, n), np.int32), np.zeros((2, n), bool)
    out = StepOutput(
        T_w_c=np.tile(np.eye(4, dtype=np.float32), (2, 1, 1)),
        T_cur_prev=np.tile(np.eye(4, dtype=np.float32), (2, 1, 1)),
        status=np.zeros(2, np.int32),
        ids=ids,
        moving=ids >= 2,
        dynamic=dynamic,
        static=zeros_b,
        labels=zeros_i,
        hyp_labels=zeros_i,
        matched=zeros_i,
        num_segments=np.zeros(2, np.int32),
        evidence=np.zeros((2, n), np.float32),
        background=np.ones(2, np.int32),
        reacquired=np.zeros(2, bool),
        noise=NoiseScale(np.full(2, 0.75, np.float32), np.full(2, 1.5e-3, np.float32)),
    )
    lazy = list(iter_dynamic_masks(out, H, W, CELL))
    np.testing.assert_array_equal(np.stack(lazy), dynamic_masks(dynamic, H, W, CELL))
    np.testing.assert_array_equal(lazy[1], reference_mask([(2, 0), (2, 1), (1, 1)]))
    assert not np.array_equal(lazy[0], dynamic_masks(ids, H, W, CELL)[0])


def test_wrong_grid_is_refused():
    with pytest.raises(ValueError, match="cells"):
        dynamic_masks(np.ones((2, 5), np.int32), H, W, CELL)


def test_png_values_and_public_export():
    png = mask_png(np.array([[True, False]]))
    assert png.dtype == np.uint8
    np.testing.assert_array_equal(png, [[255, 0]])
    assert jaxvo.dynamic_masks is dynamic_masks
    assert "dynamic_masks" in jaxvo.__all__


def test_a_streams_labels_lie_on_the_image_each_pair_starts_at():
    """LabelAnchor (jaxvo run's masks, overlays, bag and map): pair k's labels on image k,
    the last image, which starts no pair, with the last pair's."""
    from jaxvo.host.writers.plugin import LabelAnchor

    anchor = LabelAnchor()
    assert anchor.push("image 0", None) is None and anchor.last_image() is None
    assert anchor.push("image 1", "pair 0-1") == "image 0"
    assert anchor.push("image 2", "pair 1-2") == "image 1"
    assert anchor.last_image() == ("image 2", "pair 1-2")
