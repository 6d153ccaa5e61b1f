"""Running the odometry from the host: live frame by frame, or over a recorded sequence.

* :class:`Odometry` is fed ``(bgr, depth, timestamp)`` one frame at a time, as from a live
  camera, and answers with the pose and labels of that frame. The per-frame step is
  compiled once (the first frame pays for it).
* :func:`run_sequence` computes the grid flow of a whole recorded sequence on the host, then
  runs every frame in one jit-compiled ``lax.scan``.

Both drop the frames that cannot be used and pair the next frame with the last good one
(:class:`jaxvo.host.frontend.flow.FrameChain`), and both use the same per-frame step and the same PRNG
keys (folded from the seed and the index of the frame pair stepped), so they give the same
trajectory for the same seed.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxvo.config import Config, Params, check_config, check_params, grid_shape, params_as_arrays
from jaxvo.core.inputs import GridFlow, KeyframeFlow
from jaxvo.core.pipeline import (
    StepOutput,
    committed_poses,
    jit_init,
    jit_step,
    revised_poses,
    run_scan,
)
from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics, as_intrinsics, check_intrinsics, depth_metres
from jaxvo.host.frontend.flow import (
    MAX_DROPPED,
    FrameChain,
    GridFlowTracker,
    min_valid_flow,
    sequence_flows,
)
from jaxvo.host.readers.io import DepthScaleWarning, check_depth_scale
from jaxvo.host.services.compile_cache import default_compile_cache, exported_program
from jaxvo.host.services.memory import check_memory, run_bytes
from jaxvo.status import Status
from jaxvo.trajectory import Trajectory, pose_at, timestamp_seconds


class FrameResult(NamedTuple):
    """What the streaming odometry returns for one frame (host numpy)."""

    index: int  # the frame's place in the stream, 0 for the first frame given
    timestamp: float
    T_w_c: np.ndarray  # (4, 4) float64 camera-to-world (a dropped frame: the last kept pose)
    status: Status  # OK, or why this frame's motion was skipped (BAD_INPUT: dropped)
    ids: np.ndarray  # (n,) int32 temporal identifiers of the previous image's grid cells
    static: np.ndarray  # (n,) bool grid points used for the ego-motion
    output: StepOutput | None  # every per-step output (None on the first or a dropped frame)
    dropped: str | None = None  # why the frame was dropped (it has no pose), None if kept
    # (k, 4, 4) float64 the k poses before this one, revised: the background switched to
    # another motion in this pair (StepOutput.switched), and the camera's path so far is
    # redrawn along that motion's chain, or the test over the keyframe switched
    # (StepOutput.separated), and the poses since the keyframe are redrawn as the other
    # motion had them (Odometry.trajectory holds them); None: none
    revised: np.ndarray | None = None


class _Dispatched(NamedTuple):
    """A frame handed to the device (:meth:`Odometry._dispatch`), its result not yet read."""

    index: int  # the frame's index among those given
    t: float  # its time, seconds
    T_w_c: Any  # (4, 4) its pose, on the device until read
    out: Any  # the step's StepOutput, on the device; None: no pair (first or dropped frame)
    dropped: str | None  # why the frame was dropped, None: kept
    images: tuple | None  # (bgr, depth) for the logger, None: no logger attached


class Odometry:
    """Frame-by-frame odometry for a live RGB-D stream.

    The per-frame step runs on ``device``, by default the CPU (also where an accelerator
    is present: see ``__init__``).

    A frame that cannot be used (its size differs from the first frame's, or its flow with
    the last good frame has too few valid vectors: a black, saturated or noise image) is
    dropped: it gets no pose (``FrameResult.dropped`` says why; ``T_w_c`` repeats the last
    kept pose) and is left out of :attr:`trajectory`, and the next frame pairs with the last
    good one (:class:`jaxvo.host.frontend.flow.FrameChain`).

    Example::

        odo = Odometry("tum_fr3")          # a preset: depth_scale 5000 per metre
        for bgr, depth, t in camera:   # depth: uint16 raw units or float32 metres
            r = odo.process(bgr, depth, t)
            print(r.T_w_c[:3, 3], r.status.reason)

    The first frame's depth is checked against what RGB-D sensors see
    (:func:`jaxvo.host.readers.io.check_depth_scale`): a median depth no sensor reads (float depth in
    millimetres or raw units, a wrong depth scale) raises a ``ValueError``, an unusual one
    gives a :class:`jaxvo.host.readers.io.DepthScaleWarning` (also kept in :attr:`warnings`).

    Args:
      intrinsics: the (depth-registered) camera, pixels, as an :class:`Intrinsics`, a
        preset name, ``(fx, fy, cx, cy[, depth_scale])``, a dict of those keys or a 3x3
        camera matrix (depth_scale 5000); its ``depth_scale`` converts ``uint16`` depth to
        metres.
      cfg: settings, a Config or a mapping of its fields (the host's flow reads
        ``cfg.flow``, the compiled step ``cfg.step``).
      params: numeric settings (default :class:`Params`).
      seed: PRNG seed of the hypothesis sampling.
      T_w_c0: (4, 4) camera-to-world pose of the first frame; None: the identity (the
        trajectory then starts at the origin of its own frame).
      device: where the per-frame step runs (see ``__init__``).
      max_dropped: most frames dropped in a row (:class:`jaxvo.host.frontend.flow.FrameChain`).
      logger: gets every frame's result with its images (:meth:`attach`), e.g. a
        :class:`jaxvo.host.writers.recording.RerunLogger`; None: nothing is logged.
      checked: the caller has checked the intrinsics and ``cfg`` against the image size,
        the memory the run needs and the first frame's depth, as ``jaxvo run`` does before
        JAX loads (:func:`jaxvo.run.prepare_run`): they are not checked again.
    Raises:
      ValueError: intrinsics of another type or that no camera has, settings no run can
        use, or a ``T_w_c0`` that is not a finite rigid transform.
    """

    def __init__(
        self,
        intrinsics: Intrinsics | tuple | dict | np.ndarray | str,
        *,
        cfg: Config | Mapping[str, object] = Config(),
        params: Params | None = None,
        seed: int = 0,
        T_w_c0: np.ndarray | None = None,
        device: jax.Device | str | None = None,
        max_dropped: int = MAX_DROPPED,
        logger=None,
        checked: bool = False,
    ):
        default_compile_cache()  # before the first compile: the commands' cache, from Python
        intrinsics = as_intrinsics(intrinsics)
        cfg = as_config(cfg)
        if not checked:
            check_intrinsics(intrinsics, where="intrinsics")
            check_config(cfg)
        self._checked = checked
        self.intrinsics = intrinsics
        self.warnings: list[str] = []  # one-line notes on the input (the depth scale)
        self.cfg = cfg
        self._step_options = cfg.step  # the step's static argument: no flow setting in it
        # One frame's step is a long chain of small dependent operations, bound by launch
        # latency on an accelerator: on an H100 it took longer a frame than on 2 CPU cores
        # (docs/report/pipeline_h100.md). So the step runs on the CPU unless told
        # otherwise; the state, parameters and key live there, and the step follows them.
        self.device = _device(device)
        params = params if params is not None else Params()
        check_params(params)
        self._min_valid = min_valid_flow(cfg, params=params)
        self._max_dropped = max_dropped
        self.params = params_as_arrays(params, self.device)
        self.key = jax.device_put(jax.random.key(seed), self.device)
        self._T_w_c0 = np.eye(4) if T_w_c0 is None else check_pose(T_w_c0, name="T_w_c0")
        self._chain: FrameChain | None = None
        self._state = None
        self._grid = None
        self._index = 0
        self._last_t: float | None = None
        self._pending = None  # a frame dispatched by submit() whose result is not out yet
        self._step = None  # the compiled step, from the first frame pair on
        self.timestamps: list[float] = []
        self.poses: list[np.ndarray] = []
        # every pair's pose chains, renumbering and identifiers given anew
        # (StepOutput.chains, .permutation, .new_ids): what a switch of the background
        # revises the earlier poses from
        self._chains: list[np.ndarray] = []
        self._permutations: list[np.ndarray] = []
        self._new_ids: list[np.ndarray] = []
        # the pairs tested against the latest keyframe (jaxvo.core.separation): its number
        # and each pair's pose under the other motion
        self._tested_keyframe, self._other_poses = -1, []
        self.logger = None
        if logger is not None:
            self.attach(logger)

    def attach(self, logger) -> None:
        """Give every frame's result from now on to ``logger``: an object with
        ``setup(intrinsics, cell)`` (called here) and ``log_frame(result, bgr, depth)``
        (called as each result comes out, with the frame's colour image and its depth in
        float32 metres), such as :class:`jaxvo.host.writers.recording.RerunLogger`.

        Raises:
          ValueError: ``logger`` lacks those methods (a file name: give
            ``RerunLogger(save=...)``).
        """
        if not (callable(getattr(logger, "setup", None))
                and callable(getattr(logger, "log_frame", None))):
            hint = (f"; for a recording, logger=RerunLogger(save={str(logger)!r}) (from "
                    "jaxvo.host.writers.recording)" if isinstance(logger, str | Path) else "")
            raise ValueError("logger must have setup(intrinsics, cell) and log_frame(result, "  # noqa: TRY004 (the API says ValueError for any bad input)
                             "bgr, depth), as jaxvo.host.writers.recording.RerunLogger does; got "
                             f"{type(logger).__name__}" + hint)
        logger.setup(self.intrinsics, self.cfg.cell)
        self.logger = logger

    @property
    def trajectory(self) -> Trajectory:
        """Every pose so far (camera-to-world), dropped frames left out: each as it was
        when its frame was processed, or as a later switch of the background revised it
        (:attr:`FrameResult.revised`)."""
        return Trajectory(np.asarray(self.timestamps, np.float64),
                          np.asarray(self.poses).reshape(-1, 4, 4))

    def process(self, bgr: np.ndarray, depth: np.ndarray, timestamp: float | None = None):
        """Feed one frame and get its result.

        Args:
          bgr: (H, W, 3) uint8 colour image in OpenCV's BGR order (or (H, W) uint8 grey).
          depth: (H, W) depth registered to the colour image: ``uint16`` raw sensor units
            (divided by ``intrinsics.depth_scale``, as Open3D does; what ``cv2.imread(path,
            cv2.IMREAD_UNCHANGED)`` gives) or float metres; 0 (or NaN) = no reading.
          timestamp: seconds, later than the previous frame's (a float, or what numpy and
            ROS hold: ``np.datetime64``, an int of nanoseconds as ROS stamps count them, a
            ROS ``Time`` / header stamp; see :func:`timestamp_seconds`); None: the frame's
            index / 30.
        Returns:
          this frame's :class:`FrameResult` (a result still pending from :meth:`submit` is
          completed first).
        Raises:
          ValueError: a colour or depth image of the wrong type or shape, images of
            different sizes, a timestamp that is not finite or does not increase; on the
            first frame, depth no sensor reads or settings that need more memory than the
            machine has (:mod:`jaxvo.host.services.memory`).
        """
        self.flush()
        return self._finish(self._dispatch(bgr, depth, timestamp))

    def submit(self, bgr: np.ndarray, depth: np.ndarray, timestamp: float | None = None):
        """Pipelined :meth:`process`: feed one frame, get the result of the frame before it.

        The device step of this frame is left running while the caller fetches the next
        frame and the next call computes its flow on the host, so a frame costs about the
        larger of the two instead of their sum (``bench/bench_pipeline.py``,
        ``docs/report/host_decisions.md``); each result arrives
        one frame later. Call :meth:`flush` after the last
        frame for its result. Poses, labels and statuses are those of :meth:`process`, and
        so are the arguments and errors.

        Returns:
          The previous frame's :class:`FrameResult`, or None for the first frame.
        """
        previous, self._pending = self._pending, self._dispatch(bgr, depth, timestamp)
        return None if previous is None else self._finish(previous)

    def flush(self):
        """The result of the frame last given to :meth:`submit`, or None if none is pending."""
        previous, self._pending = self._pending, None
        return None if previous is None else self._finish(previous)

    def _dispatch(self, bgr, depth, timestamp) -> _Dispatched:
        """Host flow of this frame's pair and the (asynchronous) device step."""
        t = float(self._index) / 30.0 if timestamp is None else timestamp_seconds(timestamp)
        if self._last_t is not None and t <= self._last_t:
            raise ValueError(
                f"timestamp {t:.6f} s does not follow the previous frame's {self._last_t:.6f} s"
            )
        raw_units = getattr(depth, "dtype", None) == np.uint16
        bgr, depth = _frame_arrays(bgr, depth, self.intrinsics)
        if self._chain is None:  # the first frame sets the image size and the grid
            h, w = depth.shape
            if not self._checked:
                self._check_first(depth, raw_units)
            tracker = GridFlowTracker(self.intrinsics, self.cfg, height=h, width=w)
            self._chain = FrameChain(tracker, min_valid=self._min_valid,
                                     max_dropped=self._max_dropped, keyframes=self.cfg.keyframes)
            self._grid = tracker.grid
            self._state = jax.device_put(
                jit_init(cfg=self._step_options, grid=self._grid, T_w_c0=self._T_w_c0,
                         params=self.params), self.device
            )
        self._last_t = t
        flow, dropped = self._chain.push(bgr, depth)
        index = self._index
        self._index += 1
        images = (bgr, depth) if self.logger is not None else None
        if flow is None:  # the chain's first frame, or a dropped one: the pose stays
            return _Dispatched(index, t, self._state.T_w_c, None, dropped, images)
        args = (self._state, flow, self.key, self.params, self._chain.keyframe_flow)
        if self._step is None:
            self._step = self._compiled_step(args)
        self._state, out = self._step(*args)
        return _Dispatched(index, t, out.T_w_c, out, None, images)

    def _compiled_step(self, args):
        """The per-frame step for arguments of the types of ``args``: exported in the compile
        cache (:func:`jaxvo.host.services.compile_cache.exported_program`), so that a later process
        neither traces nor lowers it; else :func:`jit_step` as it is."""
        cfg, grid = self._step_options, self._grid

        def step(state, flow, key, params, keyframe):
            return jit_step(state, flow, key, params, cfg=cfg, grid=grid, keyframe=keyframe)

        return exported_program("step", step, args, static=f"{cfg!r} {grid}") or step

    def _check_first(self, depth: np.ndarray, raw_units: bool) -> None:
        """The first frame's checks: its depth (a warning kept in :attr:`warnings`), the
        intrinsics and the settings against its size, the memory the run needs."""
        note = check_depth_scale(depth, self.intrinsics, where="the first frame",
                                 raw_units=raw_units)
        if note:
            self.warnings.append(note)
            warnings.warn(note, DepthScaleWarning, stacklevel=4)
        h, w = depth.shape
        check_intrinsics(self.intrinsics, where="intrinsics", width=w, height=h)
        check_config(self.cfg, height=h, width=w)
        check_memory(run_bytes(self.cfg, height=h, width=w),
                     what=f"Odometry with {_shape_settings(self.cfg)}")

    def _revise(self, winner: int) -> np.ndarray:
        """Redraw the poses before the last one along the chain of the ``winner`` the
        background switched to in the last pair (:func:`jaxvo.core.pipeline.revised_poses`);
        the revised poses, (k, 4, 4) float64. The pairs are padded in front to a power of
        two, so that a long stream compiles the walk a few times, not at every switch."""
        pairs = len(self._chains)
        size = 1 << max(pairs - 1, 0).bit_length()
        eye = np.eye(4, dtype=np.float32)
        switched = np.zeros(size, np.int32)
        switched[-1] = winner
        after = revised_poses(
            _padded([p.astype(np.float32) for p in self.poses[-pairs:]], size, eye), switched,
            _padded(self._chains, size, np.broadcast_to(eye, self._chains[0].shape)),
            _padded(self._permutations, size, np.arange(len(self._permutations[0]))),
            _padded(self._new_ids, size, np.zeros_like(self._new_ids[0])))
        revised = np.asarray(after, np.float64)[size - pairs:-1]
        self.poses[len(self.poses) - pairs:-1] = list(revised)
        return revised

    def _separate(self, out: StepOutput) -> np.ndarray | None:
        """Where the test over the keyframe switched the commitment in the last pair, redraw
        the poses of the earlier pairs tested against the same keyframe as the other motion
        had them (:func:`jaxvo.core.pipeline.separated_poses`); the revised poses, (k, 4, 4)
        float64, else None. Only the pairs of the latest keyframe are kept for it."""
        keyframe = int(out.tested_keyframe)
        if keyframe != self._tested_keyframe:
            self._tested_keyframe, self._other_poses = keyframe, []
        self._other_poses.append(np.asarray(out.other_pose, np.float64))
        k = len(self._other_poses) - 1
        if not bool(out.separated) or k == 0:
            return None
        revised = np.stack(self._other_poses[:-1])
        self.poses[len(self.poses) - 1 - k:-1] = list(revised)
        return revised

    def _finish(self, pending: _Dispatched) -> FrameResult:
        """Wait for a dispatched frame, record its pose, log it (:meth:`attach`) and return
        its result."""
        r = self._result(pending)
        if pending.images is not None and self.logger is not None:
            self.logger.log_frame(r, *pending.images)
        return r

    def _result(self, pending: _Dispatched) -> FrameResult:
        """A dispatched frame's result, its pose recorded (waits for the device)."""
        index, t, T, out, dropped, _ = pending
        T = np.asarray(T, np.float64)
        if dropped is None:
            self.timestamps.append(t)
            self.poses.append(T)
        if out is None:
            n = self._grid[0] * self._grid[1]
            status = Status.OK if dropped is None else Status.BAD_INPUT
            return FrameResult(index, t, T, status, np.zeros(n, np.int32), np.zeros(n, bool),
                               None, dropped)
        out = jax.tree.map(np.asarray, out)
        self._chains.append(out.chains)
        self._permutations.append(out.permutation)
        self._new_ids.append(out.new_ids)
        revised = None
        if out.separated is not None:
            revised = self._separate(out)
        if int(out.switched):
            revised = self._revise(int(out.switched))
        return FrameResult(index, t, T, Status(int(out.status)), out.ids, out.static, out,
                           revised=revised)


def _padded(items: list[np.ndarray], size: int, fill: np.ndarray) -> np.ndarray:
    """``items`` stacked after ``size - len(items)`` copies of ``fill``."""
    return np.stack([fill] * (size - len(items)) + items)


def _frame_arrays(bgr, depth, K: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """The colour image as given and the depth in float32 metres, or a ValueError that says
    what is wrong with them (see :meth:`Odometry.process`)."""
    if not (isinstance(bgr, np.ndarray) and bgr.dtype == np.uint8
            and (bgr.ndim == 2 or (bgr.ndim == 3 and bgr.shape[2] == 3))):
        got = (f"{bgr.dtype} {bgr.shape}" if isinstance(bgr, np.ndarray)
               else type(bgr).__name__)
        raise ValueError(
            f"bgr must be an (H, W, 3) uint8 BGR image or (H, W) uint8 grey, got {got}"
        )
    depth = depth_metres(depth, K)
    if depth.shape != bgr.shape[:2]:
        raise ValueError(
            f"colour {bgr.shape[1]}x{bgr.shape[0]} and depth {depth.shape[1]}x{depth.shape[0]} "
            "differ in size: depth must be registered to the colour image"
        )
    return bgr, depth


def check_pose(T, *, name: str) -> np.ndarray:
    """A pose checked to be a rigid transform: finite, last row ``0 0 0 1``, rotation
    orthonormal with determinant 1 within 1e-4 (float32 poses written to 6 decimals pass).

    Args:
      T: (4, 4) array-like.
      name: what to call it in the message (e.g. ``T_w_c0``).
    Returns:
      (4, 4) float64.
    Raises:
      ValueError: it is not.
    """
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be a finite (4, 4) pose, got shape {T.shape}")
    R = T[:3, :3]
    if (not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6)
            or not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0):
        raise ValueError(f"{name} is not a rigid transform (rotation and translation)")
    return T


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

    trajectory: Trajectory  # one pose per kept frame, camera-to-world
    outputs: StepOutput  # every field stacked over the T frame pairs stepped
    flows: GridFlow  # stacked over the T pairs the scan consumed
    flow_seconds: float  # host time computing the grid flow
    scan_seconds: float  # device time of the scan, compile included
    grid: tuple[int, int]
    # (T + 1,) int indices of the frames kept: pair k is frames[k] -> frames[k + 1], and its
    # labels lie on image frames[k] (0 .. len(seq) - 1 when no frame is dropped)
    frames: np.ndarray
    dropped: dict[int, str]  # index of each dropped frame -> why
    start_pose: str  # where the first pose came from, in words
    # the KeyframeFlow of every pair the scan consumed beside ``flows`` (cfg.keyframes)
    keyframes: KeyframeFlow | None = None


def scan_flows(flows, keyframes, T_w_c0, *, cfg: Config, grid: tuple[int, int], seed: int = 0,
               params: Params | None = None):
    """The whole-sequence scan as :func:`run_sequence` calls it: the same argument types
    every time, so a second call with a result's ``flows``, ``keyframes`` and first pose
    runs the program the first one compiled (a call with other types, e.g. ``keyframes``
    left out instead of given as None, compiles it again).

    Returns:
      ``(final_state, outputs)`` of :func:`jaxvo.core.pipeline.run_scan`, not waited for.
    """
    default_compile_cache()
    p = params_as_arrays(params if params is not None else Params())
    return run_scan(flows, jax.random.key(seed), p, jnp.asarray(T_w_c0, jnp.float32),
                    cfg=cfg.step, grid=grid, keyframes=keyframes)


def run_sequence(
    seq,
    *,
    cfg: Config | Mapping[str, object] = Config(),
    params: Params | None = None,
    seed: int = 0,
    start_pose: str | np.ndarray = "gt",
    progress: Callable[[int, int], None] | None = None,
) -> SequenceResult:
    """Flow for every frame pair on the host, then one jit-compiled ``lax.scan``.

    Frames that cannot be used are dropped and the next frame pairs with the last good one
    (:func:`jaxvo.host.frontend.flow.sequence_flows`); the trajectory holds the kept frames.

    Args:
      seq: a sequence per docs/architecture.md (:func:`jaxvo.open_sequence`,
        :func:`jaxvo.make_sequence`), or the path of a TUM-layout folder.
      cfg: static settings, a Config or a mapping of its fields ({"cell": 16}).
      params: numeric settings (default :class:`Params`).
      seed: PRNG seed of the hypothesis sampling.
      start_pose: the first kept frame's pose: ``"gt"`` its ground-truth pose when the
        sequence has one within 0.02 s of it (estimated and true trajectories then share a
        frame without alignment), else the identity; ``"identity"``; or a (4, 4)
        ``T_w_c0``.
      progress: called as ``progress(done, total)`` while the flow is computed.
    Returns:
      :class:`SequenceResult`.
    Raises:
      InputError: fewer than 2 frames, or fewer than 2 that can be used, or a run that
        needs more memory than the machine has (:mod:`jaxvo.host.services.memory`).
      ValueError: ``seq`` is neither a sequence nor a folder path.
    """
    seq = _as_sequence(seq)
    cfg = as_config(cfg)
    if len(seq) < 2:
        raise InputError(f"sequence {seq.name!r} has {len(seq)} frame(s); odometry needs 2 or more")
    check_config(cfg, height=seq.height, width=seq.width)
    if params is not None:
        check_params(params)
    check_memory(run_bytes(cfg, height=seq.height, width=seq.width, frames=len(seq)),
                 what=f"run_sequence of {len(seq)} frames with {_shape_settings(cfg)}")
    grid = grid_shape(seq.height, seq.width, cfg.cell)

    t0 = time.perf_counter()
    chain = sequence_flows(seq, cfg, params=params, progress=progress)
    flow_s = time.perf_counter() - t0
    if len(chain.frames) < 2:
        reasons = sorted(set(chain.dropped.values()))
        raise InputError(f"sequence {seq.name!r}: fewer than 2 frames can be used "
                         f"({len(chain.dropped)} dropped: {'; '.join(reasons)})")
    stamps = np.asarray(seq.timestamps, np.float64)[chain.frames]
    T0, start = choose_start_pose(start_pose, getattr(seq, "groundtruth", None), stamps[0])

    t0 = time.perf_counter()
    _, outs = scan_flows(chain.flows, chain.keyframes, T0, cfg=cfg, grid=grid, seed=seed,
                         params=params)
    outs = jax.tree.map(np.asarray, jax.block_until_ready(outs))
    scan_s = time.perf_counter() - t0

    committed = committed_poses(outs)
    poses = np.concatenate([T0[None], np.asarray(committed, np.float64)])
    return SequenceResult(Trajectory(stamps, poses), outs, chain.flows, flow_s, scan_s, grid,
                          chain.frames, chain.dropped, start, chain.keyframes)


def _shape_settings(cfg: Config) -> str:
    """The settings that size a run's memory, for messages."""
    return f"num_hypotheses {cfg.num_hypotheses}, cell {cfg.cell}"


def as_config(cfg: Config | Mapping[str, object]) -> Config:
    """``cfg`` as a :class:`Config`: a Config itself, or a mapping of its fields
    (``{"cell": 16}``) made into one, so that its values meet the same checks.

    Raises:
      TypeError: neither, or a mapping with a name that is no field (one line).
    """
    if isinstance(cfg, Config):
        return cfg
    if isinstance(cfg, Mapping):
        return Config(**{str(k): v for k, v in cfg.items()})
    raise TypeError(f"cfg must be a jaxvo.Config or a mapping of its fields (cfg={{'cell': 16}}"
                    f" or jaxvo.Config(cell=16)); got {type(cfg).__name__}")


def _as_sequence(seq):
    """A sequence object from what users pass :func:`run_sequence`: the object itself, or
    a folder path opened as a TUM-layout sequence; else a ValueError saying what is
    expected (a list of frames has no camera and no timestamps of its own)."""
    if isinstance(seq, str | Path):
        from jaxvo.host.readers.io import open_sequence

        return open_sequence(seq)
    needed = ("intrinsics", "height", "width", "timestamps", "name")
    missing = [a for a in needed if not hasattr(seq, a)]
    if missing or not hasattr(seq, "__getitem__"):
        raise ValueError(
            "seq must be a sequence (jaxvo.open_sequence(folder), jaxvo.make_sequence(...): "
            f"frames with {', '.join(needed)}) or a folder path; got {type(seq).__name__}"
            + (" without " + ", ".join(missing) if missing else "")
            + ("; for frames in a list, feed them to jaxvo.Odometry" if isinstance(
                seq, list | tuple) else ""))
    return seq


def choose_start_pose(
    choice: str | np.ndarray,
    gt: Trajectory | None,
    t0: float,
    *,
    max_diff: float = 0.02,
    required: bool = False,
) -> tuple[np.ndarray, str]:
    """The first frame's pose and where it came from, in words.

    Args:
      choice: ``"gt"``, ``"identity"`` or a (4, 4) pose (see :func:`run_sequence`).
      gt: the sequence's ground truth, or None.
      t0: the first frame's timestamp, seconds.
      max_diff: largest time difference to a ground-truth pose, seconds.
      required: with ``"gt"``, raise instead of taking the identity when there is no
        ground-truth pose.
    Returns:
      ``(T_w_c0 (4, 4) float64, description)``.
    Raises:
      ValueError: an unknown choice, or a pose that is not a rigid transform.
      InputError: ``required`` and no ground-truth pose of the first frame.
    """
    if not isinstance(choice, str):
        return check_pose(choice, name="start_pose"), "given"
    if choice == "identity":
        return np.eye(4), "identity"
    if choice != "gt":
        raise ValueError(f"start_pose must be 'gt', 'identity' or a (4, 4) pose, got {choice!r}")
    T = pose_at(gt, t0, max_diff=max_diff) if gt is not None else None
    if T is None:
        why = "no ground truth" if gt is None else f"no ground-truth pose within {max_diff:g} s"
        if required:
            raise InputError(f"start pose gt: {why} of the first frame ({t0:.6f} s)")
        return np.eye(4), f"identity ({why} of the first frame)"
    return T, f"ground truth at {t0:.6f} s"
