"""A run over a recorded sequence, its outputs recorded as it goes: ``jaxvo run``'s work as
a library (host side), which the command reads its options into and prints.

:func:`prepare_run` checks every option and file and makes the outputs ready, without JAX,
so that a one-line answer comes at once. :func:`record_run` then runs the streaming
odometry over the frames (pipelined: a frame's device step runs while the next frame's flow
is computed; the frames are read and decoded ahead on other threads) and a
:class:`Recorder` records each frame's result as it comes: the pose in the trajectory file
at once (an interrupted run keeps what it computed), the label masks, dynamic masks,
overlays and the ROS 2 bag's messages on a writer thread, the dynamic cells the static map
leaves out. After the last frame come the map, the bag and the scores against the ground
truth. The run's summary is a dict, which :func:`summary_lines` puts in words, as evo's
``ape()`` returns a result that its command prints.

Each check runs once a run: :func:`prepare_run` checks the settings against the image size
and the memory they need, :func:`record_run` the first frame's depth, and the odometry is
told so (``Odometry(checked=True)``). Every file appears whole or not at all
(:mod:`jaxvo.host.writers.outputs`); an output other than the trajectory that fails (a full disk)
stops the run as Ctrl-C does, the trajectory kept, and is then raised
(:class:`OutputFailures`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import json
import math
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from jaxvo.config import Config, check_config
from jaxvo.errors import InputError, check_seed
from jaxvo.errors import warn as warn_user
from jaxvo.host.frontend.camera import Intrinsics, check_depth_scale_value, describe_distortion
from jaxvo.host.writers.bagout import BagOptions, check_bag_options, check_bag_target, open_bag
from jaxvo.host.writers.mapping import MapOptions, make_maps, map_outputs


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """What a run is asked: ``jaxvo run``'s options (its messages name them so)."""

    sequence: str | Path  # a TUM-layout folder, a ROS bag or a RealSense recording
    out: str | Path  # the trajectory file (TUM, camera-to-world); "-": standard output
    cfg: Config = dataclasses.field(default_factory=Config)
    seed: int = 0
    camera: str | Intrinsics | None = None  # a preset or the intrinsics; None: the input's
    depth_scale: float | None = None  # raw depth units per metre; None: the camera's
    max_diff: float = 0.02  # seconds: rgb / depth / ground truth association, and the map's
    frames: int | None = None  # the first frames only; None: all
    start_pose: str | None = None  # "gt" or "identity"; None: gt where there is one
    rgb_topic: str | None = None  # a bag's topics; None: TUM's
    depth_topic: str | None = None
    masks: str | Path | None = None  # folders of per-frame images (None: not written)
    dynamic_masks: str | Path | None = None
    overlays: str | Path | None = None
    rerun: bool = False  # the Rerun viewer
    rerun_save: str | Path | None = None  # a Rerun recording
    map: str | Path | None = None  # the static map (MapOptions' defaults) after the run
    bag: BagOptions = dataclasses.field(default_factory=BagOptions)  # a ROS 2 bag of it
    quiet: bool = False  # no progress line, and no line saying that the step compiles


class PreparedRun(NamedTuple):
    """A run checked and ready (:func:`prepare_run`)."""

    options: RunOptions
    seq: object  # the sequence, open
    frames: int  # frames to process
    out: Path | str  # the trajectory file, or "-"
    folders: dict[str, Path]  # option -> its folder of per-frame images, made


def _check_values(o: RunOptions) -> None:
    """The options that need no file, checked (InputError naming the option)."""
    if not (math.isfinite(o.max_diff) and o.max_diff >= 0):
        raise InputError(f"--max-diff must be a number of seconds >= 0, got {o.max_diff}")
    if o.frames is not None and o.frames < 2:
        raise InputError(f"--frames must be at least 2 (odometry needs a pair), got {o.frames}")
    if o.depth_scale is not None:
        check_depth_scale_value(o.depth_scale, name="--depth-scale")
    check_seed(o.seed, name="--seed")
    check_bag_options(o.bag)


def prepare_run(o: RunOptions, *, names: dict[str, str] | None = None) -> PreparedRun:
    """Every option and file checked, the sequence opened and the outputs made ready (the
    output folders created; nothing else written), before JAX loads.

    Args:
      o: the run.
      names: what to call a ``Config`` field in messages (``{"cell": "--cell"}``).
    Raises:
      InputError: one line, naming the option or the file.
    """
    from jaxvo.host.readers.io import open_sequence
    from jaxvo.host.services.memory import check_memory, run_bytes

    _check_values(o)
    seq = open_sequence(o.sequence, camera=o.camera, max_diff=o.max_diff,
                        depth_scale=o.depth_scale, rgb_topic=o.rgb_topic,
                        depth_topic=o.depth_topic)
    n = len(seq) if o.frames is None else min(len(seq), o.frames)
    if n < 2:
        raise InputError(f"{o.sequence}: {n} frame(s); odometry needs at least 2")
    check_config(o.cfg, height=seq.height, width=seq.width, names=names)
    check_memory(run_bytes(o.cfg, height=seq.height, width=seq.width),
                 what=f"jaxvo run with --hypotheses {o.cfg.num_hypotheses}, --cell {o.cfg.cell}")
    out, folders = _outputs(o, seq, n)
    return PreparedRun(o, seq, n, out, folders)


def _outputs(o: RunOptions, seq, n: int) -> tuple[Path | str, dict[str, Path]]:
    """The run's outputs checked (none over an input or another output) and made ready."""
    from jaxvo.host.writers.outputs import (
        STDOUT,
        check_outputs,
        output_file,
        output_folder,
        stream_target,
    )

    given = {option: folder for option, folder in (
        ("--masks", o.masks), ("--dynamic-masks", o.dynamic_masks),
        ("--overlays", o.overlays)) if folder}
    out = stream_target(o.out, what="--out", stdout=True)
    files = {} if out == STDOUT else {"--out": out}
    if o.rerun_save:
        files["--rerun-save"] = o.rerun_save
    if o.map:
        files.update({("--map" if k == "map" else f"--map's {k}"): v
                      for k, v in map_outputs(o.map).items()})
    files = {what: stream_target(path, what=what) for what, path in files.items()}
    bag = {"--out-bag": Path(o.bag.folder)} if o.bag.folder else {}
    check_outputs(seq.files(), files=files,
                  folders={**{k: Path(v) for k, v in given.items()}, **bag})
    if o.bag.folder:
        from jaxvo.host.writers.bagout import check_bag_input

        check_bag_target(o.bag.folder)
        check_bag_input(o.bag, seq)
    for what, path in files.items():
        output_file(path, what=what)
    if o.rerun or o.rerun_save:
        from jaxvo.host.writers.recording import check_display, import_rerun

        import_rerun("--rerun" if o.rerun else "--rerun-save")
        if o.rerun:
            check_display("--rerun")
    names = {f"{t:.6f}.png" for t in seq.timestamps[:n]}
    return out, {option: output_folder(folder, what=option, names=names)
                 for option, folder in given.items()}


class _NoStop:
    """A stop request never made (:func:`record_run` without one)."""

    requested = False

    def __call__(self) -> None:
        pass


def record_run(run: PreparedRun, *, stop=None,
               warn: Callable[[str], None] = warn_user) -> dict:
    """The odometry over the prepared frames, every output recorded; the run's summary.

    Args:
      run: :func:`prepare_run`'s.
      stop: called between frames, raising ``KeyboardInterrupt`` to end the run there with
        what was computed (``requested`` says whether it did; the command's Ctrl-C,
        :func:`jaxvo.cli.main.interrupt_at_safe_points`); None: never.
      warn: what is done with a warning line (default: printed to standard error).
    Returns:
      the summary (``interrupted``, ``pairs_ok``, ... ; :func:`summary_lines`).
    Raises:
      InputError: no frame can be read, or the first one's depth no sensor reads.
    """
    from jaxvo.host.frontend.prefetch import BackgroundWriter, read_ahead
    from jaxvo.host.readers.io import TrajectoryWriter, check_depth_scale, first_readable
    from jaxvo.host.services.compile_cache import announce_compile
    from jaxvo.host.services.progress import Progress
    from jaxvo.odometry import Odometry, choose_start_pose

    o, seq, n, out, folders = run
    stop = stop if stop is not None else _NoStop()
    warnings = list(seq.warnings)
    reads = read_ahead(seq.__getitem__, range(n))  # beside the flow and the step
    # the first readable frame: its depth tells a wrong depth scale, its time the start pose
    first, early = first_readable(((i, fut.result) for i, fut in reads), where=o.sequence,
                                  total=n)
    note = check_depth_scale(first.depth, seq.intrinsics,
                             where=f"{o.sequence} frame {first.index}",
                             raw_units=not getattr(seq, "float_depth", False))
    warnings += [note] if note else []
    for w in warnings:
        warn(w)
    gt = seq.groundtruth
    T_w_c0, start = choose_start_pose(o.start_pose or "gt", gt, first.timestamp,
                                      max_diff=o.max_diff, required=bool(o.start_pose))
    odo = Odometry(seq.intrinsics, cfg=o.cfg, seed=o.seed, T_w_c0=T_w_c0, checked=True)
    progress = Progress("jaxvo run", n - 1, enabled=not o.quiet)
    failures = OutputFailures()
    # the recording and the bag are whole once the run and its map are (the recording
    # closed last); an error discards both, and an earlier recording stays
    with _logger(o, odo, gt, failures) as logger, open_bag(o.bag, seq, cell=o.cfg.cell) as bag:
        # leaving this block, also by Ctrl-C, closes the reader, writes every image queued,
        # then puts the trajectory file in place (whole, with every pose computed)
        with (TrajectoryWriter(out, comment=run_header(o.sequence, seq)) as writer,
              BackgroundWriter() as images,
              contextlib.closing(reads),
              announce_compile("the per-frame step", stream=None if o.quiet else sys.stderr)
              as compiling):
            rec = Recorder(o.cfg, writer, images, folders, keep_dynamic=bool(o.map), bag=bag,
                           failures=failures)
            rec.process(odo, itertools.chain(early, ((i, fut.result) for i, fut in reads)),
                        stop, progress)
            failures.call(images.close)  # the last images and bag messages written
        progress.close()
        failures.raise_kept()  # the trajectory in place: now the failure
        summary = _summary(o, seq, n, start, rec, compiling, warnings, out)
        # a Ctrl-C after the last frame: no map; the bag finished with every frame, as the
        # trajectory was put in place with every pose; then the run says it was interrupted
        if o.map:
            rec.interrupted = rec.interrupted or stop.requested
            summary.update(_map(o, seq, n, rec, out, writer, logger, warn))
        if bag is not None:
            summary.update(bag.finish())
        if o.map or bag is not None:
            summary["interrupted"] = rec.interrupted = rec.interrupted or stop.requested
    if gt is not None and rec.written >= 3:
        summary.update(_scores(gt, writer, o.max_diff))
    return summary


def _logger(o: RunOptions, odo, gt, failures: OutputFailures):
    """The run's Rerun logger attached to ``odo`` (a context that closes it), or a context
    holding None; a failure of its frames' logging goes to ``failures``."""
    if not (o.rerun or o.rerun_save):
        return contextlib.nullcontext(None)
    from jaxvo.host.writers.recording import RerunLogger

    logger = RerunLogger(save=o.rerun_save, spawn=o.rerun, what="--rerun-save")
    odo.attach(_Logging(logger, failures))
    logger.log_groundtruth(gt)
    return logger


class OutputFailures:
    """The first failure of an output other than the trajectory (the masks, overlays, bag,
    recording: a full disk there), kept instead of raised where it happens: the run then
    stops at the next frame as after Ctrl-C, the trajectory (on a disk that may be healthy)
    is put in place with the poses computed, and the failure is raised
    (:meth:`raise_kept`), naming its file. The outputs not finished (the bag, the
    recording, the map) are not written."""

    def __init__(self) -> None:
        self.error: OSError | None = None

    def call(self, fn, *args) -> None:
        """``fn(*args)``, its ``OSError`` kept; nothing once one failed."""
        if self.error is not None:
            return
        try:
            fn(*args)
        except OSError as exc:
            self.error = exc

    def raise_kept(self) -> None:
        """Raise the failure kept, if any."""
        if self.error is not None:
            raise self.error


class _Logging:
    """The run's logger as the odometry calls it, a failure kept in ``failures`` (raised
    inside the odometry, it would lose the frame's result)."""

    def __init__(self, logger, failures: OutputFailures) -> None:
        self.logger, self.failures = logger, failures

    def setup(self, intrinsics, cell: int) -> None:
        self.logger.setup(intrinsics, cell)

    def log_frame(self, r, *images) -> None:
        self.failures.call(self.logger.log_frame, r, *images)


class Recorder:
    """What a run does with each frame's result: the pose to the trajectory file, the
    pair's images (and the bag's messages) to the writer thread, the dynamic cells the map
    leaves out, and the counts the summary gives.

    Args:
      cfg: the run's settings (the grid cell).
      writer: the :class:`~jaxvo.host.readers.io.TrajectoryWriter`.
      images: the :class:`~jaxvo.host.frontend.prefetch.BackgroundWriter` the images go through.
      folders: ``--masks``, ``--dynamic-masks``, ``--overlays`` -> the folder written.
      keep_dynamic: keep each frame's dynamic cells for the map (:attr:`dynamic`).
      bag: the :class:`~jaxvo.host.writers.bagout.BagWriter`, or None.
      failures: where a failure on the writer thread is kept (:class:`OutputFailures`);
        the run stops at the next frame after one.
    """

    def __init__(self, cfg: Config, writer, images, folders: dict[str, Path], *,
                 keep_dynamic: bool = False, bag=None, failures: OutputFailures | None = None):
        from jaxvo.host.writers.plugin import LabelAnchor  # OpenCV's masks: not before the run

        self.cfg, self.writer, self.images, self.folders = cfg, writer, images, folders
        self.bag = bag  # written on the writer thread, as the images
        self.failures = failures if failures is not None else OutputFailures()
        self.skipped: Counter[str] = Counter()
        self.dropped: Counter[str] = Counter()
        self.times: list[float] = []
        self.written = 0
        self.pairs_ok = 0
        self.recent: dict[int, object] = {}  # submitted frames whose results are not out yet
        self.labels = LabelAnchor()  # which image each pair's labels lie on
        self.reacquired = 0  # pairs in which the background took its identifier back
        # switches of the background to another motion, the poses they redrew in the file,
        # and those already printed (standard output) or published (the bag) as they were
        self.switches = self.revised = self.unrevised = 0
        self.keyframes = 1 if cfg.keyframes else 0  # keyframes taken (the first frame is one)
        self.first_unreadable = ""  # the first unreadable frame's error, for the summary
        self.interrupted = False
        self.seen = 0  # frames taken from the sequence (read, or found unreadable)
        # frame index -> its dynamic cells (n,) bool, for the map; None: not kept
        self.dynamic: dict[int, np.ndarray] | None = {} if keep_dynamic else None

    def process(self, odo, frames, stop, progress) -> None:
        """Every frame of ``frames`` ((index, read) pairs) through ``odo``, pipelined;
        Ctrl-C (taken by ``stop`` between frames) ends the loop with what was computed."""
        try:
            submitted = 0
            for i, read in frames:
                stop()  # Ctrl-C is taken here, between frames, never inside a compile
                if self.failures.error is not None:  # an output failed: stop as Ctrl-C does
                    break
                t0 = time.perf_counter()
                self.seen += 1
                try:
                    frame = read()
                except InputError as exc:  # unreadable frame: drop it, keep going
                    self.dropped["unreadable frame"] += 1
                    self.first_unreadable = self.first_unreadable or str(exc)
                    continue
                self.recent[submitted] = frame
                submitted += 1
                # pipelined: this frame's device step runs while the next one is read
                # and its flow computed; the result that comes back is the previous one's
                r = odo.submit(frame.bgr, frame.depth, frame.timestamp)
                if r is not None:
                    self.record(r)
                self.times.append(time.perf_counter() - t0)  # reading and writing included
                if i:
                    progress(i)
        except KeyboardInterrupt:
            self.interrupted = True
        self.finish(odo)

    def finish(self, odo) -> None:
        """The last frame's result (also after an interruption) and the last image's
        dynamic mask: the last pair's labels."""
        r = odo.flush()
        if r is not None:
            self.record(r)
        last = self.labels.last_image()
        if last is None:
            return
        frame, output = last
        if self.dynamic is not None:
            self.dynamic[frame.index] = output.dynamic
        if "--dynamic-masks" in self.folders or self.bag is not None:
            self.submit(self.write_images, frame, None, output.dynamic)

    def record(self, r) -> None:
        """One finished frame: its pose now (a line, flushed: a second Ctrl-C, which ends
        the process at once, loses none), its pair's images on the writer thread."""
        from jaxvo.status import Status

        frame = self.recent.pop(r.index)
        if self.bag is not None and self.bag.input_frames:
            self.submit(self.bag.write_frame, frame)
        if r.dropped is not None:
            self.dropped[r.dropped] += 1
            return
        self.writer.write(r.timestamp, r.T_w_c)
        if r.revised is not None:  # the background switched: the path so far redrawn
            self.switches += 1
            self.revised += len(r.revised)
            self.unrevised += self.writer.revise(r.revised)
        if self.bag is not None:
            self.submit(self.bag.write_pose, frame.index, r.T_w_c)
        self.written += 1
        image = self.labels.push(frame, r.output)
        if image is None:
            return
        if r.status == Status.OK:
            self.pairs_ok += 1
        else:
            self.skipped[r.status.reason] += 1
        self.reacquired += int(r.output.reacquired)
        if r.output.keyframes is not None:
            self.keyframes = int(r.output.keyframes)
        if self.dynamic is not None:
            self.dynamic[image.index] = r.output.dynamic
        if self.folders or self.bag is not None:
            self.submit(self.write_images, image, r, r.output.dynamic)

    def submit(self, fn, *args) -> None:
        """``fn(*args)`` on the writer thread; a failure there kept (:attr:`failures`)."""
        self.failures.call(self.images.submit, fn, *args)

    def write_images(self, frame, r, moving) -> None:
        """The images of a pair whose labels lie on ``frame``'s image, named by its time as
        TUM names its images; ``r`` None: the dynamic mask ``moving`` alone. Runs on the
        writer thread: encoding PNGs is most of what a frame's output costs."""
        from jaxvo.host.writers import outputs
        from jaxvo.host.writers.masks import dynamic_pixels, grid_to_pixels, overlay_panel
        from jaxvo.host.writers.plugin import mask_png

        h, w = frame.depth.shape
        cell = self.cfg.cell
        name = f"{frame.timestamp:.6f}.png"
        if "--masks" in self.folders and r is not None:
            ids = grid_to_pixels(r.ids, h, w, cell).astype(np.uint8)
            outputs.write_image(self.folders["--masks"] / name, ids)
        mask = mask_png(dynamic_pixels(moving, h, w, cell))
        if "--dynamic-masks" in self.folders:
            outputs.write_image(self.folders["--dynamic-masks"] / name, mask)
        if self.bag is not None:
            self.bag.write_mask(frame, mask, None if r is None else r.output)
        if "--overlays" in self.folders and r is not None:
            outputs.write_image(self.folders["--overlays"] / name,
                                overlay_panel(frame.bgr, r.output, cell))


def _map(o: RunOptions, seq, n: int, rec: Recorder, out, writer, logger, warn) -> dict:
    """The maps from the trajectory written and the run's dynamic cells, at
    :class:`~jaxvo.host.writers.mapping.MapOptions`' defaults; the summary's part (why there is no
    map, after Ctrl-C or with no pose)."""
    if rec.interrupted or not rec.written:
        why = "the run was interrupted" if rec.interrupted else "no pose was written"
        kept = f" (an earlier {o.map} is as it was)" if Path(o.map).exists() else ""
        return {"map_not_written": why + kept}
    from jaxvo.host.writers.masks import dynamic_pixels

    def dynamic(index: int, timestamp: float):
        cells = rec.dynamic.get(index)
        return None if cells is None else dynamic_pixels(cells, seq.height, seq.width,
                                                         o.cfg.cell)

    est = writer.written()  # as the file holds it, whoever replaced the file since
    last = rec.labels.image  # the last image kept: the map is stamped with its time
    on_static = None if rec.bag is None else (
        lambda static: rec.bag.write_map(static, last.index))
    return make_maps(seq, est, dynamic, MapOptions(max_diff=o.max_diff), map_outputs(o.map),
                     where=f"--out {out}", frames=n, logger=logger, on_static=on_static,
                     warn=warn)


def peak_rss_mib() -> float:
    """This process's peak resident memory, MiB: Linux's VmHWM (the high-water mark of this
    program's own address space), else ``ru_maxrss``, which on Linux also keeps the peak of
    the process before ``exec`` (a large parent's pages shared through ``fork``)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024, 1)
    except OSError:
        pass
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def _summary(o: RunOptions, seq, n: int, start: str, rec: Recorder, compiling, warnings,
             out) -> dict:
    """The run's summary, as far as the frames go."""
    times = rec.times
    steady = times[2:] if len(times) > 3 else times[1:]
    fps = len(steady) / sum(steady) if steady and sum(steady) > 0 else 0.0
    return {
        "sequence": str(o.sequence),
        "frames_listed": getattr(seq, "frames_listed", len(seq)),
        "frames": n,
        "frames_processed": rec.seen,
        "camera": getattr(seq, "camera_source", "given"),
        "lens": describe_distortion(seq.intrinsics),
        "start_pose": start,
        "poses_written": rec.written,
        "keyframes": rec.keyframes,  # 0: frame to frame only (Config.keyframes off)
        "trajectory": str(out),
        "frames_per_second": round(fps, 2),
        "first_frame_pair_seconds": round(times[1], 3) if len(times) > 1 else None,
        # the step's compile (or its load from the persistent compile cache), seconds
        "compile": [{"seconds": round(c.seconds, 3), "from_cache": c.from_cache}
                    for c in compiling],
        "pairs_ok": rec.pairs_ok,
        "skipped": dict(rec.skipped),
        "background_reacquired": rec.reacquired,
        # switches of the background to another motion (its challenge), the earlier poses
        # they redrew in the trajectory file, and those printed or published before
        "background_switched": {"times": rec.switches, "poses_revised": rec.revised,
                                "poses_left_as_printed": rec.unrevised},
        "dropped": {(f"{k} (first: {rec.first_unreadable})" if k == "unreadable frame" else k):
                    v for k, v in rec.dropped.items()},
        "warnings": warnings,
        "interrupted": rec.interrupted,
        "peak_rss_mib": peak_rss_mib(),
    }


def _scores(gt, writer, max_diff: float) -> dict:
    """ATE and RPE of the written trajectory against the sequence's ground truth, or why
    they could not be computed: the file as ``jaxvo eval`` reads it, or the poses the
    writer wrote where they went to standard output."""
    from jaxvo.evaluation.metrics import ate, rpe

    est = writer.written()  # as the file holds it, whoever replaced the file since
    # a camera that never moves (a fixed camera) defines no alignment: compared as it is,
    # from the true first pose (as jaxvo.evaluation.scores.trajectory_scores does)
    aligned = bool(np.ptp(np.asarray(gt.poses)[:, :3, 3], axis=0).max() > 1e-6)
    try:
        a = ate(gt, est, align=aligned, max_diff=max_diff)
        r1 = rpe(gt, est, delta=1, delta_unit="frames", max_diff=max_diff)
    except InputError as exc:  # e.g. every pose carried: nothing to align
        return {"scores_not_computed": str(exc)}
    return {"ate_rmse_m": round(a.stats.rmse, 5), "ate_aligned": aligned,
            "rpe_trans_rmse_m_per_frame": round(r1.trans.rmse, 5),
            "rpe_rot_rmse_deg_per_frame": round(r1.rot.rmse, 4)}


def summary_lines(summary: dict) -> list[str]:
    """A run's summary (:func:`record_run`) in words, a line each, as ``jaxvo run`` prints
    it."""
    s = summary
    where = "standard output" if s["trajectory"] == "-" else s["trajectory"]
    lines = [f"jaxvo run: {s['poses_written']} poses -> {where}"
             + (" (interrupted)" if s["interrupted"] else "")]
    how = ("the step loaded from the compile cache" if s["compile"] and all(
        c["from_cache"] for c in s["compile"]) else "compile included")
    lines += [(f"  speed      {s['frames_per_second']:.1f} frames/s steady state, reading "
               f"and writing included (first pair {s['first_frame_pair_seconds']} s, {how})"),
              f"  camera     {s['camera']}", f"  lens       {s['lens']}",
              f"  start pose {s['start_pose']}"]
    if s["keyframes"]:
        lines.append(f"  keyframes  {s['keyframes']} taken (each frame's motion also fitted to "
                     "the latest keyframe's static points; the last keyframes refined together "
                     "as each was taken)")
    n, listed, seen = s["frames"], s["frames_listed"], s["frames_processed"]
    lines.append(f"  frames     {seen} processed" + (f" of {n}" if seen != n else "")
                 + (f" ({listed} listed)" if listed != n else ""))
    for label, counts, unit in (("dropped", s["dropped"], "frames"),
                                ("skipped", s["skipped"], "frame pairs")):
        total = sum(counts.values())
        what = unit if total != 1 else unit[:-1]  # "1 frame", "2 frame pairs"
        lines.append(f"  {label:<10} {total} {what}" + (
            " (no pose)" if label == "dropped" and total else
            " (the last motion carried)" if total else ""))
        lines += [f"    {count:5d}  {reason}"
                  for reason, count in sorted(counts.items(), key=lambda kv: -kv[1])]
    lines.append(f"  background re-acquired in {s['background_reacquired']} frame pairs (the "
                 "segment the evidence gave the background had another identifier)")
    switched = s["background_switched"]
    if switched["times"]:
        lines.append(f"  background switched to another motion {switched['times']} time(s): "
                     f"{switched['poses_revised']} earlier poses redrawn along it" + (
                         f" ({switched['poses_left_as_printed']} already printed stay as "
                         "they were)" if switched["poses_left_as_printed"] else ""))
    lines.append(f"  memory     {s['peak_rss_mib']:.0f} MiB peak resident")
    lines += [f"  warning    {w}" for w in s["warnings"]]
    return lines + _outcome_lines(s)


def _outcome_lines(s: dict) -> list[str]:
    """The summary's lines on the scores, the map and the bag."""
    lines = []
    if "scores_not_computed" in s:
        lines.append(f"  ATE / RPE  not computed: {s['scores_not_computed']}")
    if "map_not_written" in s:
        lines.append(f"  map        not written: {s['map_not_written']}")
    if "map" in s:
        lines.append(f"  map        {s['map_points']} points -> {s['map']} (dynamic pixels left "
                     f"out), {s['map_all_points']} -> {s['map_all']} (nothing left out), "
                     f"picture {s['map_picture']}")
    if "bag" in s:
        lines.append(f"  bag        {s['bag_messages']} messages on {s['bag_topics']} topics "
                     f"-> {s['bag']}" + (f" ({s['bag_input_messages']} of them the input's)"
                                         if s["bag_input_messages"] else ""))
    if "ate_rmse_m" in s:
        how = "aligned" if s["ate_aligned"] else "not aligned: the camera does not move"
        lines.append(f"  ATE        {s['ate_rmse_m']:.4f} m rmse ({how}, ground truth in "
                     "folder)")
        lines.append(f"  RPE        {s['rpe_trans_rmse_m_per_frame']:.4f} m, "
                     f"{s['rpe_rot_rmse_deg_per_frame']:.3f} deg rmse per frame")
    return lines


# A run's trajectory names what it ran on in a comment line (RUN_TAG, then JSON): jaxvo map
# reads the depth as the run read it, and refuses a trajectory of another sequence
RUN_TAG = "jaxvo-run "


def run_header(where: str | Path, seq) -> str:
    """The comment lines a run's trajectory starts with (without ``#``): the command, and
    the sequence's name, frames, first frame's time and camera as the run read them."""
    K = seq.intrinsics
    info = {"sequence": seq.name, "frames_listed": int(getattr(seq, "frames_listed", len(seq))),
            "first_time": round(float(seq.timestamps[0]), 6),
            "intrinsics": [float(K.fx), float(K.fy), float(K.cx), float(K.cy)],
            "depth_scale": float(K.depth_scale)}
    return f"jaxvo run {where}\n{RUN_TAG}{json.dumps(info)}"


def read_run_header(path: str | Path) -> dict | None:
    """What :func:`run_header` wrote at the top of a trajectory file, or None (another
    tool's trajectory, or a header that does not parse)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            lines = [line for _, line in zip(range(8), fh) if line.startswith("# " + RUN_TAG)]
        info = json.loads(lines[0][2 + len(RUN_TAG):])
        K = Intrinsics(*(float(v) for v in info["intrinsics"]), float(info["depth_scale"]))
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None
    return {**info, "intrinsics": K}
