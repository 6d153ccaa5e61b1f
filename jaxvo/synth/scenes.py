"""Seeded synthetic and composited dynamic RGB-D sequences with exact ground truth (host).

Two kinds of sequence, one interface (the sequence contract of ``docs/architecture.md``):

* fully synthetic: a textured room with furniture, a camera path and ``K`` rigid textured
  boxes moving on their own paths, ray-cast by :mod:`jaxvo.synth.render`;
* composited: the same moving boxes inserted into a real RGB-D sequence that has camera
  ground truth, z-buffered against its depth.

Each frame carries the object-id mask (0 = static) and every sequence the camera
trajectory ``T_w_c`` and the object trajectories ``T_w_o``.

This module holds the entry points: :func:`make_sequence` (a preset of ``SCENARIOS`` or a
custom :class:`Scenario`), :func:`composite_sequence` and :func:`write_sequence` (any
sequence in the TUM layout plus masks and object trajectories). What a scene is made of
lives in :mod:`jaxvo.synth.scenario`, its rendering in :mod:`jaxvo.synth.sequence`; their
public names are re-exported here.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Distortion, write_camera_file
from jaxvo.host.readers.io import TumSequence, write_trajectory
from jaxvo.synth.scenario import SCENARIOS, ObjectSpec, Scenario, SensorOptions
from jaxvo.synth.sequence import (
    DEPTH_SCALE,
    RealBackground,
    SyntheticSequence,
    make_atlas,
    smooth_poses,
)
from jaxvo.trajectory import associate

DEFAULT_FRAMES = 90
DEFAULT_FPS = 30.0


# ------------------------------------------------------------------------- entry points


def _scenario(scenario: str | Scenario) -> Scenario:
    if isinstance(scenario, Scenario):
        return scenario
    try:
        return SCENARIOS[scenario]
    except KeyError:
        raise InputError(f"unknown scenario {scenario!r}; choose one of "
                         f"{', '.join(SCENARIOS)}") from None


def make_sequence(scenario: str | Scenario = "handheld_slow", *, frames: int = DEFAULT_FRAMES,
                  seed: int = 0, options: SensorOptions | None = None,
                  fps: float = DEFAULT_FPS, lens: Distortion | None = None) -> SyntheticSequence:
    """A fully synthetic sequence of a preset (a name in ``SCENARIOS``) or a ``Scenario``.

    Args:
      scenario: preset name or a custom :class:`Scenario`.
      frames: number of frames (>= 1).
      seed: seeds textures, furniture jitter, paths and sensor noise.
      options: sensor effects (default :class:`SensorOptions`: noise, holes, range on).
      fps: frame rate, Hz.
      lens: render the images through this lens distortion (each frame's pinhole render
        remapped, as a calibrated camera's raw images are); the sequence's ``intrinsics``
        carry it. None: pinhole images.

    Raises:
      InputError: unknown scenario, no frames, an object that does not fit in the room,
        a camera inside an object.
    """
    spec = _scenario(scenario)
    if int(frames) < 1:
        raise InputError(f"frames must be at least 1, got {frames}")
    if not fps > 0:
        raise InputError(f"fps must be positive, got {fps}")
    return SyntheticSequence(spec, frames=int(frames), seed=seed,
                             options=options or SensorOptions(), fps=fps, lens=lens)


def composite_sequence(sequence: str | Path | TumSequence,
                       scenario: str | Scenario = "handheld_slow", *,
                       frames: int | None = None, start: int = 0, seed: int = 0,
                       options: SensorOptions | None = None) -> SyntheticSequence:
    """Insert a preset's moving boxes into a real RGB-D sequence with camera ground truth.

    The boxes move around a heavily smoothed copy of the real camera path (a 3 s moving
    average), so they stay in view while moving independently of the camera, and are
    z-buffered against the real depth (no reading counts as far). The camera trajectory is
    the real ground truth; object trajectories are exact. Only frames with a ground-truth
    pose within 0.02 s are used. Sensor effects apply to the inserted pixels only.

    Args:
      sequence: a TUM-layout folder (with ``groundtruth.txt``, ``camera.txt``) or an open
        ``io.TumSequence``.
      scenario: which preset's objects to insert (its camera motion is ignored).
      frames: use ``frames`` frames (default all from ``start`` on).
      start: the first of them: the ``start``-th frame that has a ground-truth pose.
      seed, options: as in :func:`make_sequence`.
    """
    spec = _scenario(scenario)
    seq = sequence if isinstance(sequence, TumSequence) else TumSequence(sequence)
    if seq.groundtruth is None:
        raise InputError(f"{seq.name}: compositing needs camera ground truth "
                         "(groundtruth.txt)")
    ia, ib = associate(seq.timestamps, seq.groundtruth.timestamps, 0.02,
                       names=(seq.name, "groundtruth.txt"))
    if int(start) < 0:
        raise InputError(f"start must be 0 or more, got {start}")
    ia, ib = ia[int(start):], ib[int(start):]
    if frames is not None:
        if int(frames) < 1:
            raise InputError(f"frames must be at least 1, got {frames}")
        ia, ib = ia[:int(frames)], ib[:int(frames)]
    if len(ia) == 0:
        raise InputError(f"{seq.name}: no frame has a ground-truth pose")
    poses = seq.groundtruth.poses[ib].astype(np.float64)
    anchors = smooth_poses(poses, half_window=45)
    # Keep the boxes in front of the real surfaces: the preset's distances assume a room
    # 3 m deep; scale them to the real scene's median depth at the start.
    first = seq[int(ia[0])].depth
    valid = first[first > 0]
    median = float(np.median(valid)) if valid.size else 2.0
    far = max((o.centre[2] + o.amplitude[2] for o in spec.objects), default=1.0)
    z_scale = float(np.clip(0.8 * median / far, 0.4, 1.0))
    bg = RealBackground(seq, ia, poses, anchors, z_scale)
    return SyntheticSequence(spec, frames=len(ia), seed=seed,
                             options=options or SensorOptions(), fps=DEFAULT_FPS,
                             background=bg, name=f"composite_{spec.name}_{seq.name}"
                             f"{f'_from{int(start)}' if start else ''}_s{seed}")


def write_sequence(seq: SyntheticSequence, out_dir: str | Path, *,
                   progress: Callable[[int, int], None] | None = None) -> Path:
    """Write a sequence in the TUM layout plus masks and object trajectories, the folder
    whole or not at all (:class:`jaxvo.host.writers.outputs.OutputFolder`: written beside it and
    renamed into place when complete; an interrupted or failed write leaves no folder).

    Layout: ``rgb/`` (PNG), ``depth/`` (16-bit PNG, ``DEPTH_SCALE`` per metre, 0 = no
    reading), ``mask/`` (8-bit PNG object ids), ``rgb.txt``, ``depth.txt``, ``mask.txt``
    (``timestamp filename``), ``associations.txt``, ``groundtruth.txt`` (``T_w_c``),
    ``objects.txt`` (``timestamp object_id tx ty tz qx qy qz qw``, ``T_w_o``) and
    ``camera.txt``. Readable back with ``io.TumSequence``.

    Args:
      seq: the sequence (frames are rendered one at a time).
      out_dir: the folder (missing, or empty; its parent exists or is created).
      progress: called as ``progress(done, total)`` after each frame.

    Returns:
      the folder.
    Raises:
      InputError: ``out_dir`` holds files, or the timestamps collide.
      OSError: a file cannot be written, naming it (a full disk).
    """
    from jaxvo.host.writers.outputs import OutputFolder, write_image, write_text
    from jaxvo.transforms import rotation_to_quat

    out = Path(out_dir)
    names = [f"{t:.6f}.png" for t in seq.timestamps]
    if len(set(names)) != len(names):
        raise InputError(f"{seq.name}: timestamps collide at microsecond resolution")
    out.parent.mkdir(parents=True, exist_ok=True)
    with OutputFolder(out) as folder:
        tmp = folder.temporary
        for sub in ("rgb", "depth", "mask"):
            (tmp / sub).mkdir()
        scale = seq.intrinsics.depth_scale
        for i, frame in enumerate(seq):
            raw = np.clip(np.round(frame.depth.astype(np.float64) * scale), 0, 65535)
            for sub, img in (("rgb", frame.bgr), ("depth", raw.astype(np.uint16)),
                             ("mask", frame.mask)):
                write_image(tmp / sub / names[i], img)
            if progress is not None:
                progress(i + 1, len(seq))
        header = f"# {seq.name}: jaxvo.synth.scenes, seed {seq.seed}\n"
        for sub, what in (("rgb", "colour, 8-bit BGR PNG"),
                          ("depth", f"depth, 16-bit PNG, {scale:g} per metre, 0 = no reading"),
                          ("mask", "moving-object id, 8-bit PNG, 0 = static")):
            lines = [f"{t:.6f} {sub}/{n}" for t, n in zip(seq.timestamps, names)]
            write_text(tmp / f"{sub}.txt",
                       header + f"# {what}\n# timestamp filename\n" + "\n".join(lines) + "\n")
        lines = [f"{t:.6f} rgb/{n} {t:.6f} depth/{n}" for t, n in zip(seq.timestamps, names)]
        write_text(tmp / "associations.txt",
                   header + "# timestamp rgb timestamp depth\n" + "\n".join(lines) + "\n")
        write_trajectory(tmp / "groundtruth.txt", seq.groundtruth,
                         comment=f"{seq.name}: exact camera poses T_w_c (synthetic ground truth)")
        lines = [header.rstrip(), "# moving-object poses T_w_o",
                 "# timestamp object_id tx ty tz qx qy qz qw"]
        for k, traj in seq.object_trajectories.items():
            q = rotation_to_quat(traj.poses[:, :3, :3])
            for t, T, qi in zip(traj.timestamps, traj.poses, q):
                lines.append(f"{t:.6f} {k} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *qi)))
        write_text(tmp / "objects.txt", "\n".join(lines) + "\n")
        what = "pinhole intrinsics" if seq.intrinsics.distortion is None else "intrinsics and lens distortion"
        write_camera_file(tmp / "camera.txt", seq.intrinsics,
                          comment=f"{seq.name}: {what}, pixels; depth units per metre")
    return out


__all__ = [
    "DEFAULT_FPS",
    "DEFAULT_FRAMES",
    "DEPTH_SCALE",
    "SCENARIOS",
    "ObjectSpec",
    "Scenario",
    "SensorOptions",
    "SyntheticSequence",
    "composite_sequence",
    "make_atlas",
    "make_sequence",
    "write_sequence",
]
