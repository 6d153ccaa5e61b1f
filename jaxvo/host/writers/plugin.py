"""jaxvo's segmentation as a plug-in for other odometry: per-frame masks of dynamic pixels.

Thesis Fig. 5.8 ("Proposed x DVO") hands the static / dynamic labels of the proposed method
to a dense odometry, which then ignores the moving pixels. This module turns the labels of
a run into one ``(H, W)`` bool mask per frame of the sequence (True = dynamic, ignore it);
``~mask`` is the ``keep`` argument of :func:`jaxvo.host.services.peers.run_peer`.

Anchoring. ``StepOutput`` ``k`` (the frame pair ``k -> k+1``) labels the grid of image ``k``,
the previous image of the pair, where its flow was measured. So image ``k`` takes the
identifiers of step ``k`` for ``k = 0 .. T-1``. The last image ``T`` has no step of its own:
it takes ``final_ids`` when given, the temporal label map of the final state, which the
temporal stage has already compensated forward onto image ``T``'s grid
(``final_state.temporal.model.ids`` of :func:`jaxvo.core.pipeline.run_scan`); without it, it
takes the last available map (step ``T-1``, anchored one frame earlier), which the ``grow`` margin
covers for small motions.

A stream's results come one pair at a time, each with the image it ends at:
:class:`LabelAnchor` holds the same rule for them (``jaxvo run``'s masks, overlays, bag and
map).

Dropped frames. A :class:`~jaxvo.odometry.SequenceResult` steps only the frames it kept:
pair ``k`` is ``frames[k] -> frames[k+1]``, so mask ``k`` belongs to image
``result.frames[k]`` (the same as image ``k`` when no frame was dropped), and a dropped
frame has no mask.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from jaxvo.host.writers.masks import dynamic_pixels


def _ids_of(result) -> np.ndarray:
    """``(T, n)`` moving flags (or identifiers) from a ``SequenceResult``, a stacked
    ``StepOutput`` or an array."""
    outputs = getattr(result, "outputs", result)  # SequenceResult -> its StepOutput
    # StepOutput -> its mask cells (moving points and their unmeasured neighbours)
    ids = getattr(outputs, "dynamic", getattr(outputs, "moving", getattr(outputs, "ids", outputs)))
    ids = np.asarray(ids)
    if ids.ndim == 1:
        ids = ids[None]
    if ids.ndim != 2:
        raise ValueError(f"expected identifiers of shape (T, n), got {ids.shape}")
    return ids


class LabelAnchor:
    """Which image a stream's labels lie on (module docstring): a pair's on the image it
    starts at, where its flow was measured; the last image, which starts no pair, takes the
    last pair's.

    Push each kept image with the output of the pair that ends at it (None for the first
    image of the stream); :meth:`push` answers the image those labels lie on.
    """

    def __init__(self) -> None:
        self.image = None  # the last image pushed: the next pair's labels lie on it
        self.output = None  # the last pair's output, which the last image takes

    def push(self, image, output):
        """The image that ``output``, the labels of the pair that ends at ``image``, lie
        on: the image pushed before it; None where there is no pair (``output`` None, or
        no image before)."""
        on, self.image = self.image, image
        if output is None or on is None:
            return None
        self.output = output
        return on

    def last_image(self):
        """``(the last image, the last pair's output)``, the labels the last image takes;
        None before any pair."""
        return None if self.output is None else (self.image, self.output)


def iter_dynamic_masks(
    result, height: int, width: int, cell: int, *, final_ids=None, grow: int = 0
) -> Iterator[np.ndarray]:
    """One ``(height, width)`` bool mask per image of the sequence, lazily, in frame order.

    Args:
      result: a :class:`~jaxvo.odometry.SequenceResult`, a :class:`~jaxvo.core.pipeline.StepOutput`
        stacked over T frame pairs (its ``moving`` points are used), or ``(T, n)`` moving
        flags (bool) or identifiers (int, ``>= 2`` = moving; ``(n,)`` for one pair).
      height, width: image size, pixels.
      cell: grid cell size, pixels (``Config.cell`` of the run).
      final_ids: optional ``(n,)`` identifiers of the final state
        (``final_state.temporal.model.ids``), compensated onto the last image; see the module
        docstring for what the last image takes without it.
      grow: cells by which each moving cell is dilated (covers object borders between grid
        points); 0 keeps exactly the moving cells.

    Yields:
      T + 1 masks, bool, True = dynamic pixel (a moving cell); mask ``k`` is image ``k``,
      or ``result.frames[k]`` where a ``SequenceResult`` dropped frames.
    """
    ids = _ids_of(result)
    n = (height // cell) * (width // cell)
    if ids.shape[1] != n:
        raise ValueError(
            f"identifiers have {ids.shape[1]} cells but a {height} x {width} image with "
            f"{cell} px cells has {n}"
        )
    last = ids[-1] if final_ids is None else np.asarray(final_ids).reshape(n)
    for k in range(len(ids)):
        yield dynamic_pixels(ids[k], height, width, cell, grow=grow)
    yield dynamic_pixels(last, height, width, cell, grow=grow)


def dynamic_masks(
    result, height: int, width: int, cell: int, *, final_ids=None, grow: int = 0
) -> np.ndarray:
    """Dynamic pixels of every image of a run: ``(T + 1, height, width)`` bool, True = ignore.

    Index ``k`` is image ``k`` of the sequence (``T`` frame pairs make ``T + 1`` images).
    Arguments as :func:`iter_dynamic_masks`. Feed a peer with
    ``run_peer(seq, kind, keep=lambda i: ~masks[i])``.
    """
    return np.stack(
        list(iter_dynamic_masks(result, height, width, cell, final_ids=final_ids, grow=grow))
    )


def mask_png(mask: np.ndarray) -> np.ndarray:
    """A mask as the 8-bit image written to disk: 255 = dynamic pixel, 0 = static."""
    return np.where(np.asarray(mask, bool), np.uint8(255), np.uint8(0))
