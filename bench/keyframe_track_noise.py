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

A second table bins the same errors by the track's displacement, the pixels the point moved
in the image between its two images, pair tracks and keyframe tracks side by side: whether a
track errs by its age or by how far it moved. ``--reference jaxvo`` reads every error
under jaxvo's own poses (the default settings, seed 0) instead of the ground truth's: the
residuals the method itself sees, without the reference's own mismatch (7-Scenes' colour
images are not registered to the depth its ground truth was made from).

    .venv/bin/python bench/keyframe_track_noise.py [--case static_val_every1 ...]
        [--reference truth|jaxvo] [--cache results/cache]
"""

from __future__ import annotations

import argparse
import collections
import itertools
from pathlib import Path

import numpy as np
from _common import groundtruth, machine_line
from _options import config_from
from bench_robustness import prepare, run_jaxvo
from bench_seeds import reference_case
from splits import available, cases

from jaxvo.config import Params
from jaxvo.trajectory import pose_at

CASES = ("static_dev_every1", "static_dev_every2", "static_val_every1", "tum_walking_nopeople")
MIN_TRACKS = 200  # an age with fewer tracks than this over the sequence is left out
DISPLACEMENT_BINS = (0, 2, 5, 10, 20, 40, 80)  # pixels; the last bin is open


def keyframe_images(renew: np.ndarray) -> np.ndarray:
    """(T,) the image each pair's keyframe was taken on: image 0 first, then the current
    image of every pair that renews (``renew`` (T,) bool), from the pair after it on."""
    images, kf = [], 0
    for k, r in enumerate(renew):
        images.append(kf)
        if r:
            kf = k + 1
    return np.asarray(images)


def image_distance(a, b, focal: float):
    """Pixels between the projections of points ``a`` and ``b`` (m, 3), each in its camera."""
    return focal * np.hypot(a[:, 0] / a[:, 2] - b[:, 0] / b[:, 2],
                            a[:, 1] / a[:, 2] - b[:, 1] / b[:, 2])


def track_errors(src, dst, T_true, focal: float):
    """Lateral pixel error (m,) and depth error over z^2 (m,) of points ``src`` (m, 3)
    tracked to ``dst`` (m, 3) where the true motion is ``T_true`` (4, 4)."""
    q = src @ T_true[:3, :3].T + T_true[:3, 3]
    return image_distance(q, dst, focal), (q[:, 2] - dst[:, 2]) / dst[:, 2] ** 2


def reference_poses(data: dict, reference: str) -> list:
    """Each image's camera-to-world pose (None where unknown): the ground truth's, or
    jaxvo's own estimate (``reference == "jaxvo"``: the default settings, seed 0)."""
    if reference == "jaxvo":
        traj = run_jaxvo(data, Params(), config_from([]), seed=0)[0]
        return list(np.asarray(traj.poses, np.float64))
    truth = groundtruth(data)
    return [pose_at(truth, t) for t in np.asarray(data["timestamps"], np.float64)]


def by_age(data: dict, reference: str = "truth") -> dict:
    """Each age's (and the pairs', key ``"pair"``) lateral errors, depth errors and
    displacements (pixels between the track's two images), concatenated."""
    poses = reference_poses(data, reference)
    focal = float(np.asarray(data["flow_focal"])[0])
    kf_image = keyframe_images(np.asarray(data["kf_renew"], bool))
    lateral, depth = collections.defaultdict(list), collections.defaultdict(list)
    moved = collections.defaultdict(list)
    for k, a in enumerate(kf_image):
        if poses[a] is None or poses[k] is None or poses[k + 1] is None:
            continue  # a frame of the pair or its keyframe without a ground-truth pose
        for key, first, src, dst, valid in (
                (k + 1 - a, a, data["kf_pts_kf"][k], data["kf_pts_cur"][k], data["kf_valid"][k]),
                ("pair", k, data["flow_pts_prev"][k], data["flow_pts_cur"][k],
                 data["flow_valid"][k])):
            v = np.asarray(valid, bool)
            a, b = np.asarray(src, np.float64)[v], np.asarray(dst, np.float64)[v]
            lat, dz = track_errors(a, b, np.linalg.inv(poses[k + 1]) @ poses[first], focal)
            lateral[key].append(lat)
            depth[key].append(dz)
            moved[key].append(image_distance(a, b, focal))
    return {key: (np.concatenate(lateral[key]), np.concatenate(depth[key]),
                  np.concatenate(moved[key])) for key in lateral}


def by_displacement(errors: dict) -> list[tuple[str, str, str]]:
    """Rows ``(bin, pair tracks, keyframe tracks)``: the median lateral error in pixels and
    the number of tracks of each kind whose displacement falls in each bin of
    :data:`DISPLACEMENT_BINS` ("-" under :data:`MIN_TRACKS` tracks)."""
    kinds = {"pair": [errors["pair"]],
             "keyframe": [e for key, e in errors.items() if key != "pair"]}

    def joined(kind: str, column: int) -> np.ndarray:
        return np.concatenate([e[column] for e in kinds[kind]] or [np.zeros(0)])

    lat = {k: joined(k, 0) for k in kinds}
    moved = {k: joined(k, 2) for k in kinds}
    rows = []
    for lo, hi in itertools.pairwise([*DISPLACEMENT_BINS, np.inf]):
        cells = []
        for kind in ("pair", "keyframe"):
            inside = (moved[kind] >= lo) & (moved[kind] < hi)
            n = int(np.sum(inside))
            cells.append(f"{np.median(lat[kind][inside]):.2f} ({n})" if n >= MIN_TRACKS
                         else f"- ({n})")
        rows.append((f"{lo}-{hi:g}" if np.isfinite(hi) else f"{lo}+", *cells))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs="*", default=list(CASES),
                    help="static cases of bench/splits.py, or tum_walking_nopeople")
    ap.add_argument("--reference", choices=("truth", "jaxvo"), default="truth",
                    help="the poses the errors are read under: the ground truth's, or jaxvo's "
                         "own (default settings, seed 0)")
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
        errors = by_age(data, args.reference)
        keyframes = int(np.sum(data["kf_renew"])) + 1
        print(f"\n{name}: {len(data['kf_renew'])} pairs, {keyframes} keyframes, "
              f"errors under {'the ground truth' if args.reference == 'truth' else 'jaxvo'}'s "
              "poses")
        print("| age (pairs) | tracks | lateral px median | p90 "
              "| depth error / z^2, 1.4826 MAD (1/m) |")
        print("|---|---|---|---|---|")
        ages = ["pair"] + sorted(k for k in errors if k != "pair")
        for age in ages:
            lat, dz, _ = errors[age]
            if len(lat) < MIN_TRACKS:
                continue
            mad = 1.4826 * np.median(np.abs(dz - np.median(dz)))
            print(f"| {age} | {len(lat)} | {np.median(lat):.2f} | {np.percentile(lat, 90):.2f} "
                  f"| {mad:.4f} |")
        print("\n| displacement px | pair tracks: lateral px median (tracks) | keyframe tracks |")
        print("|---|---|---|")
        for row in by_displacement(errors):
            print("| " + " | ".join(row) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
