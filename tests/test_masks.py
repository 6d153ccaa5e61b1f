"""Grid label maps as pixel masks and overlays."""

import numpy as np

from jaxvo.evaluation.scores import moving_at_grid
from jaxvo.host.writers.masks import dynamic_pixels, grid_to_pixels, label_image, overlay

H, W, CELL = 50, 70, 16  # 3 x 4 cells with a strip of 2 rows / 6 columns left over


def test_grid_to_pixels_blocks_and_edge_strip():
    vals = np.arange(12)
    img = grid_to_pixels(vals, H, W, CELL)
    assert img.shape == (H, W)
    assert img[0, 0] == 0 and img[15, 15] == 0 and img[16, 16] == 5
    assert img[49, 69] == 11  # the strip below / right takes the nearest cell


def test_moving_at_grid_reads_cell_centres():
    mask = np.zeros((H, W), np.uint8)
    mask[16:32, 32:48] = 2  # exactly cell (1, 2)
    got = moving_at_grid(mask, CELL)
    assert got.shape == (12,) and got.sum() == 1 and got[1 * 4 + 2]


def test_dynamic_pixels_accepts_flags_or_ids_and_grows_by_cells():
    ids = np.ones(12, np.int32)
    ids[5] = 3
    exact = dynamic_pixels(ids, H, W, CELL, grow=0)
    np.testing.assert_array_equal(exact, dynamic_pixels(ids >= 2, H, W, CELL, grow=0))
    assert exact.sum() == CELL * CELL and exact[20, 20]
    grown = dynamic_pixels(ids, H, W, CELL, grow=1)
    assert grown[0, 0] and grown.sum() > exact.sum()
    # by default the mask follows the cells exactly (the plug-in's masks grow nothing)
    np.testing.assert_array_equal(dynamic_pixels(ids, H, W, CELL), exact)


def test_overlay_and_label_image_shapes():
    bgr = np.full((H, W, 3), 100, np.uint8)
    ids = np.array([0, 1, 2, 3] * 3)
    out = overlay(bgr, ids, CELL)
    assert out.shape == bgr.shape and out.dtype == np.uint8
    assert (out[0, 0] == 100).all()  # unknown cells untouched
    assert (out[0, 40] != 100).any()  # moving cells tinted
    assert label_image(ids, H, W, CELL).shape == (H, W, 3)


def test_overlay_blends_each_pixel_with_its_cells_colour():
    """Against the blend written out pixel by pixel in float64 (the colour and weight per
    cell are computed once per cell now, in float32): within 1 grey level."""
    from jaxvo.host.writers.masks import _PALETTE

    rng = np.random.default_rng(0)
    bgr = rng.integers(0, 256, (H, W, 3), np.uint8)
    ids = rng.integers(0, 14, 12)
    got = overlay(bgr, ids, CELL, alpha=0.45).astype(int)
    for y in range(0, H, 7):
        for x in range(0, W, 5):
            cell = ids[min(y // CELL, 2) * 4 + min(x // CELL, 3)]
            colour = _PALETTE[0 if cell <= 0 else (cell - 1) % 9 + 1].astype(np.float64)
            a = 0.45 if cell >= 2 else 0.45 * 0.35 if cell == 1 else 0.0
            want = np.clip(bgr[y, x] * (1 - a) + colour * a, 0, 255).astype(int)
            assert np.abs(got[y, x] - want).max() <= 1, (y, x)


def test_label_image_and_colour_blocks_match_the_palette_per_pixel():
    from jaxvo.host.writers.masks import palette

    ids = np.arange(-1, 11)
    np.testing.assert_array_equal(label_image(ids, H, W, CELL),
                                  palette(grid_to_pixels(ids, H, W, CELL)))
    colours = grid_to_pixels(palette(ids), H, W, CELL)  # (n, 3) blocks keep their 3
    assert colours.shape == (H, W, 3)
    np.testing.assert_array_equal(colours[49, 69], palette(ids)[11])
