"""The memory a run will need, estimated before any work, and the refusal of one that
cannot fit (host side).

A setting such as ``--hypotheses 100000`` used to compile for 20 s
and then die with an out-of-memory traceback; a study scene of 10^9 frames or ``jaxvo
synth --frames 1000000000`` likewise. :func:`run_bytes` estimates the peak from the
settings alone, and :func:`check_memory` refuses, in one line giving both numbers, what the
machine does not have.
"""

from __future__ import annotations

from jaxvo.errors import InputError

# Calibration (docs/report/host_decisions.md has the measurements). The per-frame step's buffers,
# from XLA's buffer assignment of jit_step (temporaries + arguments + outputs,
# `compiled.memory_analysis()`), at several hypothesis counts H and grid cells, are fit by
# per-point, hypothesis x point and H^2 terms (the hypotheses' pairwise inlier overlaps and
# DBSCAN distances are (H, H)). The process's peak resident memory grows faster than the
# buffers (compiling), so the squared term below is that peak's: the estimate is of what
# the process takes, and it held on a size it was not fit to.
_STEP_PER_POINT = 1.65e3  # bytes per grid point (flow, state, per-point stages)
_STEP_PER_HYP_POINT = 2.6  # bytes per hypothesis and grid point (inlier sets)
_STEP_PER_HYP2 = 16.0  # bytes per hypothesis squared (overlaps, distances)
# The keyframe window (cfg.keyframes): each point of each of K keyframes is read by every
# later one and the refinement's Jacobian blocks are per reading, so the step's buffers grow
# as K^2 m (m points a keyframe). Measured on jit_step at several K
# (docs/report/host_decisions.md), times the process's peak over the buffers, as above.
_STEP_PER_KF2_POINT = 560.0
# Per frame pair kept for a whole-sequence scan or a study: its flow (flow_bytes: the grid
# flow, and with keyframes the keyframe flow, as their types hold them) and the stacked
# step outputs (about 23 bytes a point: identifiers, labels, moving and static flags,
# evidence).
_OUTPUT_PER_POINT = 23.0
# Host memory per frame of a synthetic sequence (its camera and object trajectories and
# the file names written): measured 855 bytes a frame (static, no object) and 990 (one
# object) over 100,000 frames, peak resident.
SYNTH_BYTES_PER_FRAME = 860.0
SYNTH_BYTES_PER_OBJECT_FRAME = 135.0
# A frame held in memory (jaxvo.host.readers.io.InMemorySequence, jaxvo demo): BGR uint8, depth float32
# metres and a uint8 mask, bytes per pixel.
FRAME_BYTES_PER_PIXEL = 8
# What a jaxvo process holds before its own arrays: Python, JAX, XLA's compiler and
# OpenCV: the peak resident of `jaxvo run` on 4 synthetic frames with the default
# settings, compiling its step (no compile cache), rounded up (docs/report/host_decisions.md).
PROCESS_BYTES = 0.9e9


def run_bytes(cfg, *, height: int, width: int, frames: int = 0, configs: int = 1,
              host_bytes: float = 0.0) -> float:
    """Peak memory of a run, bytes (estimate from the settings alone).

    Args:
      cfg: the :class:`~jaxvo.config.Config` (cell, ``num_hypotheses``, the keyframe window).
      height, width: the image size, pixels.
      frames: frames whose flow (with keyframes, the keyframe flow too: :func:`flow_bytes`)
        and step outputs are held at once (a whole-sequence scan, a study); 0 for the
        streaming ``jaxvo run``, which holds none.
      configs: configurations run side by side (a study's batch per device).
      host_bytes: more bytes held on the host (a synthetic scene's trajectories,
        :data:`SYNTH_BYTES_PER_FRAME` a frame; frames kept in memory).
    Returns:
      bytes, float (it may exceed any machine's memory: 1.6e11 for ``--hypotheses 100000``).
    """
    n = (height // cfg.cell) * (width // cfg.cell)
    H = float(cfg.num_hypotheses)
    step = _STEP_PER_POINT * n + _STEP_PER_HYP_POINT * H * n + _STEP_PER_HYP2 * H * H
    if cfg.keyframes:
        rows, cols = height // cfg.cell, width // cfg.cell
        s = cfg.keyframe_stride
        m = -(-rows // s) * -(-cols // s)
        step += _STEP_PER_KF2_POINT * float(cfg.keyframe_window) ** 2 * m
    per_frame = flow_bytes(cfg, n) + configs * _OUTPUT_PER_POINT * n
    return PROCESS_BYTES + configs * step + float(frames) * per_frame + float(host_bytes)


def flow_bytes(cfg, n: int) -> float:
    """Bytes of one frame pair's flow as a whole-sequence scan or a study holds it: its
    :class:`~jaxvo.core.inputs.GridFlow` and, with ``cfg.keyframes``, its
    :class:`~jaxvo.core.inputs.KeyframeFlow` (whose window's points grow it with
    ``cfg.keyframe_window``), of ``n`` grid points: the sizes of their fields."""
    import numpy as np

    from jaxvo.core.inputs import invalid_flow, invalid_keyframe_flow

    held = [invalid_flow(np.zeros((n, 2), np.float32))]
    if cfg.keyframes:
        held.append(invalid_keyframe_flow(n, cfg.keyframe_window))
    return float(sum(np.asarray(field).nbytes for flow in held for field in flow))


def available_bytes() -> float:
    """Memory this process may still take, bytes: the system's available memory
    (``MemAvailable``), within the control group's limit where one is set; infinity where
    neither can be read."""
    avail = float("inf")
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024.0
    except OSError:
        pass
    try:  # a control group's limit (cgroup v2), less what the group already uses
        from pathlib import Path

        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        if limit != "max":
            used = float(Path("/sys/fs/cgroup/memory.current").read_text())
            avail = min(avail, float(limit) - used)
    except (OSError, ValueError):
        pass
    return avail


def check_memory(need: float, *, what: str, available: float | None = None) -> None:
    """Refuse, before any work, a run whose estimate exceeds the memory available.

    Args:
      need: bytes (:func:`run_bytes`).
      what: the run, for the message (its options).
      available: bytes the machine has (default :func:`available_bytes`).
    Raises:
      InputError: one line with both numbers.
    """
    have = available_bytes() if available is None else available
    if need > have:
        raise InputError(f"{what} needs about {_size(need)} of memory; this machine has "
                         f"{_size(have)} available")


def _size(b: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if b >= size:
            return f"{b / size:.3g} {unit}"
    return f"{b:.0f} bytes"

