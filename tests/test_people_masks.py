"""The hand-drawn people masks of the TUM walking clip (bench/people_masks.py).

The annotation file is checked on its own (it ships with the repository); the rendered
masks are checked against the clip itself, which lives outside the repository and is
skipped, with the reason, when the data folder is absent.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_BENCH = Path(__file__).resolve().parent.parent / "bench" / "people_masks.py"
_spec = importlib.util.spec_from_file_location("people_masks", _BENCH)
people_masks = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(people_masks)

# The clip's associations.txt lists 49 frames (the 50th colour image has no depth partner).
N_FRAMES = 49
# Share of the image the union mask covers: measured 16.6 % (frame 48) to 27.8 % (frame 28)
# when the annotation was made; the bounds leave about 2.5 points either side, so a
# polygon lost, doubled, or drawn in the wrong frame's coordinates fails.
SHARE_MIN, SHARE_MAX = 0.14, 0.30


def test_annotation_is_well_formed():
    ann = people_masks.load_annotation()
    frames = ann["frames"]
    assert len(frames) == N_FRAMES
    assert sorted(f["index"] for f in frames.values()) == list(range(N_FRAMES))
    w, h = ann["image_size"]["width"], ann["image_size"]["height"]
    for stamp, frame in frames.items():
        assert frame["rgb"] == f"rgb/{stamp}.png"
        for person in frame["people"]:
            assert person["person"] in ann["people"]
            for poly in person["polygons"]:
                xy = np.asarray(poly)
                assert xy.ndim == 2 and xy.shape[1] == 2 and len(xy) >= 10, (stamp, person)
                assert xy.min() >= 0 and (xy[:, 0] <= w).all() and (xy[:, 1] <= h).all()


def test_render_mask_fills_a_polygon():
    mask = people_masks.render_mask([[[10, 10], [29, 10], [29, 19], [10, 19]]], 40, 50)
    assert mask.dtype == bool and mask.shape == (40, 50)
    assert mask.sum() == 20 * 10 and mask[10:20, 10:30].all()


def test_people_masks_on_the_clip(require_data):
    seq = require_data(people_masks.SEQUENCE, "associations.txt").parent
    ann = people_masks.load_annotation()
    masks = people_masks.people_masks(seq, ann)
    assert sorted(masks) == list(range(N_FRAMES))
    by_index = {f["index"]: f for f in ann["frames"].values()}
    shares = []
    for index, mask in masks.items():
        assert mask.shape == (480, 640) and mask.dtype == bool
        if by_index[index]["people"]:
            assert mask.any(), f"frame {index}: people annotated but the mask is empty"
        else:
            assert not mask.any()
        shares.append(mask.mean())
    assert SHARE_MIN <= min(shares) and max(shares) <= SHARE_MAX, (min(shares), max(shares))
    # Both men are in view throughout the clip, so no frame may lose one of them.
    assert all(len(by_index[i]["people"]) == 2 for i in range(N_FRAMES))


def test_frame_order_mismatch_is_an_error(require_data, tmp_path):
    seq = require_data(people_masks.SEQUENCE, "associations.txt").parent
    rows = (seq / "associations.txt").read_text().splitlines()
    (tmp_path / "associations.txt").write_text("\n".join([rows[1], rows[0], *rows[2:]]) + "\n")
    with pytest.raises(ValueError, match="annotated as index"):
        people_masks.people_masks(tmp_path)
