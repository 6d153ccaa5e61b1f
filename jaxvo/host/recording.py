"""A Rerun recording of a run (host side): what jaxvo sees, frame by frame.

Rerun (``rerun-sdk``, the optional extra ``jaxvo[viz]``) is a viewer and a recording format
(``.rrd``) that opens on any machine. :class:`RerunLogger` is attached to an
:class:`jaxvo.Odometry` (``jaxvo run --rerun`` / ``--rerun-save FILE.rrd`` attach one) and
logs, on one timeline per frame timestamp (``time``, and ``frame``, the frame's index):

==============================  ==========================================================
``world/camera``                the camera's pose (``Transform3D``, camera-to-world)
``world/camera/image``          its frustum (``Pinhole``, static)
``world/camera/image/rgb``      the colour image
``world/camera/image/depth``    the depth (metres)
``world/camera/image/ids``      the grid cells' identifiers (0 unknown, 1 static, >= 2 a
                                moving object), on the image the frame pair starts at
``world/points``                that image's grid points in the world, by identifier
``world/trajectory``            the trajectory so far
``world/groundtruth``           the ground truth, where the sequence has it (static)
``world/map/static``, ``/full`` the fused maps (:mod:`jaxvo.host.mapping`; static)
``stats/...``                   points used in the fit, moving share of the grid, skipped
                                pairs so far, ms per frame
``log``                         why a pair was skipped or a frame dropped
==============================  ==========================================================

A pair's labels lie on the image it starts at (as ``--masks`` files are named), so they are
logged at that image's time, one frame after the pose. With ``Config.window`` the poses are
the immediate ones (each refined once), as :attr:`Odometry.trajectory` holds them.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from jaxvo.errors import InputError
from jaxvo.host.camera import Intrinsics, grid_pixels
from jaxvo.host.masks import _PALETTE, grid_to_pixels
from jaxvo.host.prefetch import BackgroundWriter

EXTRA = "pip install 'jaxvo[viz]'"
# the colour image's JPEG quality: a raw 640x480 image is 0.9 MB a frame, a recording of a
# 1000-frame run 2 GB; at 90 it is about a tenth of that and looks the same
JPEG_QUALITY = 90


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
    """Logs a run to Rerun: attach it with ``Odometry(..., logger=RerunLogger(save=...))``
    or :meth:`jaxvo.Odometry.attach`.

    Args:
      save: write the recording to this ``.rrd`` file.
      spawn: open the Rerun viewer and stream to it (needs a display).
      name: the recording's application id (what the viewer calls it).
    Raises:
      InputError: rerun-sdk is not installed (the message names ``jaxvo[viz]``), or neither
        ``save`` nor ``spawn`` is given.
    """

    def __init__(self, *, save: str | Path | None = None, spawn: bool = False,
                 name: str = "jaxvo"):
        rr = import_rerun()
        if save is None and not spawn:
            raise InputError("RerunLogger: give save=FILE.rrd, spawn=True or both")
        self.rr = rr
        self.rec = rr.RecordingStream(name)
        bp = blueprint()
        if spawn:
            self.rec.spawn(connect=False)
        sinks = ([rr.GrpcSink()] if spawn else []) + ([rr.FileSink(str(save))] if save else [])
        self.rec.set_sinks(*sinks, default_blueprint=bp)
        self.K: Intrinsics | None = None
        self.cell = 0
        self.positions: list[np.ndarray] = []
        self.previous = None  # (index, timestamp, bgr, depth, T_w_c) of the last kept frame
        self.skipped = 0
        self.last_clock: float | None = None
        # encoding and logging run on one thread behind the run, in order
        self._writer = BackgroundWriter(limit=4)

    def setup(self, intrinsics: Intrinsics, cell: int) -> None:
        """The camera and grid of the run (called by :meth:`jaxvo.Odometry.attach`)."""
        self.K, self.cell = intrinsics, cell

    def _time(self, index: int, timestamp: float) -> None:
        self.rec.set_time("time", timestamp=float(timestamp))
        self.rec.set_time("frame", sequence=int(index))

    def _start(self, height: int, width: int) -> None:
        """What does not change: the frustum and the identifiers' colours and names."""
        rr, K = self.rr, self.K
        self.rec.log("world/camera/image", rr.Pinhole(
            focal_length=[K.fx, K.fy], principal_point=[K.cx, K.cy], width=width,
            height=height, camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3),
            static=True)
        info = [(0, "unknown", (0, 0, 0)), (1, "static", tuple(_PALETTE[1][::-1]))]
        info += [(i, f"moving {i}", tuple(_PALETTE[(i - 1) % (len(_PALETTE) - 1) + 1][::-1]))
                 for i in range(2, 64)]
        self.rec.log("world", rr.AnnotationContext(
            [rr.AnnotationInfo(id=i, label=lab, color=c) for i, lab, c in info]), static=True)

    def log_frame(self, r, bgr: np.ndarray, depth: np.ndarray) -> None:
        """One frame's result (:class:`jaxvo.odometry.FrameResult`) with the images it came
        from (``bgr`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres, neither changed
        afterwards): queued, and logged on the logger's thread."""
        now = time.perf_counter()
        ms = None if self.last_clock is None else 1e3 * (now - self.last_clock)
        self.last_clock = now
        self._writer.submit(self._log_frame, r, bgr, depth, ms)

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
        jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1]
        rec.log("world/camera/image/rgb", rr.EncodedImage(contents=jpeg.tobytes(),
                                                          media_type="image/jpeg"))
        mm = np.minimum(np.rint(depth * 1000.0), 65535).astype(np.uint16)  # half the bytes
        rec.log("world/camera/image/depth", rr.DepthImage(mm, meter=1000.0))
        self.positions.append(T[:3, 3])
        rec.log("world/trajectory", rr.LineStrips3D([np.asarray(self.positions)],
                                                    colors=[(255, 200, 0)]))
        if ms is not None:
            rec.log("stats/ms", rr.Scalars(ms))
        if r.output is not None and self.previous is not None:
            self._log_pair(r)
        self.previous = (r.index, r.timestamp, depth, T)

    def _log_pair(self, r) -> None:
        """A frame pair's numbers at this frame's time, its labels at the time of the image
        they lie on (the previous one)."""
        rr, rec = self.rr, self.rec
        ids = np.asarray(r.ids)
        rec.log("stats/points_used", rr.Scalars(float(np.sum(r.static))))
        rec.log("stats/moving_share", rr.Scalars(float(np.mean(r.output.moving))))
        if int(r.status) != 0:  # Status.OK
            self.skipped += 1
            rec.log("log", rr.TextLog(f"pair to frame {r.index} skipped: {r.status.reason}",
                                      level="WARN"))
        rec.log("stats/skipped_pairs", rr.Scalars(float(self.skipped)))
        index, t, depth, T = self.previous
        h, w = depth.shape
        self._time(index, t)
        rec.log("world/camera/image/ids",
                rr.SegmentationImage(grid_to_pixels(ids.astype(np.uint8), h, w, self.cell)))
        uv = grid_pixels(h, w, self.cell)
        z = depth[np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1),
                  np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)]
        ok = z > 0
        cam = np.stack([(uv[:, 0] - self.K.cx) / self.K.fx * z,
                        (uv[:, 1] - self.K.cy) / self.K.fy * z, z], -1)[ok]
        rec.log("world/points", rr.Points3D(cam @ T[:3, :3].T + T[:3, 3], class_ids=ids[ok],
                                            radii=0.01))

    def log_groundtruth(self, gt) -> None:
        """The sequence's ground truth (a :class:`jaxvo.host.io.Trajectory`), static."""
        if gt is not None and len(gt):
            self.rec.log("world/groundtruth", self.rr.LineStrips3D(
                [gt.poses[:, :3, 3]], colors=[(80, 220, 80)]), static=True)

    def log_map(self, name: str, pmap) -> None:
        """A fused map (:class:`jaxvo.host.mapping.PointMap`) as ``world/map/<name>``, static."""
        self.rec.log(f"world/map/{name}", self.rr.Points3D(pmap.points, colors=pmap.colours,
                                                           radii=0.01), static=True)

    def close(self) -> None:
        """Log what is queued and write out everything logged (the file is complete after
        this; an error on the logger's thread is raised here)."""
        try:
            self._writer.close()
        finally:
            self.rec.flush()
            self.rec.disconnect()
