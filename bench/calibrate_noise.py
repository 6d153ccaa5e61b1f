"""The sensor noise of the development split, measured against ground truth.

Under the true camera motion a static grid point's residual ``T_gt p_prev - p_cur`` is the
sensor's noise (and the ground truth's own error). Split along the viewing ray and across
it, its robust spread per depth band gives the two scales of the noise model
(:mod:`jaxvo.core.noise`): the depth noise along the ray over ``z^2`` (two depth readings) and the
tracker's pixel noise across it. The starting values of ``Params.pixel_sigma`` and
``Params.depth_coeff`` are those of the real development frames (7-Scenes frames 0-149);
the pipeline keeps them (its online calibration, ``Params.noise_rate > 0``, is off by
default: it did not pay on the validation split).

Run: ``.venv/bin/python bench/calibrate_noise.py [--cache results/cache]`` (the flows of
``bench/bench_robustness.py``'s cache; it builds them when absent).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_robustness import CFG, prepare
from splits import available, cases

_BANDS = ((0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.0), (3.0, 4.0))


def residual_parts(data: dict):
    """(z, along-ray residual, lateral residual length) of every static valid point, metres."""
    prev, cur, valid = data["flow_pts_prev"], data["flow_pts_cur"], data["flow_valid"]
    poses, truth = data["gt_poses"], data.get("grid_gt")
    out = []
    for k in range(len(valid)):
        T = np.linalg.inv(poses[k + 1]) @ poses[k]
        keep = valid[k] & (~truth[k] if truth is not None else True)
        p, c = prev[k][keep].astype(np.float64), cur[k][keep].astype(np.float64)
        r = p @ T[:3, :3].T + T[:3, 3] - c
        ray = c / np.linalg.norm(c, axis=1, keepdims=True)
        along = np.sum(r * ray, axis=1)
        lateral = np.linalg.norm(r - along[:, None] * ray, axis=1)
        out.append(np.stack([c[:, 2], along, lateral], axis=1))
    return np.concatenate(out)


def report(name: str, parts: np.ndarray, focal: float) -> None:
    print(f"{name}: {len(parts)} static point pairs")
    for lo, hi in _BANDS:
        m = (parts[:, 0] >= lo) & (parts[:, 0] < hi)
        if m.sum() < 50:
            continue
        z = parts[m, 0].mean()
        # robust sigma of the along-ray part (one axis, two readings) and of the lateral
        # length (a 2-D Rayleigh: its median is 1.1774 sigma)
        s_ray = 1.4826 * np.median(np.abs(parts[m, 1]))
        s_lat = np.median(parts[m, 2]) / 1.1774
        print(f"  z {lo:.1f}-{hi:.1f} m ({m.sum():6d}): along the ray {1e3 * s_ray:5.2f} mm = "
              f"{1e3 * s_ray / np.sqrt(2) / z ** 2:.2f}e-3 z^2 a reading; across "
              f"{1e3 * s_lat:5.2f} mm = {s_lat / z * focal:.2f} px")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    args = ap.parse_args(argv)
    for case in cases():
        if case.split != "dev" or case.kind not in ("static", "synthetic") or available(case):
            continue
        data = prepare(case, args.cache, CFG)
        if "gt_poses" not in data:
            continue
        report(case.name, residual_parts(data), float(data["flow_focal"][0]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
