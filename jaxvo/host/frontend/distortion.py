"""Lens distortion undone at points, never over whole images (host side, numpy and OpenCV).

A calibrated camera's image is the pinhole image warped by its lens. jaxvo tracks the grid
in the image as it comes and undoes the warp only where a point is turned into a ray: the
grid points and their tracked positions (:func:`undistort`, from
:func:`jaxvo.host.frontend.camera.backproject`), a few thousand pixels a frame where remapping both
images would touch every pixel. The depth is read at the pixel itself: a depth image
registered to the colour camera holds each colour pixel's reading where that pixel is.

OpenCV's models (ROS's ``plumb_bob``, ``rational_polynomial``) are undone by
``cv2.undistortPointsIter`` (OpenCV 5: ``cv2.undistortPoints`` with a stopping rule);
librealsense's inverse and modified Brown-Conrady as its ``rs2_deproject_pixel_to_point``
does, by fixed-point iteration.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

import numpy as np

# Lens models whose distortion jaxvo undoes, and the names of their coefficients in order.
# plumb_bob and rational_polynomial are ROS's names for OpenCV's 5- and 8-coefficient
# models; librealsense's Brown-Conrady is plumb_bob. Its "inverse" and "modified"
# Brown-Conrady map a point to its pixel alike (radial factor first, the tangential terms
# on the radially distorted point), which the current librealsense inverts by iteration
# (``rs2_deproject_pixel_to_point``); before its 2021 fix (librealsense pull request 8523)
# it applied inverse Brown-Conrady's polynomial to the pixel directly, the coefficients
# read as the inverse model.
DISTORTION_MODELS: dict[str, tuple[str, ...]] = {
    "plumb_bob": ("k1", "k2", "p1", "p2", "k3"),
    "rational_polynomial": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "inverse_brown_conrady": ("k1", "k2", "p1", "p2", "k3"),
    "modified_brown_conrady": ("k1", "k2", "p1", "p2", "k3"),
}


class Distortion(NamedTuple):
    """A lens's distortion: its model (a name of :data:`DISTORTION_MODELS`) and coefficients
    in that model's order (:func:`jaxvo.host.frontend.camera.distortion` checks and builds one)."""

    model: str
    coeffs: tuple[float, ...]

    def describe(self) -> str:
        """The model and its coefficients in one line (``plumb_bob k1=0.26 k2=-0.95 ...``)."""
        names = DISTORTION_MODELS[self.model]
        return " ".join([self.model] + [f"{n}={v:.7g}" for n, v in zip(names, self.coeffs)])


class Camera(Protocol):
    """What the functions here read of a camera (:class:`jaxvo.host.frontend.camera.Intrinsics`)."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: Distortion | None

    def matrix(self) -> np.ndarray: ...


# A point is undone when its ray, distorted again, lands within this many pixels of it;
# OpenCV's own default (5 iterations, no tolerance) leaves 0.08 pixels at the corners of a
# Kinect's image under TUM's fr1 coefficients, as much as LK's own error.
UNDISTORT_PX = 1e-4
UNDISTORT_ITERS = 50
_OPENCV = ("plumb_bob", "rational_polynomial")


def undistort(uv: np.ndarray, K: Camera) -> np.ndarray:
    """The rays of pixels seen through ``K``'s lens, as normalised image coordinates.

    Args:
      uv: (..., 2) pixels (x right, y down) in the distorted image.
      K: the camera, with its ``distortion`` (None: the pinhole's rays).
    Returns:
      (..., 2) float64 ``(x / z, y / z)`` of each pixel's ray.
    """
    uv = np.asarray(uv, np.float64)
    d = K.distortion
    if d is None:
        return np.stack([(uv[..., 0] - K.cx) / K.fx, (uv[..., 1] - K.cy) / K.fy], axis=-1)
    if d.model in _OPENCV:
        import cv2  # loaded by the lens that needs it: host.frontend.camera imports this module

        pts = uv.reshape(-1, 1, 2)
        if len(pts) == 0:
            return np.zeros(uv.shape, np.float64)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, UNDISTORT_ITERS,
                    UNDISTORT_PX)
        M, D = K.matrix(), np.asarray(d.coeffs, np.float64)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
            out = cv2.undistortPointsIter(pts, M, D, None, None, criteria)
        else:  # OpenCV 5 takes the stopping rule in undistortPoints itself
            out = cv2.undistortPoints(pts, M, D, None, None, None, criteria)
        return out.reshape(uv.shape)
    return _undo_brown_conrady(uv, K, d)


def _undo_brown_conrady(uv: np.ndarray, K: Camera, d: Distortion) -> np.ndarray:
    """librealsense's inverse (and modified) Brown-Conrady undone by its fixed-point
    iteration, run to :data:`UNDISTORT_PX` rather than its 10 fixed rounds."""
    k1, k2, p1, p2, k3 = d.coeffs
    x0 = (uv[..., 0] - K.cx) / K.fx
    y0 = (uv[..., 1] - K.cy) / K.fy
    x, y = x0.copy(), y0.copy()
    tol = UNDISTORT_PX / max(abs(K.fx), abs(K.fy))
    for _ in range(UNDISTORT_ITERS):
        r2 = x * x + y * y
        icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        xq, yq = x / icdist, y / icdist
        dx = 2 * p1 * xq * yq + p2 * (r2 + 2 * xq * xq)
        dy = 2 * p2 * xq * yq + p1 * (r2 + 2 * yq * yq)
        x_new, y_new = (x0 - dx) * icdist, (y0 - dy) * icdist
        step = np.max(np.abs(np.concatenate([(x_new - x).ravel(), (y_new - y).ravel()])),
                      initial=0.0)
        x, y = x_new, y_new
        if step < tol:
            break
    return np.stack([x, y], axis=-1)


def distort(xn: np.ndarray, K: Camera) -> np.ndarray:
    """The pixels where rays land through ``K``'s lens (the inverse of :func:`undistort`).

    Args:
      xn: (..., 2) normalised image coordinates ``(x / z, y / z)``.
      K: the camera and its ``distortion`` (None: the pinhole).
    Returns:
      (..., 2) float64 pixels.
    """
    xn = np.asarray(xn, np.float64)
    x, y = xn[..., 0], xn[..., 1]
    d = K.distortion
    if d is not None:
        c = list(d.coeffs) + [0.0] * (8 - len(d.coeffs))
        k1, k2, p1, p2, k3, k4, k5, k6 = c
        r2 = x * x + y * y
        radial = ((1 + ((k3 * r2 + k2) * r2 + k1) * r2)
                  / (1 + ((k6 * r2 + k5) * r2 + k4) * r2))
        if d.model in _OPENCV:  # the tangential terms on the undistorted point
            x, y = (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                    y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y))
        else:  # librealsense's: on the radially distorted point
            xq, yq = x * radial, y * radial
            x, y = (xq + 2 * p1 * xq * yq + p2 * (r2 + 2 * xq * xq),
                    yq + 2 * p2 * xq * yq + p1 * (r2 + 2 * yq * yq))
    return np.stack([K.fx * x + K.cx, K.fy * y + K.cy], axis=-1)
