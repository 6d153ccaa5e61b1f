"""Peer odometry on the same frames: OpenCV's ``cv2.Odometry`` (RGB, DEPTH, RGB_DEPTH) and
Open3D's RGB-D odometry when it is installed (host side).

Each peer runs frame to frame like jaxvo (no keyframes, no loop closure) and returns a
camera-to-world :class:`~jaxvo.trajectory.Trajectory` starting at the sequence's first pose, so
ATE and RPE compare like with like. An optional per-frame ``keep`` mask (``True`` = may be
used) lets any peer ignore pixels, which is how jaxvo's segmentation plugs into them
(thesis Fig. 5.8, "Proposed x DVO").
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import cv2
import numpy as np

from jaxvo.host.frontend.camera import Intrinsics
from jaxvo.trajectory import Trajectory

OPENCV_PEERS = {
    "opencv_rgb": cv2.OdometryType_RGB,
    "opencv_depth": cv2.OdometryType_DEPTH,
    "opencv_rgbd": cv2.OdometryType_RGB_DEPTH,
}
OPEN3D_PEERS = ("open3d_color", "open3d_hybrid")


def available_peers() -> list[str]:
    """Peer names that can run here (Open3D ones only when ``open3d`` imports)."""
    names = list(OPENCV_PEERS)
    try:
        import open3d  # noqa: F401

        names += list(OPEN3D_PEERS)
    except ImportError:
        pass
    return names


class PeerRun(NamedTuple):
    trajectory: Trajectory
    failures: int  # frame pairs where the peer reported failure (pose carried)
    ms_per_frame: float  # median wall time per frame pair, milliseconds


def _opencv_step(kind: str, K: Intrinsics):
    settings = cv2.OdometrySettings()
    settings.setCameraMatrix(K.matrix().astype(np.float32))
    odo = cv2.Odometry(OPENCV_PEERS[kind], settings, cv2.OdometryAlgoType_COMMON)

    def prepare(frame, keep):
        gray = cv2.cvtColor(frame.bgr, cv2.COLOR_BGR2GRAY)
        depth = np.ascontiguousarray(frame.depth, np.float32)
        use = frame.depth > 0 if keep is None else keep & (frame.depth > 0)
        # OpenCV reads only 255 as "use this pixel": a 0/1 mask makes every compute() fail
        mask = np.where(use, np.uint8(255), np.uint8(0))
        return cv2.OdometryFrame(depth, gray, mask)

    def motion(prev, cur):
        odo.prepareFrames(prev, cur)
        ok, Rt = odo.compute(prev, cur)  # Rt maps previous-frame points to the current frame
        return bool(ok), Rt

    return prepare, motion


def _open3d_step(kind: str, K: Intrinsics, height: int, width: int):
    import open3d as o3d

    intr = o3d.camera.PinholeCameraIntrinsic(width, height, K.fx, K.fy, K.cx, K.cy)
    jac = (
        o3d.pipelines.odometry.RGBDOdometryJacobianFromColorTerm()
        if kind == "open3d_color"
        else o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()
    )
    option = o3d.pipelines.odometry.OdometryOption()

    def prepare(frame, keep):
        rgb = cv2.cvtColor(frame.bgr, cv2.COLOR_BGR2RGB)
        depth = frame.depth if keep is None else np.where(keep, frame.depth, 0.0)
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(rgb)),
            o3d.geometry.Image(np.ascontiguousarray(depth, np.float32)),
            depth_scale=1.0,
            depth_trunc=10.0,
            convert_rgb_to_intensity=True,
        )

    def motion(prev, cur):
        # Open3D returns the transform taking source (prev) points into the target (cur)
        ok, T, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            prev, cur, intr, np.eye(4), jac, option
        )
        return bool(ok), np.asarray(T)

    return prepare, motion


def run_peer(
    seq,
    kind: str,
    *,
    keep: Callable[[int], np.ndarray] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> PeerRun:
    """Run one peer frame to frame over ``seq``.

    Args:
      seq: a sequence (``len``, ``seq[i] -> Frame``, ``intrinsics``, ``timestamps``,
        optional ``groundtruth`` whose first pose anchors the trajectory).
      kind: a name from :func:`available_peers`.
      keep: optional ``index -> (H, W) bool`` mask of pixels the peer may use.
      progress: optional ``callback(done, total)``.
    """
    if kind in OPENCV_PEERS:
        prepare, motion = _opencv_step(kind, seq.intrinsics)
    elif kind in OPEN3D_PEERS:
        prepare, motion = _open3d_step(kind, seq.intrinsics, seq.height, seq.width)
    else:
        raise ValueError(f"unknown peer {kind!r}; choose one of {', '.join(available_peers())}")

    n = len(seq)
    poses = np.empty((n, 4, 4))
    gt = getattr(seq, "groundtruth", None)
    poses[0] = gt.poses[0] if gt is not None and len(gt) == n else np.eye(4)
    prev = prepare(seq[0], None if keep is None else keep(0))
    failures, times = 0, []
    for i in range(1, n):
        cur = prepare(seq[i], None if keep is None else keep(i))
        t0 = time.perf_counter()
        ok, T_cur_prev = motion(prev, cur)
        times.append(time.perf_counter() - t0)
        if not ok or not np.all(np.isfinite(T_cur_prev)):
            failures += 1
            T_cur_prev = np.eye(4)
        poses[i] = poses[i - 1] @ np.linalg.inv(T_cur_prev)
        prev = cur
        if progress is not None:
            progress(i, n - 1)
    ms = 1e3 * float(np.median(times)) if times else 0.0
    return PeerRun(Trajectory(np.asarray(seq.timestamps, np.float64), poses), failures, ms)
