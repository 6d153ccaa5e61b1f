"""How far apart are the background's motion and a near mover's over k frames, measured
with jaxvo's own noise model on the exact ground truth: does a motion test against a frame
k back tell them apart where one pair cannot?

For each sequence and seed, at every frame t from k on, the background's grid points of
frame t - k (one per 16-pixel cell, valid depth, no object) are moved to frame t twice:
by the camera's true motion (where they are) and by the mover's true motion relative to the
camera (where they would be if they moved with it). The difference, in units of the
sensor's noise (:func:`jaxvo.core.noise.point_noise` at the default ``pixel_sigma`` and
``depth_coeff``, both readings), is a chi-square of 3 degrees of freedom for pure noise.
The share of points over its 0.99 quantile (11.34) is the share an inlier test at jaxvo's
default confidence could tell apart. Reported: its median over the frames and seeds, and
the median squared distance, for each k.

The heavy-cover family (``heavy_cover_50`` / ``_70``, synthetic) is where jaxvo finds one
segment in a pair; the carried composites (``carried_50`` / ``_70`` over the 7-Scenes
frames, when the data is there) are where the motions separate in a pair but late.

``--tracked`` measures the same with jaxvo's own tracked points instead of exact motions
of exact points, on the heavy-cover family: the pair's grid flow (k = 1) and the keyframe
tracker's points (``Config.keyframes``; k the frames since the keyframe, 10 or more pooled).
A background point (ground-truth mask of its first frame) counts as told apart where it is
an inlier under the camera's true motion and an outlier under the mover's: the tracking's
own errors over k frames are in it.

Usage: ``python bench/bench_separation.py [--seeds 5] [--frames 60] [--tracked] [--out
results/]``; writes ``separation.md`` and ``separation.json`` (``separation_tracked.*``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from _options import count

from jaxvo.config import Params
from jaxvo.core.noise import init_noise, mahalanobis, point_noise
from jaxvo.host.readers.io import data_root
from jaxvo.synth.scenes import composite_sequence, make_sequence

K = (1, 2, 5, 10, 20)
CHI2_3_099 = 11.345  # the 0.99 quantile of chi-square with 3 degrees of freedom
SEVEN_SCENES = "7scenes_static_0000_0299"


def grid_points(frame, K_, cell: int = 16):
    """The background's points of ``frame`` at the cell centres: (3, n) in its camera."""
    h, w = frame.depth.shape
    v, u = np.mgrid[cell // 2:h:cell, cell // 2:w:cell]
    z = frame.depth[v, u].astype(np.float64)
    keep = (z > 0) & (frame.mask[v, u] == 0)
    u, v, z = u[keep], v[keep], z[keep]
    return np.stack([(u - K_.cx) / K_.fx * z, (v - K_.cy) / K_.fy * z, z])


def moved(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return T[:3, :3] @ p + T[:3, 3:4]


def separation(seq, frames: list, k: int) -> tuple[list[float], list[float]]:
    """Per frame t >= k: the share of frame t - k's background points an inlier test tells
    apart from the mover's motion, and their median squared distance in noise units."""
    scale = init_noise(Params())
    T_w_c = seq.groundtruth.poses
    [T_w_o] = [tr.poses for tr in seq.object_trajectories.values()]
    shares, medians = [], []
    for t in range(k, len(seq)):
        p0 = grid_points(frames[t - k], seq.intrinsics)
        if p0.shape[1] < 10:
            continue
        camera = np.linalg.inv(T_w_c[t]) @ T_w_c[t - k]
        mover = np.linalg.inv(T_w_c[t]) @ T_w_o[t] @ np.linalg.inv(T_w_o[t - k]) @ T_w_c[t - k]
        where, if_moved = moved(camera, p0), moved(mover, p0)
        noise = point_noise(p0.astype(np.float32), where.astype(np.float32),
                            np.float32(seq.intrinsics.fx), scale)
        d2 = np.asarray(mahalanobis((if_moved - where).astype(np.float32), noise))
        shares.append(float(np.mean(d2 > CHI2_3_099)))
        medians.append(float(np.median(d2)))
    return shares, medians


def _told_apart(K_, frame0, src, dst, valid, camera, mover, scale) -> float | None:
    """The share of ``frame0``'s background points among the tracked ``src`` -> ``dst``
    (n, 3) that are inliers under ``camera`` and outliers under ``mover``; None where fewer
    than 10 are there."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    z = np.where(src[:, 2] > 0, src[:, 2], 1.0)
    u = np.round(src[:, 0] / z * K_.fx + K_.cx).astype(int)
    v = np.round(src[:, 1] / z * K_.fy + K_.cy).astype(int)
    h, w = frame0.mask.shape
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    label = np.full(len(src), 255)
    label[inside] = frame0.mask[v[inside], u[inside]]
    background = np.asarray(valid) & inside & (label == 0)
    if background.sum() < 10:
        return None
    p0, p1 = src[background].T, dst[background].T
    noise = point_noise(p0.astype(np.float32), p1.astype(np.float32), np.float32(K_.fx), scale)
    d_cam, d_mov = (np.asarray(mahalanobis((moved(T, p0) - p1).astype(np.float32), noise))
                    for T in (camera, mover))
    return float(np.mean((d_cam < CHI2_3_099) & (d_mov > CHI2_3_099)))


def tracked_separation(seq, frames: list) -> dict[str, list[float]]:
    """Per pair: :func:`_told_apart` of the pair's flow (``"1"``) and of the keyframe's
    tracked points (``"kf k"``, k the frames since the keyframe, at most 10)."""
    from jaxvo.config import Config
    from jaxvo.host.frontend.flow import FrameChain, GridFlowTracker

    scale = init_noise(Params())
    K_ = seq.intrinsics
    T_w_c = seq.groundtruth.poses
    [T_w_o] = [tr.poses for tr in seq.object_trajectories.values()]
    chain = FrameChain(GridFlowTracker(K_, Config(keyframes=True), height=seq.height,
                                       width=seq.width), min_valid=5, keyframes=True)
    chain.push(frames[0].bgr, frames[0].depth)
    out: dict[str, list[float]] = {}
    previous = keyframe = 0
    for t in range(1, len(frames)):
        flow, _ = chain.push(frames[t].bgr, frames[t].depth)
        if flow is None:
            continue
        kf = chain.keyframe_flow
        for name, src, dst, valid, i0 in (
                ("1", flow.pts_prev, flow.pts_cur, flow.valid, previous),
                (f"kf {min(t - keyframe, 10)}", kf.pts_kf, kf.pts_cur, kf.valid, keyframe)):
            camera = np.linalg.inv(T_w_c[t]) @ T_w_c[i0]
            mover = np.linalg.inv(T_w_c[t]) @ T_w_o[t] @ np.linalg.inv(T_w_o[i0]) @ T_w_c[i0]
            share = _told_apart(K_, frames[i0], src, dst, valid, camera, mover, scale)
            if share is not None:
                out.setdefault(name, []).append(share)
        previous = t
        keyframe = t if bool(kf.renew) else keyframe
    return out


def tracked_report(args) -> list[str]:
    """The ``--tracked`` table: the heavy-cover family through jaxvo's own tracking."""
    table: dict[str, dict[str, list[float]]] = {}
    for name in ("heavy_cover_50", "heavy_cover_70"):
        for s in range(args.seeds):
            seq = make_sequence(name, frames=args.frames, seed=s)
            for key, shares in tracked_separation(seq, list(seq)).items():
                table.setdefault(f"synth_{name}", {}).setdefault(key, []).extend(shares)
            print(f"{name} seed {s} done", flush=True)
    keys = ["1"] + [f"kf {k}" for k in range(1, 11)]
    heads = [f"keyframe, k {'>=' if k == keys[-1] else '='} {k[3:]}" for k in keys[1:]]
    lines = ["| case | pair | " + " | ".join(heads) + " |",
             "|---|" + "---|" * len(keys)]
    for case, by in table.items():
        cells = [(f"{np.median(by[k]):.2f} [{np.percentile(by[k], 10):.2f}] ({len(by[k])})"
                  if k in by else "-") for k in keys]
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    (args.out / "separation_tracked.json").write_text(json.dumps(table))
    return lines


def cases(frames: int, seeds: int):
    for name in ("heavy_cover_50", "heavy_cover_70"):
        for s in range(seeds):
            yield f"synth_{name}", s, lambda n=name, s=s: make_sequence(n, frames=frames, seed=s)
    root = data_root() / SEVEN_SCENES
    if root.is_dir():
        for name in ("carried_50", "carried_70"):
            for split, start in (("dev", 0), ("val", 150)):  # as bench/bench_cover.py
                for s in range(seeds):
                    yield (f"comp_{name}_{split}", s, lambda n=name, a=start, s=s:
                           composite_sequence(root, n, start=a, frames=frames, seed=s))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=count(1), default=5)
    # more frames than the longest k, so that every k has pairs to measure
    ap.add_argument("--frames", type=count(max(K) + 1), default=60)
    ap.add_argument("--out", type=Path, default=Path("results"))
    ap.add_argument("--tracked", action="store_true", help="jaxvo's own tracked points")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.tracked:
        lines = tracked_report(args)
        (args.out / "separation_tracked.md").write_text("\n".join(lines) + "\n")
        print("\n".join(lines))
        return
    table: dict[str, dict[int, dict[str, list[float]]]] = {}
    for case, seed, build in cases(args.frames, args.seeds):
        seq = build()
        frames = list(seq)  # rendered once
        for k in K:
            shares, medians = separation(seq, frames, k)
            row = table.setdefault(case, {}).setdefault(k, {"share": [], "d2": []})
            row["share"] += shares
            row["d2"] += medians
        print(f"{case} seed {seed} done", flush=True)
    lines = ["# How far apart the background's and the mover's motions are over k frames",
             "", ("`bench/bench_separation.py`: the share of the background's grid points an "
                  "inlier test at 0.99 tells apart from the mover's motion, median [10th-90th "
                  f"percentile] over the frames of {args.seeds} seeds ({args.frames} frames "
                  "each); the median squared distance in noise units (chi-square, 3 degrees "
                  "of freedom)."),
             "", "| case | " + " | ".join(f"k = {k}" for k in K) + " |",
             "|---|" + "---|" * len(K)]
    summary = {}
    for case, by_k in table.items():
        cells = []
        for k in K:
            share, d2 = np.asarray(by_k[k]["share"]), np.asarray(by_k[k]["d2"])
            q = np.percentile(share, [50, 10, 90])
            summary.setdefault(case, {})[k] = {"share_median": q[0], "share_p10": q[1],
                                               "share_p90": q[2], "d2_median": np.median(d2)}
            cells.append(f"{q[0]:.2f} [{q[1]:.2f}-{q[2]:.2f}], d2 {np.median(d2):.1f}")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    (args.out / "separation.md").write_text("\n".join(lines) + "\n")
    (args.out / "separation.json").write_text(json.dumps(summary, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
