"""Grid label maps <-> pixel masks, and label overlays people can look at (host side).

The segmentation labels one point per grid cell; users and peers want pixel masks. A cell's
label covers its ``cell x cell`` block; the strip of pixels right and below the last full
cell takes the nearest cell's label.
"""

from __future__ import annotations

import cv2
import numpy as np

# Identifier colours (BGR): 0 unknown = none, 1 static = grey-blue, then distinct hues.
_PALETTE = np.array(
    [
        [0, 0, 0],
        [160, 110, 60],
        [40, 40, 230],
        [40, 200, 40],
        [230, 60, 200],
        [30, 200, 230],
        [230, 200, 30],
        [120, 40, 160],
        [0, 140, 255],
        [200, 200, 200],
    ],
    np.uint8,
)


def palette(labels: np.ndarray) -> np.ndarray:
    """BGR colour per label (labels beyond the palette wrap around, skipping 0)."""
    labels = np.asarray(labels)
    idx = np.where(labels <= 0, 0, (labels - 1) % (len(_PALETTE) - 1) + 1)
    return _PALETTE[idx]


def grid_to_pixels(values: np.ndarray, height: int, width: int, cell: int) -> np.ndarray:
    """Per-cell values ``(rows * cols, ...)`` or ``(rows, cols, ...)`` -> ``(height, width,
    ...)`` image, each cell a block (trailing axes, e.g. a colour's 3, are kept)."""
    rows, cols = height // cell, width // cell
    values = np.asarray(values)
    grid = (values if values.shape[:2] == (rows, cols)
            else values.reshape(rows, cols, *values.shape[1:]))
    block = np.repeat(np.repeat(grid, cell, axis=0), cell, axis=1)
    pad = ((0, height - block.shape[0]), (0, width - block.shape[1])) + ((0, 0),) * (
        grid.ndim - 2)
    return np.pad(block, pad, mode="edge")


def dynamic_pixels(moving: np.ndarray, height: int, width: int, cell: int, *, grow: int = 0):
    """Pixels to ignore for ego-motion: moving cells, grown by ``grow`` cells so that object
    borders between grid points are covered too.

    Args:
      moving: (n,) bool per grid cell (``StepOutput.moving``), or identifiers where
        ``>= 2`` means moving.

    Returns ``(H, W)`` bool, True = dynamic.
    """
    rows, cols = height // cell, width // cell
    moving = np.asarray(moving)
    dyn = (moving if moving.dtype == bool else moving >= 2).reshape(rows, cols).astype(np.uint8)
    if grow > 0:
        dyn = cv2.dilate(dyn, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
    return grid_to_pixels(dyn, height, width, cell).astype(bool)


def overlay(bgr: np.ndarray, ids: np.ndarray, cell: int, *, alpha: float = 0.45) -> np.ndarray:
    """The image with each grid cell tinted by its identifier (static cells lightly)."""
    h, w = bgr.shape[:2]
    ids = np.asarray(ids)
    # colour and weight per cell, then per pixel, in float32: per pixel in float64 this was
    # half of the time a `jaxvo run --overlays` panel took
    a = np.where(ids >= 2, alpha, np.where(ids == 1, alpha * 0.35, 0.0)).astype(np.float32)
    tint = palette(ids).astype(np.float32) * a[:, None]
    a_px = grid_to_pixels(a, h, w, cell)[..., None]
    out = bgr.astype(np.float32) * (1 - a_px) + grid_to_pixels(tint, h, w, cell)
    return np.clip(out, 0, 255).astype(np.uint8)


def label_image(ids: np.ndarray, height: int, width: int, cell: int) -> np.ndarray:
    """Identifiers as a colour image (black = unknown)."""
    return grid_to_pixels(palette(ids), height, width, cell)  # the palette per cell: faster


def overlay_panel(bgr: np.ndarray, out, cell: int, *, scale: float = 0.5) -> np.ndarray:
    """Thesis Fig. 5.1-style panel of one frame pair's internal stages, side by side:
    image with the temporal labels ("Model"), raw hypotheses ("Hypotheses"), spatial
    segments ("Segments") and segments after label matching ("Group").

    Args:
      bgr: (H, W, 3) the previous image of the pair (labels are anchored there).
      out: a :class:`~jaxvo.core.pipeline.StepOutput` of host arrays.
    """
    h, w = bgr.shape[:2]
    tiles = [
        ("Model", overlay(bgr, out.ids, cell)),
        ("Hypotheses", label_image(out.hyp_labels, h, w, cell)),
        ("Segments", label_image(out.labels, h, w, cell)),
        ("Group", label_image(out.matched, h, w, cell)),
    ]
    small = []
    for title, img in tiles:
        img = cv2.resize(img, (int(w * scale), int(h * scale)), interpolation=cv2.INTER_AREA)
        cv2.putText(img, title, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1,
                    cv2.LINE_AA)
        small.append(img)
    return np.concatenate(small, axis=1)
