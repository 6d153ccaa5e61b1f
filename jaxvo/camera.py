"""Pinhole camera intrinsics and depth scale (host side, numpy)."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np


class Intrinsics(NamedTuple):
    """Pinhole intrinsics in pixels and the depth scale in raw units per metre."""

    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float = 5000.0

    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], np.float64
        )


# Published calibrations, depth 5000 per metre: TUM RGB-D (vision.in.tum.de, "file formats")
# and the Bonn RGB-D Dynamic Dataset (Palazzolo et al., IROS 2019; TUM layout, one camera).
PRESETS: dict[str, Intrinsics] = {
    "tum_fr1": Intrinsics(517.3, 516.5, 318.6, 255.3, 5000.0),
    "tum_fr2": Intrinsics(520.9, 521.0, 325.1, 249.7, 5000.0),
    "tum_fr3": Intrinsics(535.4, 539.2, 320.1, 247.6, 5000.0),
    "bonn": Intrinsics(542.822841, 542.576870, 315.593520, 237.756098, 5000.0),
    "ros_default": Intrinsics(525.0, 525.0, 319.5, 239.5, 5000.0),
}


def preset(name: str) -> Intrinsics:
    """A named calibration from :data:`PRESETS`."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(
            f"unknown camera preset {name!r}; choose one of {', '.join(sorted(PRESETS))}"
        ) from None


def read_camera_file(path: str | Path) -> Intrinsics:
    """Read a ``camera.txt`` of ``key value`` lines (fx, fy, cx, cy, depth_scale; # comments)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    values: dict[str, float] = {}
    for lineno, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) != 2:
            raise ValueError(f"{path}:{lineno}: expected 'key value', got {raw.strip()!r}")
        try:
            values[parts[0]] = float(parts[1])
        except ValueError:
            raise ValueError(f"{path}:{lineno}: {parts[1]!r} is not a number") from None
    missing = [k for k in ("fx", "fy", "cx", "cy") if k not in values]
    if missing:
        raise ValueError(f"{path}: missing {', '.join(missing)}")
    scale = values.get("depth_scale", 5000.0)
    if values["fx"] <= 0 or values["fy"] <= 0 or scale <= 0:
        raise ValueError(f"{path}: focal lengths and depth_scale must be positive")
    return Intrinsics(values["fx"], values["fy"], values["cx"], values["cy"], scale)


def write_camera_file(path: str | Path, K: Intrinsics, *, comment: str = "") -> None:
    lines = [f"# {comment}"] if comment else []
    lines += [f"fx {K.fx:.6g}", f"fy {K.fy:.6g}", f"cx {K.cx:.6g}", f"cy {K.cy:.6g}"]
    lines.append(f"depth_scale {K.depth_scale:.6g}")
    Path(path).write_text("\n".join(lines) + "\n")


def backproject(uv: np.ndarray, z: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Pixels ``(..., 2)`` (x right, y down) with depth ``(...)`` metres -> ``(..., 3)`` points."""
    x = (uv[..., 0] - K.cx) / K.fx * z
    y = (uv[..., 1] - K.cy) / K.fy * z
    return np.stack([x, y, z], axis=-1)


def project(points: np.ndarray, K: Intrinsics) -> np.ndarray:
    """``(..., 3)`` camera points -> ``(..., 2)`` pixels (no check on z > 0)."""
    z = points[..., 2]
    safe = np.where(np.abs(z) > 1e-9, z, 1e-9)
    return np.stack([K.fx * points[..., 0] / safe + K.cx, K.fy * points[..., 1] / safe + K.cy], -1)


def grid_pixels(height: int, width: int, cell: int) -> np.ndarray:
    """Centres of the flow grid's cells, ``(rows * cols, 2)`` float32 (x, y), row-major."""
    rows, cols = height // cell, width // cell
    ys = (np.arange(rows) + 0.5) * cell - 0.5
    xs = (np.arange(cols) + 0.5) * cell - 0.5
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)
