"""Render every jaxvo.synth.scenes scenario: one picture each and a table of what it contains.

Usage: .venv/bin/python examples/render_scenarios.py [--out DIR] [--frames 90]

Writes into ``synth_scenarios/`` by default; ``--out docs/images`` refreshes the
pictures in the docs (each file there is replaced).

Pictures: three frames per scenario (rows), each as colour | depth (turbo colour map,
0-4 m, black = no reading) | object mask over the dimmed colour. Table (markdown, on
stdout): camera speed, object count, object image speed in px/frame from the exact
ground truth (the true flow of the object's own pixels), the share of frames in which
it exceeds 1 px, the largest image share covered by objects, the nearest object distance
and the share of pixels without a depth reading under the default sensor options.
A composite picture (boxes inserted into the 7-Scenes sequence) is added when the real
data is present.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from jaxvo.host.frontend.camera import backproject, project
from jaxvo.host.readers.io import data_root
from jaxvo.synth import scenes as synth

TILE = (256, 192)
MASK_COLOURS = np.array([[0, 0, 0], [40, 40, 255], [255, 160, 30], [40, 220, 60],
                         [220, 60, 220]], np.uint8)


def panel(frame) -> np.ndarray:
    """colour | depth | mask, each resized to TILE."""
    d = np.clip(frame.depth / 4.0 * 255.0, 0, 255).astype(np.uint8)
    depth = cv2.applyColorMap(d, cv2.COLORMAP_TURBO)
    depth[frame.depth == 0] = 0
    over = (frame.bgr * 0.45).astype(np.uint8)
    m = frame.mask > 0
    over[m] = (0.35 * frame.bgr[m] + 0.65 * MASK_COLOURS[frame.mask[m] % 5]).astype(np.uint8)
    parts = [cv2.resize(img, TILE, interpolation=cv2.INTER_AREA)
             for img in (frame.bgr, depth, over)]
    return np.hstack(parts)


def picture(seq, indices, path: Path) -> None:
    rows = [panel(seq[i]) for i in indices]
    img = np.vstack(rows)
    for r, i in enumerate(indices):
        cv2.putText(img, f"{seq.name} frame {i}", (6, r * TILE[1] + 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    # A 128-colour palette PNG (Pillow, which matplotlib brings along): a quarter of the
    # size of a true-colour PNG of these noisy textures, and hardly distinguishable.
    from PIL import Image

    rgb = Image.fromarray(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
    rgb.quantize(colors=128, method=Image.Quantize.MEDIANCUT,
                 dither=Image.Dither.NONE).save(path, optimize=True)


def object_flow(seq, frame, i: int, k: int, step: int = 4) -> np.ndarray:
    """True image motion (px) of object k's pixels from frame i to i + 1."""
    v, u = np.nonzero(frame.mask[::step, ::step] == k)
    uv = np.stack([u, v], -1).astype(np.float64) * step
    z = frame.depth[v * step, u * step].astype(np.float64)
    P = backproject(uv, z, seq.intrinsics)
    T_w_c0, T_w_c1 = seq.groundtruth.poses[i], seq.groundtruth.poses[i + 1]
    T_w_o0 = seq.object_trajectories[k].poses[i]
    T_w_o1 = seq.object_trajectories[k].poses[i + 1]
    M = np.linalg.inv(T_w_c1) @ T_w_o1 @ np.linalg.inv(T_w_o0) @ T_w_c0
    uv1 = project(P @ M[:3, :3].T + M[:3, 3], seq.intrinsics)
    return np.linalg.norm(uv1 - uv, axis=1)


def stats(name: str, frames: int) -> dict:
    ideal = synth.make_sequence(name, frames=frames, seed=0, options=synth.SensorOptions.ideal())
    real = synth.make_sequence(name, frames=frames, seed=0)
    invalid, cover, nearest = [], [], np.inf
    speeds = {k: [] for k in ideal.object_trajectories}
    for i in range(frames):
        f = ideal[i]
        invalid.append(np.mean(real[i].depth == 0))
        cover.append(np.mean(f.mask > 0))
        if f.mask.any():
            nearest = min(nearest, float(f.depth[f.mask > 0].min()))
        if i + 1 < frames:
            for k, speed in speeds.items():
                if np.count_nonzero(f.mask == k) > 50:
                    speed.append(np.median(object_flow(ideal, f, i, k)))
    cam = ideal.groundtruth.poses[:, :3, 3]
    cam_speed = np.linalg.norm(np.diff(cam, axis=0), axis=1).mean() * ideal.fps
    return {
        "camera m/s": f"{cam_speed:.2f}",
        "objects": str(len(speeds)),
        "object px/frame (median, p10)": "; ".join(
            f"{np.median(s):.1f}, {np.percentile(s, 10):.1f}" for s in speeds.values() if s)
        or "-",
        "frames > 1 px": "; ".join(f"{np.mean(np.array(s) > 1):.0%}"
                                   for s in speeds.values() if s) or "-",
        "max object cover": f"{max(cover):.0%}",
        "nearest object m": f"{nearest:.2f}" if np.isfinite(nearest) else "-",
        "invalid depth": f"{np.mean(invalid):.1%}",
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="synth_scenarios",
                        help="folder for the pictures (default synth_scenarios; docs/images "
                        "replaces the docs' pictures)")
    parser.add_argument("--frames", type=int, default=synth.DEFAULT_FRAMES)
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n = args.frames
    shown = [n // 6, n // 2, (5 * n) // 6]
    table = []
    for name in synth.SCENARIOS:
        seq = synth.make_sequence(name, frames=n, seed=0)
        path = out / f"synth_{name}.png"
        picture(seq, shown, path)
        table.append((name, stats(name, n)))
        print(f"wrote {path} ({path.stat().st_size // 1024} KiB)", flush=True)
    seven = data_root() / "7scenes_static_0000_0299"
    if seven.is_dir():
        seq = synth.composite_sequence(seven, "handheld_slow", frames=n, seed=0)
        path = out / "synth_composite_7scenes.png"
        picture(seq, shown, path)
        print(f"wrote {path} ({path.stat().st_size // 1024} KiB)")
    keys = list(table[0][1])
    print("\n| scenario | " + " | ".join(keys) + " |")
    print("| --- " * (len(keys) + 1) + "|")
    for name, row in table:
        print(f"| `{name}` | " + " | ".join(row[k] for k in keys) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
