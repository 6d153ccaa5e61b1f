"""How finely a real sensor's depth readings are quantised, by depth (issue 51's diagnosis).

A structured-light sensor (Kinect, Xtion) measures disparity in fixed sub-pixel steps, so
its depth readings take values ``q z^2`` apart: a flat wall far away reads as a few
terraces, and the points of one terrace change their reading together when the camera
moves. The noise model (``Params.depth_coeff``) treats every reading's error as its own.
This script reads the steps from the depth images alone, without ground truth: in each
depth band of each frame, the spacing of the distinct values read there (their median
difference), over the band's centre squared; the table gives each band's median over the
frames, and the sequence's ``q`` is the median over its bands.

    .venv/bin/python bench/depth_quantisation.py [--frames 10] [--camera PRESET] [SEQ_DIR ...]

Without folders it reads the real sequences of the data root (``$JAXVO_DATA``) that are
there.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from _common import REAL_SEQUENCES, machine_line
from _options import count

from jaxvo.errors import InputError
from jaxvo.host.readers.io import data_root, open_sequence

# depth bands, metres: each about a tenth of its depth wide
BANDS = ((0.8, 0.9), (1.0, 1.1), (1.4, 1.55), (1.9, 2.1), (2.6, 2.85), (3.5, 3.85),
         (4.6, 5.1), (5.4, 6.0))
MIN_VALUES = 4  # a band of a frame with fewer distinct readings says nothing of a spacing
RESOLUTION = 1e-4  # metres: readings are compared to a tenth of a millimetre


def band_steps(depth: np.ndarray, bands=BANDS) -> list[float]:
    """Each band's spacing of the distinct readings of ``depth`` (H, W) metres (0: none)
    inside it, metres: the median difference of consecutive distinct values; NaN where the
    band holds fewer than :data:`MIN_VALUES` of them."""
    z = np.asarray(depth, np.float64)
    out = []
    for lo, hi in bands:
        values = np.unique(np.round(z[(z > lo) & (z < hi)] / RESOLUTION)) * RESOLUTION
        out.append(float(np.median(np.diff(values))) if values.size >= MIN_VALUES
                   else float("nan"))
    return out


def quantisation(depths, bands=BANDS) -> dict:
    """Over frames ``depths`` (each (H, W) metres): each band's median spacing (metres),
    that spacing over the band's centre squared (1/m), and the median of the latter over
    the bands that have one (``q``, NaN where none has: no frame, or no reading)."""
    steps = np.array([band_steps(d, bands) for d in depths], np.float64)  # (frames, bands)
    steps = steps.reshape(-1, len(bands))
    have = np.isfinite(steps).any(axis=0)
    step = np.full(len(bands), np.nan)
    step[have] = np.nanmedian(steps[:, have], axis=0)
    centre = np.array([(lo + hi) / 2 for lo, hi in bands])
    coeff = step / centre ** 2
    q = float(np.nanmedian(coeff)) if np.isfinite(coeff).any() else float("nan")
    return {"step": step, "coeff": coeff, "q": q}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", type=Path, help="TUM-layout sequences")
    ap.add_argument("--frames", type=count(1), default=10, help="frames read, evenly spread")
    ap.add_argument("--camera", help="a camera preset or file, for a folder without camera.txt "
                                     "(only its depth scale matters here)")
    args = ap.parse_args(argv)
    folders = args.folders or [data_root() / name for name in REAL_SEQUENCES
                               if (data_root() / name).is_dir()]
    print(machine_line())
    if not folders:
        print(f"no sequence given and none of {', '.join(REAL_SEQUENCES)} under {data_root()}")
        return 0
    print("\n| sequence | " + " | ".join(f"{lo}-{hi} m" for lo, hi in BANDS) + " | q (1/m) |")
    print("|---|" + "---|" * (len(BANDS) + 1))
    for folder in folders:
        try:
            seq = open_sequence(folder, camera=args.camera)
            picks = np.unique(np.linspace(0, len(seq) - 1, min(args.frames, len(seq))).astype(int))
            r = quantisation([seq[int(i)].depth for i in picks])
        except InputError as e:
            print(f"depth_quantisation.py: {e}", file=sys.stderr)
            return 2
        cells = [f"{1e3 * s:.1f} mm ({1e3 * c:.2f}e-3)" if np.isfinite(s) else "-"
                 for s, c in zip(r["step"], r["coeff"], strict=True)]
        q = f"{1e3 * r['q']:.2f}e-3" if np.isfinite(r["q"]) else "- (no band with readings)"
        print(f"| {folder.name} | " + " | ".join(cells) + f" | {q} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
