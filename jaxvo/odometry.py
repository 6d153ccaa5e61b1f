"""Running the odometry from the host: live frame by frame, or over a recorded sequence.

* :class:`Odometry` is fed ``(bgr, depth, timestamp)`` one frame at a time, as from a live
  camera, and answers with the pose and labels of that frame. The per-frame step is
  compiled once (the first frame pays for it).
* :func:`run_sequence` computes the grid flow of a whole recorded sequence on the host, then
  runs every frame in one jit-compiled ``lax.scan``.

Both use the same per-frame step and the same per-frame PRNG keys (folded from the seed
and the frame index), so they give the same trajectory for the same seed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.camera import Intrinsics
from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.flow import GridFlowTracker, flows_for_sequence
from jaxvo.io import Trajectory, first_pose
from jaxvo.pipeline import StepOutput, init_pipeline, jit_step, run_scan
from jaxvo.status import Status


class FrameResult(NamedTuple):
    """What the streaming odometry returns for one frame (host numpy)."""

    index: int
    timestamp: float
    T_w_c: np.ndarray  # (4, 4) float64 camera-to-world
    status: Status  # OK, or why this frame's motion was skipped (pose carried)
    ids: np.ndarray  # (n,) int32 temporal identifiers of the previous image's grid cells
    static: np.ndarray  # (n,) bool grid points used for the ego-motion
    output: StepOutput | None  # every per-step output (None on the first frame)


class Odometry:
    """Frame-by-frame odometry for a live RGB-D stream.

    The per-frame step runs on ``device``, by default the CPU (also where an accelerator
    is present: see ``__init__``).

    Example::

        odo = Odometry(jaxvo.preset("tum_fr3"))
        for bgr, depth, t in camera:
            r = odo.process(bgr, depth, t)
            print(r.T_w_c[:3, 3], r.status.reason)
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        *,
        cfg: Config = Config(),
        params: Params | None = None,
        seed: int = 0,
        T_w_c0: np.ndarray | None = None,
        device: jax.Device | str | None = None,
    ):
        self.intrinsics = intrinsics
        self.cfg = cfg
        # One frame's step is a long chain of small dependent operations, bound by launch
        # latency on an accelerator: on an H100 it took 19-25 ms a frame against 9 ms on 2
        # CPU cores (docs/report/pipeline_h100.md). So the step runs on the CPU unless told
        # otherwise; the state, parameters and key live there, and the step follows them.
        self.device = _device(device)
        self.params = jax.device_put(
            params_as_arrays(params if params is not None else Params()), self.device
        )
        self.key = jax.device_put(jax.random.key(seed), self.device)
        self._T_w_c0 = np.eye(4) if T_w_c0 is None else np.asarray(T_w_c0, np.float64)
        self._tracker: GridFlowTracker | None = None
        self._state = None
        self._grid = None
        self._index = 0
        self._pending = None  # a frame dispatched by submit() whose result is not out yet
        self.timestamps: list[float] = []
        self.poses: list[np.ndarray] = []

    @property
    def trajectory(self) -> Trajectory:
        """Every pose so far (camera-to-world)."""
        return Trajectory(np.asarray(self.timestamps, np.float64), np.asarray(self.poses))

    def process(self, bgr: np.ndarray, depth: np.ndarray, timestamp: float | None = None):
        """Feed one frame: ``bgr`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres (0 = none).

        Returns this frame's :class:`FrameResult` (a result still pending from
        :meth:`submit` is completed first)."""
        self.flush()
        return self._finish(self._dispatch(bgr, depth, timestamp))

    def submit(self, bgr: np.ndarray, depth: np.ndarray, timestamp: float | None = None):
        """Pipelined :meth:`process`: feed one frame, get the result of the frame before it.

        The device step of this frame is left running while the caller fetches the next
        frame and the next call computes its flow on the host, so a frame costs about the
        larger of the two instead of their sum (``bench/bench_pipeline.py`` on 2 cores: medians
        of 7.4-8.8 against 10.1-14.9 ms per frame over several runs); each result arrives
        one frame later. Call :meth:`flush` after the last
        frame for its result. Poses, labels and statuses are those of :meth:`process`.

        Returns:
          The previous frame's :class:`FrameResult`, or None for the first frame.
        """
        previous, self._pending = self._pending, self._dispatch(bgr, depth, timestamp)
        return None if previous is None else self._finish(previous)

    def flush(self):
        """The result of the frame last given to :meth:`submit`, or None if none is pending."""
        previous, self._pending = self._pending, None
        return None if previous is None else self._finish(previous)

    def _dispatch(self, bgr, depth, timestamp):
        """Host flow of this frame's pair and the (asynchronous) device step."""
        t = float(self._index) / 30.0 if timestamp is None else float(timestamp)
        if self._tracker is None:  # the first frame sets the image size and the grid
            if np.ndim(depth) != 2:
                from jaxvo.errors import InputError

                raise InputError("the first frame has no (H, W) depth image: cannot set the grid")
            h, w = np.shape(depth)
            self._tracker = GridFlowTracker(self.intrinsics, self.cfg, height=h, width=w)
            self._grid = self._tracker.grid
            self._state = jax.device_put(
                init_pipeline(cfg=self.cfg, grid=self._grid, T_w_c0=self._T_w_c0), self.device
            )
        flow = self._tracker.push(bgr, depth)
        index = self._index
        self._index += 1
        if flow is None:  # no earlier good frame to compare with: the pose stays
            return index, t, self._state.T_w_c, None
        self._state, out = jit_step(
            self._state, flow, self.key, self.params, cfg=self.cfg, grid=self._grid
        )
        return index, t, out.T_w_c, out

    def _finish(self, pending) -> FrameResult:
        """Wait for a dispatched frame, record its pose and return its result."""
        index, t, T, out = pending
        T = np.asarray(T, np.float64)
        self.timestamps.append(t)
        self.poses.append(T)
        if out is None:
            n = self._grid[0] * self._grid[1]
            return FrameResult(index, t, T, Status.OK, np.zeros(n, np.int32), np.zeros(n, bool),
                               None)
        out = jax.tree.map(np.asarray, out)
        return FrameResult(index, t, T, Status(int(out.status)), out.ids, out.static, out)


def _device(device) -> jax.Device:
    """The device the streaming step runs on: the CPU for None (JAX's default device if
    the CPU backend is switched off), the first device of a platform named by a string
    ("cpu", "gpu"), or the device given."""
    if device is None:
        try:
            return jax.devices("cpu")[0]
        except RuntimeError:
            return jax.devices()[0]
    if isinstance(device, str):
        try:
            return jax.devices(device)[0]
        except RuntimeError:
            available = sorted({d.platform for d in jax.devices()})
            raise ValueError(
                f"no {device!r} device here; available: {', '.join(available)}"
            ) from None
    return device


class SequenceResult(NamedTuple):
    """Everything a run over a recorded sequence produces (host numpy)."""

    trajectory: Trajectory  # one pose per frame, camera-to-world
    outputs: StepOutput  # every field stacked over the N - 1 frame pairs
    flows: object  # the stacked GridFlow the scan consumed
    flow_seconds: float  # host time computing the grid flow
    scan_seconds: float  # device time of the scan, compile included
    grid: tuple[int, int]


def run_sequence(
    seq,
    *,
    cfg: Config = Config(),
    params: Params | None = None,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> SequenceResult:
    """Flow for every frame pair on the host, then one jit-compiled ``lax.scan``.

    The first pose is the sequence's first ground-truth pose when it has one (so estimated
    and true trajectories share a frame without alignment), else the identity.
    """
    if len(seq) < 2:
        from jaxvo.errors import InputError

        raise InputError(f"sequence {seq.name!r} has {len(seq)} frame(s); odometry needs 2 or more")
    grid = grid_shape(seq.height, seq.width, cfg.cell)
    T0 = first_pose(seq)

    t0 = time.perf_counter()
    flows = flows_for_sequence(seq, cfg, progress=progress)
    flow_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    p = params_as_arrays(params if params is not None else Params())
    _, outs = run_scan(flows, jax.random.key(seed), p, jnp.asarray(T0, jnp.float32),
                       cfg=cfg, grid=grid)
    outs = jax.tree.map(np.asarray, jax.block_until_ready(outs))
    scan_s = time.perf_counter() - t0

    poses = np.concatenate([np.asarray(T0, np.float64)[None], outs.T_w_c.astype(np.float64)])
    traj = Trajectory(np.asarray(seq.timestamps, np.float64), poses)
    return SequenceResult(traj, outs, flows, flow_s, scan_s, grid)
