"""How a keyframe track's error grows with the keyframe's age, on static real frames (issues
51 and 52).

The keyframe tracker (``Config.keyframes``) tracks the latest keyframe's grid points into
every image until the keyframe is renewed, and the test over the keyframe
(``jaxvo.core.separation``) reads those tracks with the pair's noise model. On a static
sequence every point moves as the camera does, so each valid keyframe point's residual under
the true motion from the keyframe's image to the current one (the ground truth's poses) is
the track's error. Per age (pairs since the keyframe's image): the lateral error in pixels
(the point moved by the true motion and projected, against where it was tracked; median and
90th percentile) and the depth error over z^2 (its robust spread, 1/m, the unit of the
noise model's depth coefficient). The pair's own tracks, the same way, are the first row:
what the noise model is calibrated on. The ground truth's own error is in every row alike.
The TUM clip's oracle (``tum_walking_nopeople``: the people's depth removed, so every valid
point is the room's) checks it against motion capture.

    .venv/bin/python bench/keyframe_track_noise.py [--case static_val_every1 ...]
        [--cache results/cache]
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np
from _common import groundtruth, machine_line
from _options import config_from
from bench_robustness import prepare
from bench_seeds import reference_case
from splits import available, cases

from jaxvo.trajectory import pose_at

CASES = ("static_dev_every1", "static_dev_every2", "static_val_every1", "tum_walking_nopeople")
MIN_TRACKS = 200  # an age with fewer tracks than this over the sequence is left out


def keyframe_images(renew: np.ndarray) -> np.ndarray:
    """(T,) the image each pair's keyframe was taken on: image 0 first, then the current
    image of every pair that renews (``renew`` (T,) bool), from the pair after it on."""
    images, kf = [], 0
    for k, r in enumerate(renew):
        images.append(kf)
        if r:
            kf = k + 1
    return np.asarray(images)


def track_errors(src, dst, T_true, focal: float):
    """Lateral pixel error (m,) and depth error over z^2 (m,) of points ``src`` (m, 3)
    tracked to ``dst`` (m, 3) where the true motion is ``T_true`` (4, 4)."""
    q = src @ T_true[:3, :3].T + T_true[:3, 3]
    lateral = focal * np.hypot(q[:, 0] / q[:, 2] - dst[:, 0] / dst[:, 2],
                               q[:, 1] / q[:, 2] - dst[:, 1] / dst[:, 2])
    return lateral, (q[:, 2] - dst[:, 2]) / dst[:, 2] ** 2


def by_age(data: dict) -> dict:
    """Each age's (and the pairs', key ``"pair"``) lateral and depth errors, concatenated."""
    truth = groundtruth(data)
    poses = [pose_at(truth, t) for t in np.asarray(data["timestamps"], np.float64)]
    focal = float(np.asarray(data["flow_focal"])[0])
    kf_image = keyframe_images(np.asarray(data["kf_renew"], bool))
    lateral, depth = collections.defaultdict(list), collections.defaultdict(list)
    for k, a in enumerate(kf_image):
        if poses[a] is None or poses[k] is None or poses[k + 1] is None:
            continue  # a frame of the pair or its keyframe without a ground-truth pose
        for key, first, src, dst, valid in (
                (k + 1 - a, a, data["kf_pts_kf"][k], data["kf_pts_cur"][k], data["kf_valid"][k]),
                ("pair", k, data["flow_pts_prev"][k], data["flow_pts_cur"][k],
                 data["flow_valid"][k])):
            v = np.asarray(valid, bool)
            lat, dz = track_errors(np.asarray(src, np.float64)[v], np.asarray(dst, np.float64)[v],
                                   np.linalg.inv(poses[k + 1]) @ poses[first], focal)
            lateral[key].append(lat)
            depth[key].append(dz)
    return {key: (np.concatenate(lateral[key]), np.concatenate(depth[key])) for key in lateral}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs="*", default=list(CASES),
                    help="static cases of bench/splits.py, or tum_walking_nopeople")
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    args = ap.parse_args(argv)
    cfg = config_from(["keyframes=true"])
    print(machine_line())
    static = [c for c in cases() if c.kind == "static"]
    static += [reference_case(c) for c in cases() if c.kind == "people"]
    for name in args.case:
        case = next((c for c in static if c.name == name), None)
        if case is None:
            print(f"{name}: not a static case of bench/splits.py (nor the TUM clip's oracle)")
            continue
        why = available(case)
        if why:
            print(f"{name}: skipped, {why}")
            continue
        data = prepare(case, args.cache, cfg)
        errors = by_age(data)
        keyframes = int(np.sum(data["kf_renew"])) + 1
        print(f"\n{name}: {len(data['kf_renew'])} pairs, {keyframes} keyframes")
        print("| age (pairs) | tracks | lateral px median | p90 "
              "| depth error / z^2, 1.4826 MAD (1/m) |")
        print("|---|---|---|---|---|")
        ages = ["pair"] + sorted(k for k in errors if k != "pair")
        for age in ages:
            lat, dz = errors[age]
            if len(lat) < MIN_TRACKS:
                continue
            mad = 1.4826 * np.median(np.abs(dz - np.median(dz)))
            print(f"| {age} | {len(lat)} | {np.median(lat):.2f} | {np.percentile(lat, 90):.2f} "
                  f"| {mad:.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
