"""Ground-truth masks of the people in the real TUM clip ``tum_fr3_walking_halfsphere_50``.

The benchmark uses them to measure how much of jaxvo's "dynamic pixel" mask falls outside
the two people who walk through the clip. The outlines live in
``bench/annotations/tum_fr3_walking_halfsphere_50_people.json``: for every frame of the
clip's ``associations.txt`` (49 frames: the 50th colour image, 1341846435.350127, has no
depth partner there, so jaxvo never reads it and it is not annotated), keyed by the RGB
timestamp string and carrying the frame index, one polygon per visible person in RGB
pixel coordinates. The mask of a frame is the union of its filled polygons
(``cv2.fillPoly``); nothing else (no depth) enters it.

How the outlines were made
--------------------------
By hand, on the RGB images only, viewing each frame with a labelled pixel grid (2x zooms
of each person, 3x where an edge was unclear). Frame 0 was traced from scratch; each later
frame started from the previous frame's outline moved by the median Farneback optical flow
of the person's pixels near each vertex, and was then looked at and corrected vertex by
vertex. Where a person changed pose too much for that (standing up, turning, the man in
the checked shirt walking in front of the man in the black shirt from frame 42), the
outline was redrawn from scratch (frames 16, 34, 43-48 in whole or in part, and the arm
and head of the man in the checked shirt in frames 17-20 and 33-42). Along the back of the
man in the black shirt (frames 24-41, 47-48), where a black T-shirt meets a light
background, the vertices were placed where each image row's run of dark pixels ends, read
off the grey image, then checked by eye. No vertex was interpolated between keyframes
without being looked at, and every one of the 49 overlays was reviewed at the end
(``--check``).

Depth was not used to refine the masks: the two people and the hand-held camera move
fast, and in this clip the depth silhouettes are offset from the colour silhouettes by up
to about 10-15 px in the frames with fast motion (frames 0, 6-8, 14-18; the colour and
depth images are not exposed at the same instant), so trimming the polygons to depth
would cut real RGB pixels off the people, and a depth-derived mask of a person can lie up
to that far outside these outlines.

Accuracy
--------
Where a person is sharp the outline lies within about 3-6 px of the visible silhouette.
Many frames are motion-blurred (frames 6-7, 14-18, 21-24, 32, 39-48 most); there the
silhouette itself is a 10-25 px wide smear and the outline follows the middle of the
smear, so it is within about 8-10 px of any reasonable reading of it. Known
simplifications, all small: background seen through gaps between an arm and the body is
not cut out (frames 0-8, about 10 x 40 px between the left forearm and the body of the man
in the checked shirt; frames 19-20, about 25 x 35 px by his right elbow); hair is outlined
as the visible hair mass; a person hidden behind the other is outlined only where
visible (the union mask is what the benchmark uses), and the chair seat in front of the
black shirt's legs (frames 34-48, bottom edge) is left out of the mask.

Use
---
``people_masks(seq_dir)`` returns ``{frame index: (480, 640) bool mask}``; the masks cover
16.6-27.8 % of the image (median 21.9 %).
``python bench/people_masks.py --check OUT_DIR`` writes, for every frame, the RGB image with
the mask tinted and its outline drawn (``frame_NN.png``) and a contact sheet of all frames
(``contact_sheet.png``), and prints each frame's share of the image that the mask covers.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

SEQUENCE = "tum_fr3_walking_halfsphere_50"
ANNOTATION = Path(__file__).resolve().parent / "annotations" / f"{SEQUENCE}_people.json"


def load_annotation(path: str | Path = ANNOTATION) -> dict:
    """The annotation document (see the module docstring for its layout)."""
    return json.loads(Path(path).read_text())


def _associations(seq_dir: Path) -> list[str]:
    """RGB timestamp strings of ``associations.txt`` in frame order, as written there."""
    rows = []
    for line in (seq_dir / "associations.txt").read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            rows.append(line.split()[0])
    return rows


def render_mask(polygons: list, height: int = 480, width: int = 640) -> np.ndarray:
    """The (height, width) bool union of the filled ``polygons`` (lists of [x, y])."""
    mask = np.zeros((height, width), np.uint8)
    for poly in polygons:
        cv2.fillPoly(mask, [np.asarray(poly, np.int32).reshape(-1, 1, 2)], 1)
    return mask.astype(bool)


def frame_polygons(annotation: dict, timestamp: str) -> list:
    """All people's polygons of the frame whose RGB timestamp string is ``timestamp``."""
    try:
        frame = annotation["frames"][timestamp]
    except KeyError:
        raise KeyError(f"no annotation for the frame at {timestamp}") from None
    return [poly for person in frame["people"] for poly in person["polygons"]]


def people_masks(seq_dir: str | Path, annotation: dict | None = None) -> dict[int, np.ndarray]:
    """``{frame index: (H, W) bool mask of the people}`` for every frame of ``seq_dir``.

    Frame indices follow ``associations.txt`` (as jaxvo's ``TumSequence`` numbers frames);
    each frame is matched to its annotation by its RGB timestamp string, and a frame that
    carries an index different from its position in the file is an error, so a reordered
    or different clip cannot silently receive the wrong masks.
    """
    seq_dir = Path(seq_dir)
    ann = load_annotation() if annotation is None else annotation
    h, w = ann["image_size"]["height"], ann["image_size"]["width"]
    masks = {}
    for index, stamp in enumerate(_associations(seq_dir)):
        polys = frame_polygons(ann, stamp)
        if ann["frames"][stamp]["index"] != index:
            raise ValueError(f"frame {stamp} is annotated as index "
                             f"{ann['frames'][stamp]['index']}, but is frame {index} here")
        masks[index] = render_mask(polys, h, w)
    return masks


def people_clip(bench: str):
    """The TUM walking clip (:data:`SEQUENCE` under the data root) as ``(sequence, people
    masks)``, the frames read lazily; None, after a line saying ``bench`` skipped, where the
    clip is absent."""
    from jaxvo.host.readers.io import data_root, open_sequence

    folder = data_root() / SEQUENCE
    if not folder.is_dir():
        print(f"{bench}: skipped, the TUM clip is not at {folder}")
        return None
    return open_sequence(folder), people_masks(folder)


def overlay(bgr: np.ndarray, mask: np.ndarray, label: str = "") -> np.ndarray:
    """``bgr`` with ``mask`` tinted magenta and its outline drawn, for review by eye."""
    out = bgr.copy()
    tint = np.array([255, 0, 255], np.float32)
    out[mask] = (0.6 * out[mask] + 0.4 * tint).astype(np.uint8)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(out, contours, -1, (0, 255, 255), 1)
    if label:
        cv2.putText(out, label, (8, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 4)
        cv2.putText(out, label, (8, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2)
    return out


def write_check(seq_dir: str | Path, out_dir: str | Path, cols: int = 7,
                scale: float = 0.5) -> list[float]:
    """Write the per-frame overlays and the contact sheet; returns each frame's mask share."""
    seq_dir, out_dir = Path(seq_dir), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ann = load_annotation()
    masks = people_masks(seq_dir, ann)
    stamps = _associations(seq_dir)
    tiles, shares = [], []
    for index, stamp in enumerate(stamps):
        bgr = cv2.imread(str(seq_dir / ann["frames"][stamp]["rgb"]), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(seq_dir / ann["frames"][stamp]["rgb"])
        share = float(masks[index].mean())
        shares.append(share)
        img = overlay(bgr, masks[index], f"{index}  {stamp}  {100 * share:.1f}%")
        cv2.imwrite(str(out_dir / f"frame_{index:02d}.png"), img)
        tiles.append(cv2.resize(overlay(bgr, masks[index], str(index)), None, fx=scale,
                                fy=scale, interpolation=cv2.INTER_AREA))
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[r:r + cols]) for r in range(0, len(tiles), cols)]
    cv2.imwrite(str(out_dir / "contact_sheet.png"), np.vstack(rows))
    return shares


def main(argv: list[str] | None = None) -> int:
    """``--check OUT_DIR``: write the review images and print the mask shares."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", metavar="OUT_DIR", required=True,
                        help="folder for frame_NN.png overlays and contact_sheet.png")
    parser.add_argument("--seq", metavar="DIR", default=None,
                        help=f"the clip's folder (default: the data root's {SEQUENCE})")
    args = parser.parse_args(argv)
    if args.seq is None:
        from jaxvo.host.readers.io import data_root

        seq = data_root() / SEQUENCE
    else:
        seq = Path(args.seq)
    if not (seq / "associations.txt").is_file():
        print(f"{seq}: no associations.txt (set JAXVO_DATA or pass --seq)", file=sys.stderr)
        return 2
    shares = write_check(seq, args.check)
    for i, s in enumerate(shares):
        print(f"frame {i:2d}: {100 * s:5.1f} % of the image")
    print(f"mask share: min {100 * min(shares):.1f} %, median {100 * float(np.median(shares)):.1f}"
          f" %, max {100 * max(shares):.1f} % over {len(shares)} frames; wrote {args.check}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
