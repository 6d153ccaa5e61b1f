"""A Rerun recording of a run (host side): what jaxvo sees, frame by frame.

Rerun (``rerun-sdk``, the optional extra ``jaxvo[viz]``) is a viewer and a recording format
(``.rrd``) that opens on any machine. :class:`RerunLogger` is attached to an
:class:`jaxvo.Odometry` (``jaxvo run --rerun`` / ``--rerun-save FILE.rrd`` attach one) and
logs, on one timeline per frame timestamp (``time``, and ``frame``, the frame's index):

==============================  ==========================================================
``world/camera``                the camera's pose (``Transform3D``, camera-to-world)
``world/camera/image``          its frustum (``Pinhole``, static)
``world/camera/image/rgb``      the colour image (half size, JPEG)
``world/camera/image/depth``    the depth (metres, half size)
``world/camera/image/ids``      the grid cells' identifiers (0 unknown, 1 static, >= 2 a
                                moving object), on the image the frame pair starts at
``world/points``                that image's grid points in the world, by identifier
``world/trajectory``            the trajectory so far
``world/groundtruth``           the ground truth, where the sequence has it (static)
``world/map/static``, ``/full`` the fused maps (:mod:`jaxvo.host.writers.mapping`; static)
``stats``                       points used in the fit and moving cells (% of the grid), ms
                                per frame, skipped pairs so far (one series each)
``log``                         why a pair was skipped or a frame dropped
==============================  ==========================================================

A pair's labels lie on the image it starts at (as ``--masks`` files are named), so they are
logged at that image's time, one frame after the pose.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Self

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.frontend.camera import Intrinsics, grid_pixels
from jaxvo.host.frontend.prefetch import BackgroundWriter
from jaxvo.host.writers.masks import _PALETTE
from jaxvo.host.writers.outputs import OutputFile, output_file

EXTRA = "pip install 'jaxvo[viz]'"
# The images (colour, depth, identifiers) are logged at SCALE times their size, the colour
# image as JPEG: raw at full size the recording grew large and the logging cost a 2-core
# run a good share of its time (docs/report/host_decisions.md); at half size the grid's
# cells are still 8 px
JPEG_QUALITY = 90
SCALE = 0.5
# the per-frame numbers, one series each of the entity ``stats`` (one log call a frame:
# each call has a cost of its own), on scales that share one plot
STATS = ("points used in the fit (% of the grid)", "moving (% of the grid)",
         "ms per frame", "skipped pairs so far")


def import_rerun(what: str = "the Rerun recording"):
    """The ``rerun`` module, or an :class:`InputError` naming the extra that installs it."""
    try:
        import rerun
    except ImportError:
        raise InputError(f"{what} needs the Rerun SDK (rerun-sdk), which is not installed: "
                         f"{EXTRA}") from None
    return rerun


def check_display(what: str = "--rerun") -> None:
    """Refuse to open the viewer where there is no display to open it on (Linux)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError(f"{what} opens the Rerun viewer, which needs a display (neither "
                         "DISPLAY nor WAYLAND_DISPLAY is set); write a recording with "
                         "--rerun-save FILE.rrd and open it where there is one")


def blueprint():
    """The layout the recording opens on: the 3D world, the image with its labels above the
    depth, and the per-frame numbers."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="world"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="world/camera/image", name="image and labels",
                                  contents=["$origin/rgb", "$origin/ids"]),
                rrb.Spatial2DView(origin="world/camera/image", name="depth",
                                  contents=["$origin/depth"]),
                rrb.TimeSeriesView(origin="stats", name="per frame"),
                rrb.TextLogView(origin="log", name="skipped and dropped"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class RerunLogger:
    """Logs a run to Rerun: attach it with ``Odometry(..., logger=...)`` or
    :meth:`jaxvo.Odometry.attach`, and close it after the last frame, best with ``with``::

        with RerunLogger(save="run.rrd") as logger:
            odo = Odometry(K, logger=logger)
            for bgr, depth, t in frames:
                odo.process(bgr, depth, t)
        # run.rrd is whole here

    The recording is written whole or not at all (:class:`jaxvo.host.writers.outputs.OutputFile`):
    Rerun writes a temporary file beside ``save``, which replaces it when the logger closes
    (leaving a ``with`` block, also by Ctrl-C; or at the interpreter's exit for a logger
    never closed). A ``with`` block left by an error, or a write that fails (a full disk),
    leaves the earlier file as it was, and the error (``OSError``) names the file.

    Args:
      save: write the recording to this ``.rrd`` file (its folder must exist).
      spawn: open the Rerun viewer and stream to it (needs a display).
      name: the recording's application id (what the viewer calls it).
      what: how messages name the file (default ``save=``; ``--rerun-save`` in the CLI).
    Raises:
      InputError: rerun-sdk is not installed (the message names ``jaxvo[viz]``), neither
        ``save`` nor ``spawn`` is given, ``save`` cannot be written, or the viewer does not
        start (:data:`VIEWER_WAIT` seconds).
    """

    def __init__(self, *, save: str | Path | None = None, spawn: bool = False,
                 name: str = "jaxvo", what: str = "save="):
        rr = import_rerun()
        if save is None and not spawn:
            raise InputError("RerunLogger: give save=FILE.rrd, spawn=True or both")
        self.what = what
        self.rr = rr
        self._file = None
        self._closed = False
        self._warned_closed = False
        self._failed = False  # the file could not be written: Rerun's stream is let go
        if save is not None:
            save = output_file(save, what=what)
            self._file = OutputFile(save, what=what, open_file=False)
        try:
            self.rec = rr.RecordingStream(name)
            bp = blueprint()
            if spawn:
                _spawn_viewer(self.rec)
            sinks = [rr.GrpcSink()] if spawn else []
            if self._file is not None:
                sinks.append(rr.FileSink(str(self._file.temporary or self._file.target)))
            self._rerun(self.rec.set_sinks, *sinks, default_blueprint=bp)
        except BaseException:
            if self._file is not None:
                self._file.discard()
            raise
        self.K: Intrinsics | None = None
        self.cell = 0
        self.positions: list[np.ndarray] = []
        # the last kept frame: (index, timestamp, (n,) depth at the grid's cells, T_w_c)
        self.previous = None
        self.skipped = 0
        self.last_clock: float | None = None
        # encoding and logging run on one thread behind the run, in order
        self._writer = BackgroundWriter(limit=4)
        # a logger never closed is closed (its recording flushed, whole) when Python exits
        atexit.register(self._close_at_exit)

    def _rerun(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` of Rerun's; its ``RuntimeError`` (a full disk: "File-writer
        thread shut down prematurely") as an ``OSError`` naming the recording."""
        try:
            return fn(*args, **kwargs)
        except RuntimeError as exc:
            raise self._os_error(exc) from None

    def _os_error(self, exc: Exception) -> OSError:
        """Rerun's error as an ``OSError`` naming the recording: its cause where Rerun's
        message carries one ("(os error 28)") or the disk is full, else Rerun's words."""
        import re

        said = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if self._file is None:
            return OSError(errno.EIO, f"the Rerun viewer: {said}")
        self._failed = True
        code = re.search(r"\(os error (\d+)\)", str(exc))
        number = int(code[1]) if code else (
            errno.ENOSPC if _disk_full(self._file.target.parent) else None)
        why = os.strerror(number) if number else f"Rerun could not write it ({said})"
        return OSError(number or errno.EIO, why, str(self._file.path))

    def setup(self, intrinsics: Intrinsics, cell: int) -> None:
        """The camera and grid of the run (called by :meth:`jaxvo.Odometry.attach`)."""
        self.K, self.cell = intrinsics, cell

    def _time(self, index: int, timestamp: float) -> None:
        self.rec.set_time("time", timestamp=float(timestamp))
        self.rec.set_time("frame", sequence=int(index))

    def _start(self, height: int, width: int) -> None:
        """What does not change: the frustum (of the images as logged, SCALE times the
        camera's) and the identifiers' colours and names."""
        rr, K = self.rr, self.K
        self.size = (round(height * SCALE), round(width * SCALE))
        self.uv = grid_pixels(height, width, self.cell)
        self.rows, self.cols = height // self.cell, width // self.cell
        self.rec.log("world/camera/image", rr.Pinhole(
            focal_length=[K.fx * SCALE, K.fy * SCALE],
            principal_point=[(K.cx + 0.5) * SCALE - 0.5, (K.cy + 0.5) * SCALE - 0.5],
            width=self.size[1], height=self.size[0], camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.3), static=True)
        info = [(0, "unknown", (0, 0, 0)), (1, "static", tuple(_PALETTE[1][::-1]))]
        info += [(i, f"moving {i}", tuple(_PALETTE[(i - 1) % (len(_PALETTE) - 1) + 1][::-1]))
                 for i in range(2, 64)]
        self.rec.log("world", rr.AnnotationContext(
            [rr.AnnotationInfo(id=i, label=lab, color=c) for i, lab, c in info]), static=True)
        self.rec.log("stats", rr.SeriesLines(names=list(STATS)), static=True)

    def log_frame(self, r, bgr: np.ndarray, depth: np.ndarray) -> None:
        """One frame's result (:class:`jaxvo.odometry.FrameResult`) with the images it came
        from (``bgr`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres, neither changed
        afterwards): queued, and logged on the logger's thread. After :meth:`close`, nothing
        is logged (a warning says so once)."""
        if self._closed:
            if not self._warned_closed:
                self._warned_closed = True
                warnings.warn("RerunLogger: frames after close() are not logged (its recording "
                              "is complete); attach a new logger to record them",
                              RuntimeWarning, stacklevel=3)
            return
        now = time.perf_counter()
        ms = None if self.last_clock is None else 1e3 * (now - self.last_clock)
        self.last_clock = now
        self._writer.submit(self._rerun, self._log_frame, r, bgr, depth, ms)

    def _log_frame(self, r, bgr: np.ndarray, depth: np.ndarray, ms: float | None) -> None:
        import cv2

        rr, rec = self.rr, self.rec
        self._time(r.index, r.timestamp)
        if r.dropped is not None:
            rec.log("log", rr.TextLog(f"frame {r.index} dropped: {r.dropped}", level="WARN"))
            return
        if self.previous is None:
            self._start(*depth.shape)
        T = np.asarray(r.T_w_c, np.float64)
        rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        h2, w2 = self.size
        small = cv2.resize(bgr, (w2, h2), interpolation=cv2.INTER_AREA)
        jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1]
        # a uint8 array, not bytes: rerun takes bytes far slower
        rec.log("world/camera/image/rgb", rr.EncodedImage(contents=jpeg.ravel(),
                                                          media_type="image/jpeg"))
        rec.log("world/camera/image/depth", rr.DepthImage(
            cv2.resize(depth, (w2, h2), interpolation=cv2.INTER_NEAREST), meter=1.0))
        self.positions.append(T[:3, 3])
        rec.log("world/trajectory", rr.LineStrips3D([np.asarray(self.positions)],
                                                    colors=[(255, 200, 0)]))
        if r.output is not None and self.previous is not None:
            self._log_pair(r, ms)
        h, w = depth.shape
        z = depth[np.clip(np.rint(self.uv[:, 1]).astype(int), 0, h - 1),
                  np.clip(np.rint(self.uv[:, 0]).astype(int), 0, w - 1)]
        self.previous = (r.index, r.timestamp, z, T)

    def _log_pair(self, r, ms: float | None) -> None:
        """A frame pair's numbers (:data:`STATS`) at this frame's time, its labels at the
        time of the image they lie on (the previous one)."""
        rr, rec = self.rr, self.rec
        ids = np.asarray(r.ids)
        if int(r.status) != 0:  # Status.OK
            self.skipped += 1
            rec.log("log", rr.TextLog(f"pair to frame {r.index} skipped: {r.status.reason}",
                                      level="WARN"))
        rec.log("stats", rr.Scalars([100.0 * float(np.mean(r.static)),
                                     100.0 * float(np.mean(r.output.moving)),
                                     np.nan if ms is None else ms, float(self.skipped)]))
        index, t, z, T = self.previous
        self._time(index, t)
        rec.log("world/camera/image/ids", rr.SegmentationImage(self._cells_image(ids)))
        uv = self.uv
        ok = z > 0
        cam = np.stack([(uv[:, 0] - self.K.cx) / self.K.fx * z,
                        (uv[:, 1] - self.K.cy) / self.K.fy * z, z], -1)[ok]
        rec.log("world/points", rr.Points3D(cam @ T[:3, :3].T + T[:3, 3], class_ids=ids[ok],
                                            radii=0.01))

    def _cells_image(self, ids: np.ndarray) -> np.ndarray:
        """(n,) per-cell identifiers as an image of the logged size, each cell a block (the
        strip right and below the last full cell takes the nearest cell's)."""
        import cv2

        h2, w2 = self.size
        grid = np.minimum(ids, 255).astype(np.uint8).reshape(self.rows, self.cols)
        cell = self.cell * SCALE
        block = cv2.resize(grid, (round(self.cols * cell), round(self.rows * cell)),
                           interpolation=cv2.INTER_NEAREST)
        return cv2.copyMakeBorder(block, 0, h2 - block.shape[0], 0, w2 - block.shape[1],
                                  cv2.BORDER_REPLICATE)

    def log_groundtruth(self, gt) -> None:
        """The sequence's ground truth (a :class:`jaxvo.trajectory.Trajectory`), static."""
        if gt is not None and len(gt) and not self._closed:
            self._rerun(self.rec.log, "world/groundtruth", self.rr.LineStrips3D(
                [gt.poses[:, :3, 3]], colors=[(80, 220, 80)]), static=True)

    def log_map(self, name: str, pmap) -> None:
        """A fused map (:class:`jaxvo.host.writers.mapping.PointMap`) as ``world/map/<name>``, static."""
        if not self._closed:
            self._rerun(self.rec.log, f"world/map/{name}", self.rr.Points3D(
                pmap.points, colors=pmap.colours, radii=0.01), static=True)

    def close(self) -> None:
        """Log what is queued, write out everything logged and put the recording in place
        (whole after this). Idempotent.

        Raises:
          OSError: naming the file, when it could not be written (the earlier file stays);
            an error on the logger's thread.
        """
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self._close_at_exit)
        try:
            self._writer.close()
            self._flush()
            self.rec.disconnect()
            # Rerun writes the end of the stream on disconnect and, where that fails, only
            # logs it: a disk left full here most likely cut it
            if (self._file is not None and self._file.temporary is not None
                    and _disk_full(self._file.target.parent)):
                raise self._os_error(RuntimeError("(os error 28)"))
        except BaseException:
            if self._file is not None:
                self._file.discard()
            self._let_go()
            raise
        if self._file is not None:
            self._file.commit()

    def abandon(self) -> None:
        """Stop logging and leave the earlier recording as it was (an error ended the run)."""
        if self._closed:
            return
        self._closed = True
        atexit.unregister(self._close_at_exit)
        with contextlib.suppress(Exception):
            self._writer.close()
        if self._file is not None:
            self._file.discard()
        self._let_go()

    def _let_go(self) -> None:
        """After the file failed: Rerun's stream left alone to the process's end. Its own
        clean-up (a flush when the stream is collected, then a disconnect of the streams
        no one holds, and a flush of every stream at exit) waited for ever on a file
        writer stuck on a full disk, so that the process never ended and never said why.
        Rerun's flush at exit goes too: it flushes every stream of the process, this one
        included."""
        if not self._failed:
            return
        rec = self.rec
        # what RecordingStream.__del__ calls (rerun-sdk 0.41 keeps them on the instance)
        rec._flush = lambda **kwargs: None
        rec._disconnect_orphaned_recordings = lambda: None
        _LET_GO.append(rec)  # never collected
        self.rr.unregister_shutdown()

    def _flush(self) -> None:
        """Wait until Rerun has written everything logged. A file sink that stops growing
        while the flush does not finish has failed (Rerun's writer thread stops on a full
        disk; a flush would then time out, and a disconnect hang)."""
        size = -1
        while True:
            try:
                self.rec.flush(timeout_sec=FLUSH_WAIT)
                return
            except RuntimeError as exc:
                if self._file is None:  # the viewer went away (closed): the run is whole
                    warnings.warn(f"the Rerun viewer stopped taking the run "
                                  f"({str(exc).splitlines()[0]})", RuntimeWarning, stacklevel=3)
                    return
                grown = (self._file is not None and self._file.temporary is not None
                         and _size(self._file.temporary) != size)
                if not grown:
                    raise self._os_error(exc) from None
                size = _size(self._file.temporary)

    def _close_at_exit(self) -> None:
        with contextlib.suppress(Exception):
            self.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # Ctrl-C keeps what was recorded (whole), as the trajectory does; an error does not
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            self.abandon()


# the Rerun streams whose file failed, held to the process's end (RerunLogger._let_go)
_LET_GO: list = []
# The viewer is given this long to start listening (seconds); Rerun's own gRPC client waits
# about as long and then fails at the end of the run with a traceback
VIEWER_WAIT = 10.0
# one wait of a flush, seconds; flushes go on while the recording grows
FLUSH_WAIT = 2.0
# Rerun's default port, where rec.spawn starts the viewer and GrpcSink() connects
_VIEWER_PORT = 9876


def _spawn_viewer(rec) -> None:
    """Start the Rerun viewer (or find one running) and wait until it listens, or raise an
    :class:`InputError` in one line saying why it does not (no viewer executable, no
    display it could open)."""
    import socket

    port = _VIEWER_PORT
    try:
        rec.spawn(connect=False, port=port)
    except RuntimeError as exc:
        raise InputError(f"--rerun: the Rerun viewer cannot start ({str(exc).strip().splitlines()[0]}"
                         "); write a recording with --rerun-save FILE.rrd instead") from None
    deadline = time.monotonic() + VIEWER_WAIT
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise InputError(
                    f"--rerun: the Rerun viewer did not start listening on port {port} within "
                    f"{VIEWER_WAIT:g} s (no display it can open?); write a recording with "
                    "--rerun-save FILE.rrd instead") from None
            time.sleep(0.2)


def _size(path: Path) -> int:
    try:
        return os.stat(path).st_size
    except OSError:
        return -1


def _disk_full(folder: Path) -> bool:
    """Whether the file system of ``folder`` has no block left for this user."""
    try:
        return os.statvfs(folder).f_bavail == 0
    except OSError:
        return False
