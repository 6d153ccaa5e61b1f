"""A study's sequences (host side): their frames, their flow and its cache.

Every sequence's grid flow (with ``Config.keyframes``, also its keyframe flow) is computed
once (:func:`sequence_data`) and cached on disk as a ``.npz`` keyed by the sequence's
identity (its frames' files included), the flow's options (``Config.flow``) and
:data:`FLOW_FORMAT` (:func:`sequence_key`), beside what its runs are scored against: the kept frames'
timestamps, the start pose, the ground truth and the moving masks at the grid.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxvo.config import Config, FlowOptions, grid_shape
from jaxvo.errors import InputError
from jaxvo.host.readers.io import groundtruth_of_frames
from jaxvo.host.writers.outputs import OutputFile
from jaxvo.study.spec import SequenceSpec
from jaxvo.trajectory import Trajectory


class SequenceData(NamedTuple):
    """What a study needs of one sequence: its flow and what its runs are scored against."""

    label: str
    flows: Any  # GridFlow of numpy arrays, stacked over T pairs
    keyframes: Any  # with Config.keyframes: KeyframeFlow of numpy arrays stacked as flows; else None
    T_w_c0: np.ndarray  # (4, 4) float64 first camera pose (ground truth's, else identity)
    timestamps: np.ndarray  # (T + 1,) float64 seconds
    groundtruth: Trajectory | None  # camera-to-world ground truth, None without
    truth: np.ndarray | None  # (T, n) bool moving ground truth at the grid, None without masks
    height: int
    width: int


def open_study_sequence(s: SequenceSpec):
    """The sequence ``s`` names (frames are read or rendered lazily, when flow asks)."""
    from jaxvo.host.readers.io import open_sequence
    from jaxvo.synth.scenes import DEFAULT_FRAMES, composite_sequence, make_sequence

    if s.path is None:
        frames = DEFAULT_FRAMES if s.frames is None else s.frames
        seq = make_sequence(s.scene, frames=(frames - 1) * s.step + 1, seed=s.seed)
    elif s.scene is not None:
        seq = composite_sequence(open_sequence(s.path, camera=s.camera), s.scene, seed=s.seed,
                                 frames=None if s.frames is None else (s.frames - 1) * s.step + 1)
    else:
        seq = open_sequence(s.path, camera=s.camera)
    return _Subset(seq, s.label, frames=s.frames, step=s.step)


class _Subset:
    """Every ``step``-th of the first frames of a sequence, lazily; it keeps each frame's
    moving ground truth at the grid as the flow reads the frames (rendering a synthetic
    frame is slow, so it is read once)."""

    def __init__(self, seq, label: str, *, frames: int | None, step: int):
        idx = np.arange(0, len(seq), step)
        self._seq, self._idx = seq, idx if frames is None else idx[:frames]
        self.name, self.intrinsics = label, seq.intrinsics
        self.height, self.width = seq.height, seq.width
        self.timestamps = np.asarray(seq.timestamps, np.float64)[self._idx]
        self.groundtruth = groundtruth_of_frames(seq, self._idx)
        self.cell: int | None = None
        self.truth: dict[int, np.ndarray | None] = {}

    def __len__(self) -> int:
        return len(self._idx)

    def __getitem__(self, i: int):
        from jaxvo.evaluation.scores import moving_at_grid

        frame = self._seq[int(self._idx[i])]
        if self.cell is not None:
            self.truth[i] = None if frame.mask is None else moving_at_grid(frame.mask, self.cell)
        return frame


def flow_fields() -> tuple[str, ...]:
    """The ``Config`` fields the grid flow reads (those its cache is keyed by): the fields
    of :class:`~jaxvo.config.FlowOptions`, the only settings the flow's tracker holds."""
    return tuple(f.name for f in dataclasses.fields(FlowOptions))


# The version of what the flow cache holds. Bump it by hand whenever what the flow computes
# changes (the tracker, its checks, the depth refinement, the rendering of a synthetic scene)
# or what sequence_data stores beside it: a cache written under another version is then
# not read. A change to comments or layout leaves it, and the cache, as they are.
FLOW_FORMAT = 1


def sequence_identity(s: SequenceSpec) -> dict:
    """What makes a sequence's frames the ones they are: its spec (but the label), a
    synthetic scene's scenario by value and, for one read from files, the files it reads: a folder's lists by content and the camera,
    ground truth and images of the frames used by size and modification time (a depth
    image rewritten under the same lists is another sequence); a bag's files by size and
    modification time (too large to hash)."""
    from jaxvo.host.readers.rosbag import is_bag

    ident: dict = s._asdict()
    ident.pop("label")
    if s.scene is not None:  # what the scene is made of (its objects, paths, sensor), by value
        from jaxvo.synth.scenario import SCENARIOS

        ident["scenario"] = repr(SCENARIOS[s.scene])
    if s.path is None:  # rendered from its scenario, seed and length alone
        return ident
    path = Path(s.path)
    if is_bag(path):
        files = [path] if path.is_file() else sorted(path.iterdir())
    else:
        from jaxvo.host.readers.io import open_sequence

        lists = sorted(path.glob("*.txt"))
        ident["lists"] = hashlib.sha256(b"".join(p.read_bytes() for p in lists)).hexdigest()
        used = None if s.frames is None else (s.frames - 1) * s.step + 1
        files = [f for f in open_sequence(path, camera=s.camera).files(used) if f.is_file()]
    stats = [(f, f.stat()) for f in files]
    ident["files"] = [(str(f.relative_to(path)) if f != path else f.name, st.st_size,
                       st.st_mtime_ns) for f, st in stats]
    return ident


@functools.cache
def sequence_key(s: SequenceSpec, cfg: Config) -> str:
    """The flow cache's key of a sequence under ``cfg``: the sequence's identity
    (:func:`sequence_identity`), the flow's options (``Config.flow``, the only settings the
    flow reads) and :data:`FLOW_FORMAT`; the source text of the code is no part of it."""
    ident = {"sequence": sequence_identity(s), "flow": dataclasses.asdict(cfg.flow),
             "format": FLOW_FORMAT}
    blob = json.dumps(ident, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


# the keyframe flow's fields in a cached .npz, beside the pair flow's
KF_PREFIX = "kf_"


def sequence_data(s: SequenceSpec, cfg: Config, cache_dir: str | Path | None, *,
                  progress: Callable[[int, int], None] | None = None) -> tuple[SequenceData, bool]:
    """The flow and scoring data of ``s`` under ``cfg``, from the cache when it is there.

    Returns:
      ``(data, cached)``: ``cached`` says whether it came from ``cache_dir``.
    """
    from jaxvo.core.inputs import GridFlow, KeyframeFlow
    from jaxvo.host.frontend.flow import sequence_flows
    from jaxvo.odometry import choose_start_pose

    path = None
    if cache_dir is not None:
        path = Path(cache_dir) / f"{_safe(s.label)}-{sequence_key(s, cfg)}.npz"
        if path.is_file():
            z = np.load(path)
            gt = Trajectory(z["gt_t"], z["gt_poses"]) if "gt_t" in z else None
            kf = (KeyframeFlow(*(z[KF_PREFIX + f] for f in KeyframeFlow._fields))
                  if cfg.keyframes else None)
            return SequenceData(s.label, GridFlow(*(z[f] for f in GridFlow._fields)), kf,
                                z["T_w_c0"], z["timestamps"], gt,
                                z.get("truth"), int(z["height"]),
                                int(z["width"])), True
    seq = open_study_sequence(s)
    if len(seq) < 2:
        raise InputError(f"sequence {s.label!r} has {len(seq)} frame(s); odometry needs 2")
    seq.cell = cfg.cell
    grid_shape(seq.height, seq.width, cfg.cell)  # an impossible cell fails here, in one line
    # frames that cannot be used are dropped and the next pairs with the last good one, as
    # in run_sequence: the kept frames' timestamps, start pose and masks go with the pairs
    chain = sequence_flows(seq, cfg, progress=progress)
    if len(chain.frames) < 2:
        reasons = "; ".join(sorted(set(chain.dropped.values())))
        raise InputError(f"sequence {s.label!r}: fewer than 2 frames can be used "
                         f"({len(chain.dropped)} dropped: {reasons})")
    kept = np.asarray(chain.frames)
    stamps = np.asarray(seq.timestamps, np.float64)[kept]
    gt = seq.groundtruth
    masks = [seq.truth.get(int(k)) for k in kept[:-1]]  # pair k is anchored on its first image
    truth = None if any(m is None for m in masks) else np.stack(masks)
    T_w_c0, _ = choose_start_pose("gt", gt, stamps[0])
    data = SequenceData(s.label, chain.flows, chain.keyframes, T_w_c0, stamps, gt, truth,
                        seq.height, seq.width)
    if path is not None:
        arrays = {**chain.flows._asdict(), "T_w_c0": data.T_w_c0, "timestamps": data.timestamps,
                  "height": data.height, "width": data.width}
        if chain.keyframes is not None:
            arrays.update({KF_PREFIX + k: v for k, v in chain.keyframes._asdict().items()})
        if gt is not None:
            arrays.update(gt_t=gt.timestamps, gt_poses=gt.poses)
        if truth is not None:
            arrays["truth"] = truth
        path.parent.mkdir(parents=True, exist_ok=True)
        with OutputFile(path) as fh:  # whole or absent, also with several writers
            np.savez(fh.handle, **arrays)
    return data, False


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)


def sequence_pairs(s: SequenceSpec) -> int:
    """Frame pairs of a sequence (for the progress total), without reading its frames."""
    if s.path is None:
        from jaxvo.synth.scenes import DEFAULT_FRAMES

        return (DEFAULT_FRAMES if s.frames is None else s.frames) - 1
    seq = open_study_sequence(s)
    return len(seq) - 1
