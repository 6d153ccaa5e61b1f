"""The error budget of jaxvo's pose beside ORB-SLAM3's, on the same frames (issue 43).

Given the same knowledge of what moves, where does jaxvo lose precision that ORB-SLAM3 keeps?
On the static 7-Scenes frames (``bench/splits.py``'s ``static_dev_every<k>`` and
``static_val_every<k>``, k = 1, 2, 4, and the whole 300 frames, ``static_all_every<k>``)
and on the TUM walking clip with the people's depth
removed (``bench_seeds.reference_case``, scored against TUM's ground truth), per frame pair
against the ground truth:

1. **Relative pose errors** of jaxvo (``--seeds`` seeds, ``bench_seeds.run_seeds``) and of
   ORB-SLAM3 (RGB-D, one run in its own process, ``orbslam3_peer.run_orbslam3``; its
   trajectory is associated with the frames by timestamp, so frames before its
   initialisation are left out), rotation (deg) and translation (mm) apart, over all pairs
   1, 10 and 30 frames apart. A random walk of independent per-frame errors grows as
   sqrt(k), a drift (bias) as k: the growth exponent ``log(RPE_k / RPE_1) / log(k)`` says
   which (0.5 against 1; a rotation's random walk turns into translation error growing
   faster still, as eps * d). Two hybrid trajectories split the translation error: each
   frame's estimated rotation with the true translation step (what the rotation errors
   alone do to the position over k frames) and the true rotation with the estimated
   translation step. Per frame, the mean error vector's share of the mean squared error
   (the bias share) and the scale of the estimated steps against the true ones.
2. **The points** the ego-motion used (``StepOutput.static``): how many, at what depth,
   where on the image (the share in each third of the width and of the height, and the
   largest share in one of the 3 x 3 regions), and the Cramer-Rao bound of the pose that
   they give under the sensor noise model (image position and depth along the ray, each in
   its noise units, ``jaxvo.core.noise.point_noise``'s sigmas): a fit whose points are few,
   in one region or at one depth has a large bound. Beside it, the noise of those points
   measured under the true motion, over the model's (1 = the model holds).
3. **Oracles**, each replacing one thing with the truth, the rest unchanged, on the same
   frames and seeds, chained frame to frame into a trajectory (frames where jaxvo skipped
   the pair or the ground truth lacks a pose keep jaxvo's motion):

   * *refit*: ``fit_egomotion`` on the points jaxvo used, from jaxvo's own motion: the
     control, which should reproduce jaxvo;
   * *(i) from the truth*: the same fit on the same points, the true motion among its
     starts: does the optimiser find the minimum of its cost?
   * *(ii) points' floor*: Gauss-Newton from the true motion on the same points, each
     point's image-plane and depth residuals in the noise model's units (Huber beyond the
     inlier test): the pose that the points' own noise leaves when the cost is the
     sensor's; also with all valid points (*(ii) all valid*);
   * *(iii) all valid points*: ``fit_egomotion`` from jaxvo's motion on every valid point
     instead of those the background and the re-weighting chose (its robust re-weighting
     still on): what the choice leaves out or lets in;
   * *(iv) keyframes*: jaxvo with ``Config(keyframes=True)`` (its local window): what
     chaining frame to frame costs.
4. **The path's length**: the ATE after a rigid and after a similarity alignment, that
   similarity's scale, and the slope of the estimated relative translations on the true
   ones per axis of the camera (:func:`length_budget`): whether the path is too short or
   long, and across the view (the image's scale) or along it (the depth's).

Beside them **the bar** of issue 43: jaxvo's median ATE against ORB-SLAM3's (the median of
its runs) and every OpenCV and Open3D peer's (``jaxvo.host.services.peers``, one run each).

Writes ``budget.md`` and ``budget.json`` under ``--out``; ORB-SLAM3's trajectories are kept
under ``--runs`` (``--orbslam3-runs`` runs per case, default 1, the run of median ATE
budgeted; delete the files to run it again).

Run: ``.venv/bin/python bench/bench_budget.py [--only CASE ...] [--seeds 5]
[--orbslam3-runs 1] [--cache results/cache] [--runs results/budget_runs] [--out results/]``.
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer
from _common import (
    SEVEN_SCENES,
    first_pose,
    groundtruth,
    load_average,
    log,
    machine,
    markdown_table,
)
from _options import check_options, count
from bench_robustness import CFG, frames_hash, peers_alone, prepare
from bench_seeds import reference_case, run_seeds
from splits import HALF, Case, cases, runnable, static_case

from jaxvo.config import Config, Params, params_as_arrays
from jaxvo.core.egomotion import fit_egomotion
from jaxvo.core.inputs import GridFlow
from jaxvo.core.points import frame_points
from jaxvo.evaluation.metrics import align_umeyama, ate
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import write_trajectory
from jaxvo.host.services.peers import OPEN3D_PEERS, OPENCV_PEERS, available_peers
from jaxvo.host.writers.outputs import write_text
from jaxvo.status import Status
from jaxvo.trajectory import Trajectory, pose_at, read_trajectory
from jaxvo.transforms import invert_pose, relative_pose, rotation_angle

DELTAS = (1, 10, 30)
KEYFRAMES = Config(keyframes=True)
MAX_DIFF = 0.02  # seconds: association of a trajectory with the frames
# Huber corner of the points' floor, in noise units of the whole residual: the square root
# of chi2_3(0.99), the pipeline's inlier test at its default confidence
_HUBER = float(np.sqrt(11.345))
_CHI2_1_MEDIAN, _CHI2_2_MEDIAN = 0.45494, 1.38629


def budget_cases() -> list[Case]:
    """The static 7-Scenes cases of both splits, the whole 300 frames (``static_all_*``:
    issue 43's target, not a split: it holds the development frames) and the TUM clip
    without the people's depth."""
    out = [c for c in cases() if c.kind == "static"]
    out += [Case(f"static_all_every{k}", "all", "static", SEVEN_SCENES,
                 static_case(0, k, 2 * HALF)) for k in (1, 2, 4)]
    out += [reference_case(c) for c in cases() if c.name == "tum_walking"]
    return out


# ------------------------------------------------------------------ poses per frame


def at_frames(traj: Trajectory, stamps) -> np.ndarray:
    """(N, 4, 4) float64 the pose of ``traj`` at each of ``stamps`` (nearest within
    ``MAX_DIFF`` s), NaN where it has none."""
    out = np.full((len(stamps), 4, 4), np.nan)
    for i, t in enumerate(stamps):
        p = pose_at(traj, float(t), max_diff=MAX_DIFF)
        if p is not None:
            out[i] = p
    return out


def chain(T0, motions) -> np.ndarray:
    """(T + 1, 4, 4) camera poses from ``T0`` and the motions ``T_cur_prev`` (T, 4, 4)."""
    poses = [np.asarray(T0, np.float64)]
    for M in np.asarray(motions, np.float64):
        poses.append(poses[-1] @ invert_pose(M))
    return np.stack(poses)


def _so3_log(R) -> np.ndarray:
    """(..., 3) rotation vectors (radians) of rotation matrices (..., 3, 3)."""
    angle = rotation_angle(R)
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                     R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    s = np.sin(angle)
    f = np.where(s > 1e-9, angle / np.where(s > 1e-9, 2.0 * s, 1.0), 0.5)
    return skew * f[..., None]


def _so3_exp(w) -> np.ndarray:
    """(3, 3) rotation of the rotation vector ``w`` (3,), radians."""
    theta = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-9:
        return np.eye(3) + K
    return (np.eye(3) + np.sin(theta) / theta * K
            + (1.0 - np.cos(theta)) / theta ** 2 * K @ K)


def _present(*poses) -> np.ndarray:
    return np.all([np.all(np.isfinite(p), axis=(-2, -1)) for p in poses], axis=0)


def relative_errors(P, Q, k: int):
    """Rotation (deg) and translation (m) errors of every pair ``(i, i + k)`` that both
    trajectories (N, 4, 4; NaN where absent) hold: ``inv(inv(Q_i) Q_j) inv(P_i) P_j``."""
    i = np.arange(max(len(P) - k, 0))
    j = i + k
    ok = _present(P[i], P[j], Q[i], Q[j])
    i, j = i[ok], j[ok]
    E = relative_pose(relative_pose(Q[i], Q[j]), relative_pose(P[i], P[j]))
    return np.degrees(rotation_angle(E[:, :3, :3])), np.linalg.norm(E[:, :3, 3], axis=-1)


def hybrid(P, Q, keep: str) -> np.ndarray:
    """A trajectory whose every frame step takes the estimate's rotation and the truth's
    translation (``keep="rotation"``) or the reverse (``"translation"``); a step that either
    lacks is the truth's. Chained from the truth's first pose (NaN before it)."""
    out = np.full_like(Q, np.nan)
    first = int(np.argmax(_present(Q)))
    out[first] = Q[first]
    for i in range(first, len(Q) - 1):
        SQ = relative_pose(Q[i], Q[i + 1]) if _present(Q[i], Q[i + 1]) else np.eye(4)
        S = SQ.copy()
        if _present(P[i], P[i + 1], Q[i], Q[i + 1]):
            SP = relative_pose(P[i], P[i + 1])
            if keep == "rotation":
                S[:3, :3] = SP[:3, :3]
            else:
                S[:3, 3] = SP[:3, 3]
        out[i + 1] = out[i] @ S
    return out


def _rmse(x) -> float:
    x = np.asarray(x, np.float64)
    return float(np.sqrt(np.mean(x * x))) if len(x) else float("nan")


def displacements(P, Q, k: int) -> tuple[np.ndarray, np.ndarray]:
    """``(estimated (m, 3), true (m, 3))`` metres: each displacement ``p_{i+k} - p_i`` of the
    positions in the world, the estimate rigidly aligned on the truth as the ATE aligns it.
    Their difference is the path's shape error, which the ATE integrates, without the
    relative pose's turn of the displacement into camera ``i``'s frame (where camera
    ``i``'s orientation error, times the distance, adds)."""
    ok = _present(P, Q)
    idx = np.flatnonzero(ok)
    if len(idx) < 3:
        return np.zeros((0, 3)), np.zeros((0, 3))
    S = align_umeyama(P[idx, :3, 3], Q[idx, :3, 3])
    p = np.full((len(P), 3), np.nan)
    p[idx] = S.apply_points(P[idx, :3, 3])
    i = np.arange(max(len(P) - k, 0))
    j = i + k
    both = ok[i] & ok[j]
    i, j = i[both], j[both]
    return p[j] - p[i], Q[j, :3, 3] - Q[i, :3, 3]


def axis_slopes(P, Q, k: int) -> dict:
    """Per axis of camera ``i`` (x right, y down, z forward), the least-squares slope of
    the estimated translations of every pair ``(i, i + k)`` on the true ones: where the
    estimate's length goes wrong, across the view (the image's scale: the focal length,
    the colour image's registration) or along it (the depth's scale)."""
    i = np.arange(max(len(P) - k, 0))
    ok = _present(P[i], P[i + k], Q[i], Q[i + k])
    i = i[ok]
    tp = relative_pose(P[i], P[i + k])[:, :3, 3]
    tq = relative_pose(Q[i], Q[i + k])[:, :3, 3]
    return {a: float(np.sum(tp[:, j] * tq[:, j]) / max(np.sum(tq[:, j] ** 2), 1e-30))
            for j, a in enumerate("xyz")}


def length_budget(P, Q) -> dict:
    """How much of the ATE is the path's length: the ATE after a rigid alignment and after
    a similarity one (mm), that similarity's scale (above 1: the estimated path is short),
    and the per-axis slopes over 1 and 10 frames (:func:`axis_slopes`)."""
    frames = np.flatnonzero(_present(P, Q)).astype(np.float64)  # a frame's index as its time
    est, truth = (Trajectory(frames, X[frames.astype(int)]) for X in (P, Q))
    rigid, similar = (ate(truth, est, scale=scale) for scale in (False, True))
    return {"axis_slope": {k: axis_slopes(P, Q, k) for k in DELTAS[:2]},
            "ate_se3_mm": 1e3 * rigid.stats.rmse, "ate_sim3_mm": 1e3 * similar.stats.rmse,
            "sim3_scale": float(similar.alignment.scale)}


def pose_budget(P, Q) -> dict:
    """The relative-error figures of an estimate ``P`` against the truth ``Q`` (N, 4, 4)."""
    out: dict = {"rpe": {}, "rot_only_mm": {}, "trans_only_mm": {}, "disp_mm": {},
                 "scale": {}, "length": length_budget(P, Q)}
    rot_only, trans_only = hybrid(P, Q, "rotation"), hybrid(P, Q, "translation")
    for k in DELTAS:
        r, t = relative_errors(P, Q, k)
        out["rpe"][k] = {"rot_deg": _rmse(r), "trans_mm": 1e3 * _rmse(t), "pairs": len(t)}
        dp, dq = displacements(P, Q, k)
        out["disp_mm"][k] = 1e3 * _rmse(np.linalg.norm(dp - dq, axis=-1))
        # the estimated displacements' length against the true ones (least squares slope):
        # over one frame the truth's own noise dilutes it (the regressor is noisy), over 10
        # and 30 frames the displacements are long against that noise
        out["scale"][k] = float(np.sum(dp * dq) / max(np.sum(dq * dq), 1e-30))
        out["rot_only_mm"][k] = 1e3 * _rmse(relative_errors(rot_only, Q, k)[1])
        out["trans_only_mm"][k] = 1e3 * _rmse(relative_errors(trans_only, Q, k)[1])
    for k in DELTAS[1:]:
        base = out["rpe"][1]
        out.setdefault("growth", {})[k] = {
            q: float(np.log(out["rpe"][k][q] / base[q]) / np.log(k))
            if base[q] > 0 and out["rpe"][k][q] > 0 else float("nan")
            for q in ("rot_deg", "trans_mm")}
        d1, dk = out["disp_mm"][1], out["disp_mm"][k]
        out["growth"][k]["disp_mm"] = (float(np.log(dk / d1) / np.log(k)) if d1 > 0 and dk > 0
                                       else float("nan"))
    # per frame step: the mean error vector's share of the mean squared error
    i = np.arange(len(P) - 1)
    ok = _present(P[i], P[i + 1], Q[i], Q[i + 1])
    i = i[ok]
    SP, SQ = relative_pose(P[i], P[i + 1]), relative_pose(Q[i], Q[i + 1])
    E = relative_pose(SQ, SP)
    w, e = _so3_log(E[:, :3, :3]), E[:, :3, 3]
    out["bias_share"] = {
        "rot": float(np.sum(w.mean(0) ** 2) / max(np.mean(np.sum(w * w, 1)), 1e-30)),
        "trans": float(np.sum(e.mean(0) ** 2) / max(np.mean(np.sum(e * e, 1)), 1e-30))}
    return out


# ------------------------------------------------------------------------ the points


class FrameNoise:
    """One pair's points as columns and their sigmas under the noise model: the image
    position (normalised image coordinates, per axis) and the depth along the viewing ray
    (both readings and the surface's slope under the tracking error), as
    ``jaxvo.core.noise.point_noise`` builds them."""

    def __init__(self, flow: GridFlow, params: Params):
        valid = np.asarray(flow.valid) & (int(flow.status) == Status.OK)
        src, dst = np.asarray(flow.pts_prev, np.float64), np.asarray(flow.pts_cur, np.float64)
        valid &= (src[:, 2] > 0) & (dst[:, 2] > 0) & np.all(np.isfinite(src) & np.isfinite(dst), 1)
        self.valid = valid
        self.src, self.dst = src.T, dst.T
        fb = np.where(valid, np.asarray(flow.fb_error, np.float64), 0.0)
        slope = np.where(valid, np.asarray(flow.depth_slope, np.float64), 0.0)
        px2 = params.pixel_sigma ** 2 + 0.25 * fb * fb
        self.focal = float(flow.focal)
        self.s_uv = np.sqrt(px2) / self.focal
        z0, z1 = self.src[2], self.dst[2]
        self.s_z = np.sqrt(params.depth_coeff ** 2 * (z0 ** 4 + z1 ** 4) + slope * slope * px2)
        self.s_z = np.where(valid, self.s_z, 1.0)
        self.uv = np.asarray(flow.uv_prev, np.float64)

    def residuals(self, T):
        """``(ru, rv, rz, jacobians (3, 6, n))`` of the points under ``T`` (4, 4): image
        plane (normalised) and depth errors of ``T src`` against the current points, and
        their derivatives for a left perturbation ``(omega, nu)``
        (``jaxvo.core.egomotion.refine_reprojection``'s)."""
        q = T[:3, :3] @ self.src + T[:3, 3:4]
        z = np.where(q[2] > 1e-6, q[2], 1e-6)
        u, v = q[0] / z, q[1] / z
        dz0 = np.where(self.dst[2] > 0, self.dst[2], 1.0)
        ru, rv, rz = u - self.dst[0] / dz0, v - self.dst[1] / dz0, q[2] - self.dst[2]
        iz, zero = 1.0 / z, np.zeros_like(z)
        du = np.stack([-u * q[1] * iz, iz * q[2] + u * q[0] * iz, -q[1] * iz, iz, zero, -u * iz])
        dv = np.stack([-iz * q[2] - v * q[1] * iz, v * q[0] * iz, q[0] * iz, zero, iz, -v * iz])
        dz = np.stack([q[1], -q[0], zero, zero, zero, np.ones_like(z)])
        return ru, rv, rz, np.stack([du, dv, dz])

    def information(self, T, weights) -> np.ndarray:
        """(6, 6) the pose's information from the points of ``weights`` (n,) under the model."""
        *_, J = self.residuals(T)
        a, b = weights / self.s_uv ** 2, weights / self.s_z ** 2
        return (J[0] * a) @ J[0].T + (J[1] * a) @ J[1].T + (J[2] * b) @ J[2].T

    def sensor_fit(self, T, mask, iters: int = 3) -> np.ndarray:
        """Gauss-Newton from ``T`` on the points of ``mask`` (n,) bool, each residual in its
        sigma, Huber weights with the corner at the inlier test: (4, 4)."""
        T = np.asarray(T, np.float64).copy()
        for _ in range(iters):
            ru, rv, rz, J = self.residuals(T)
            e = np.sqrt((ru * ru + rv * rv) / self.s_uv ** 2 + rz * rz / self.s_z ** 2)
            w = np.where(mask, np.minimum(1.0, _HUBER / np.maximum(e, 1e-12)), 0.0)
            if np.sum(w > 0) < 6:
                return T
            a, b = w / self.s_uv ** 2, w / self.s_z ** 2
            H = (J[0] * a) @ J[0].T + (J[1] * a) @ J[1].T + (J[2] * b) @ J[2].T
            g = (J[0] * a) @ ru + (J[1] * a) @ rv + (J[2] * b) @ rz
            xi = -np.linalg.solve(H + 1e-12 * np.trace(H) * np.eye(6), g)
            dR = _so3_exp(xi[:3])
            T[:3, :3], T[:3, 3] = dR @ T[:3, :3], dR @ T[:3, 3] + xi[3:]
        return T

    def noise_ratio(self, T, mask) -> tuple[float, float]:
        """The measured noise of the points of ``mask`` under ``T`` over the model's, image
        plane and depth (medians of the squared normalised residuals over chi-square's)."""
        ru, rv, rz, _ = self.residuals(T)
        if not np.any(mask):
            return float("nan"), float("nan")
        lat = np.median(((ru * ru + rv * rv) / self.s_uv ** 2)[mask]) / _CHI2_2_MEDIAN
        dep = np.median((rz * rz / self.s_z ** 2)[mask]) / _CHI2_1_MEDIAN
        return float(np.sqrt(lat)), float(np.sqrt(dep))

    def layout(self, mask, size) -> dict:
        """Where the points of ``mask`` lie: count, depth quantiles, the share in each third
        of the width (left, centre, right) and the height (top, middle, bottom) and the
        largest share of one of the 3 x 3 regions."""
        h, w = size
        n = int(np.sum(mask))
        if n == 0:
            return {"n": 0}
        uv, z = self.uv[mask], self.src[2][mask]
        col = np.clip((3 * uv[:, 0] / w).astype(int), 0, 2)
        row = np.clip((3 * uv[:, 1] / h).astype(int), 0, 2)
        cells = np.bincount(3 * row + col, minlength=9) / n
        return {"n": n, "z": [float(x) for x in np.quantile(z, (0.1, 0.5, 0.9))],
                "x_thirds": [float(x) for x in np.bincount(col, minlength=3) / n],
                "y_thirds": [float(x) for x in np.bincount(row, minlength=3) / n],
                "max_region": float(cells.max())}


def crb(info) -> tuple[float, float, float]:
    """The Cramer-Rao bound of a pose from its (6, 6) information: the rotation's and the
    translation's standard deviations (deg, mm; square roots of the traces) and the
    translation's in its worst direction (mm)."""
    try:
        C = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return float("nan"), float("nan"), float("nan")
    Ct = C[3:, 3:]
    return (float(np.degrees(np.sqrt(max(np.trace(C[:3, :3]), 0.0)))),
            1e3 * float(np.sqrt(max(np.trace(Ct), 0.0))),
            1e3 * float(np.sqrt(max(np.linalg.eigvalsh(Ct)[-1], 0.0))))


# --------------------------------------------------------------------------- oracles


@functools.partial(jax.jit, static_argnames=("cfg",))
def _fits(flow, weights, starts, params, *, cfg: Config):
    """``fit_egomotion`` on one pair's points for each of ``weights`` (B, n) and starts
    ``starts`` (B, 4, 4) (the start given as ``T_init`` and as a candidate, beside the
    plain weighted fit): ``(T_cur_prev (B, 4, 4), status (B,))``."""
    pts = frame_points(flow.pts_prev, flow.pts_cur, flow.valid & (flow.status == Status.OK),
                       params, focal=flow.focal, fb_error=flow.fb_error,
                       depth_slope=flow.depth_slope)

    def one(w, T0):
        T, status, _ = fit_egomotion(pts, w, params, cfg=cfg, T_init=T0, candidates=T0[None])
        return T, status

    return jax.vmap(one)(weights, starts)


def true_motions(Q) -> tuple[np.ndarray, np.ndarray]:
    """``(T_cur_prev (N-1, 4, 4), present (N-1,) bool)`` of the truth's frame steps (the
    identity where the truth lacks a pose)."""
    ok = _present(Q[:-1], Q[1:])
    Qs = np.where(_present(Q)[:, None, None], Q, np.eye(4))
    return np.where(ok[:, None, None], relative_pose(Qs[1:], Qs[:-1]), np.eye(4)), ok


def oracles(data: dict, outs, Q, params: Params, cfg: Config = CFG) -> tuple[dict, dict]:
    """Each oracle's motions (S, T, 4, 4) and the points' figures per seed and pair."""
    flows = GridFlow(*(data[f"flow_{k}"] for k in GridFlow._fields))
    size = tuple(int(x) for x in data["size"])
    T_true, has_truth = true_motions(Q)
    jax_T = np.asarray(outs.T_cur_prev, np.float64)  # (S, T, 4, 4)
    static = np.asarray(outs.static)
    ok = (np.asarray(outs.status) == Status.OK) & has_truth[None]
    S, n_pairs = static.shape[:2]
    p = params_as_arrays(params)
    names = ("refit", "(i) from the truth", "(ii) points' floor", "(ii) all valid",
             "(iii) all valid points")
    motions = {k: jax_T.copy() for k in names}
    points: dict = {"used": [], "valid": [], "crb_used": [], "crb_valid": [],
                    "noise_used": [], "noise_valid": [], "noise_fit": []}
    for k in range(n_pairs):
        flow = GridFlow(*(np.asarray(a[k]) for a in flows))
        fn = FrameNoise(flow, params)
        valid = fn.valid
        truth = np.broadcast_to(T_true[k], (S, 4, 4))
        weights = np.concatenate([static[:, k], static[:, k], np.broadcast_to(valid, (S, valid.size))])
        starts = np.concatenate([jax_T[:, k], truth, jax_T[:, k]])
        T, status = _fits(flow, jnp.asarray(weights, jnp.float32), jnp.asarray(starts, jnp.float32),
                          p, cfg=cfg)
        T, status = np.asarray(T, np.float64), np.asarray(status)
        fitted = status == Status.OK
        for j, name in enumerate(("refit", "(i) from the truth", "(iii) all valid points")):
            sel = fitted[j * S:(j + 1) * S] & ok[:, k]
            motions[name][sel, k] = T[j * S:(j + 1) * S][sel]
        if has_truth[k]:
            floor_valid = fn.sensor_fit(T_true[k], valid)
            info_valid = fn.information(T_true[k], valid.astype(float))
            points["crb_valid"].append(crb(info_valid))
            points["noise_valid"].append(fn.noise_ratio(T_true[k], valid))
        for s in range(S):
            used = static[s, k] & valid
            points["used"].append(fn.layout(used, size))
            if not ok[s, k]:
                continue
            motions["(ii) points' floor"][s, k] = fn.sensor_fit(T_true[k], used)
            motions["(ii) all valid"][s, k] = floor_valid
            points["crb_used"].append(crb(fn.information(T_true[k], used.astype(float))))
            points["noise_used"].append(fn.noise_ratio(T_true[k], used))
            points["noise_fit"].append(fn.noise_ratio(jax_T[s, k], used))
        points["valid"].append(fn.layout(valid, size))
    return motions, points


def point_summary(points: dict) -> dict:
    """Medians over pairs (and seeds) of the points' figures."""
    used = [u for u in points["used"] if u["n"] > 0]
    def med(xs):
        return [float(x) for x in np.median(np.asarray(xs, np.float64), axis=0)]

    out = {"used": float(np.median([u["n"] for u in points["used"]])),
           "used_p10_p90": [float(x) for x in np.quantile([u["n"] for u in points["used"]],
                                                        (0.1, 0.9))],
           "valid": float(np.median([u["n"] for u in points["valid"]]))}
    if used:
        out.update({"z": med([u["z"] for u in used]), "x_thirds": med([u["x_thirds"] for u in used]),
                    "y_thirds": med([u["y_thirds"] for u in used]),
                    "max_region": float(np.median([u["max_region"] for u in used]))})
    for k in ("crb_used", "crb_valid", "noise_used", "noise_valid", "noise_fit"):
        if points[k]:
            out[k] = med(points[k])
    return out


# ------------------------------------------------------------------------- ORB-SLAM3


def orbslam3_runs(case: Case, runs: Path, repeats: int) -> tuple[list[Trajectory], list[dict]]:
    """ORB-SLAM3's end-of-run trajectories of the case (``repeats`` runs, each cached under
    ``runs``) and each run's figures; ``([], [{"skipped": why}])`` where it cannot run."""
    why = orbslam3_peer.missing()
    if why:
        return [], [{"skipped": why}]
    trajs, metas = [], []
    for r in range(repeats):
        path = runs / f"{case.name}__orbslam3_{frames_hash()}_run{r}.txt"
        meta = path.with_suffix(".json")
        if not (path.is_file() and meta.is_file()):
            log(f"{case.name}: ORB-SLAM3 run {r + 1} of {repeats}")
            seq = case.build()
            _, run = orbslam3_peer.run_orbslam3(seq)
            runs.mkdir(parents=True, exist_ok=True)
            # whole or not at all, each (a run is cached once both are there)
            write_trajectory(path, run.trajectory, comment="ORB-SLAM3 RGB-D, end-of-run trajectory")
            write_text(meta, json.dumps({"frames": len(seq), "tracked": len(run.trajectory),
                                         "lost": run.lost, "ms_per_frame": run.ms_per_frame,
                                         "load_average": load_average()}, indent=1))
        trajs.append(read_trajectory(path))
        metas.append(json.loads(meta.read_text()))
    return trajs, metas


def other_peers(case: Case, cache: Path, runs: Path) -> dict[str, float]:
    """ATE mm of every OpenCV and Open3D peer alone on the case (deterministic: one run
    each; the OpenCV ones from ``bench_robustness.peers_alone``'s cache, the Open3D ones,
    where ``open3d`` imports, cached under ``runs``)."""
    out = {k: 1e3 * v["ate_rmse_m"] for k, v in peers_alone(case, cache).items()
           if k in OPENCV_PEERS}
    path = runs / f"{case.name}__open3d_{frames_hash()}.json"
    o3d = json.loads(path.read_text()) if path.is_file() else {}
    todo = [k for k in available_peers() if k in OPEN3D_PEERS and k not in o3d]
    if todo:
        seq = case.build()
        for kind in todo:
            log(f"{case.name}: peer {kind}")
            run = orbslam3_peer.run_any_peer(seq, kind)
            o3d[kind] = 1e3 * trajectory_scores(seq.groundtruth, run.trajectory)["ate_rmse_m"]
        runs.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(o3d, indent=1))
    return out | o3d


# ------------------------------------------------------------------------------ a case


def _median_budget(budgets: list[dict]) -> dict:
    """The median over seeds of every number in the budgets (same layout)."""
    def walk(xs):
        if isinstance(xs[0], dict):
            return {k: walk([x[k] for x in xs]) for k in xs[0]}
        return float(np.nanmedian(np.asarray(xs, np.float64)))
    return walk(budgets)


_HAT = (("rot_deg", "rpe/{k}/rot_deg"), ("trans_mm", "rpe/{k}/trans_mm"),
        ("disp_mm", "disp_mm/{k}"))


def three_cornered_hat(row: dict) -> dict:
    """Each of jaxvo, ORB-SLAM3 and the ground truth's own error, from the three pairwise
    RMSEs (jaxvo against the truth, ORB-SLAM3 against it, jaxvo against ORB-SLAM3) as if the
    three errors were independent: ``var_a = (ab^2 + ac^2 - bc^2) / 2``, a negative
    variance shown as 0. An error the two estimates share (the same images and depth)
    counts as the truth's."""
    out: dict = {}
    for name, path in _HAT:
        for k in DELTAS:
            p = path.format(k=k)
            jg, og = _value(row["jaxvo"], p), _value(row["orbslam3"], p)
            jo = _value(row["jaxvo_vs_orbslam3"], p)
            var = {"truth": (jg ** 2 + og ** 2 - jo ** 2) / 2,
                   "jaxvo": (jg ** 2 + jo ** 2 - og ** 2) / 2,
                   "orbslam3": (og ** 2 + jo ** 2 - jg ** 2) / 2}
            out.setdefault(name, {})[k] = {w: float(np.sqrt(max(v, 0.0))) for w, v in var.items()}
    return out


def _ate_mm(gt: Trajectory, traj: Trajectory) -> float:
    return 1e3 * trajectory_scores(gt, traj)["ate_rmse_m"]


def budget_case(case: Case, cache: Path, runs: Path, seeds: int, params: Params,
                orb_repeats: int = 1) -> dict:
    t0 = time.perf_counter()
    data = prepare(case, cache, CFG)
    stamps = np.asarray(data["timestamps"], np.float64)
    gt = groundtruth(data)
    Q = at_frames(gt, stamps)
    T0 = first_pose(data)
    log(f"{case.name}: jaxvo, {seeds} seeds")
    trajs, outs = run_seeds(data, T0, params, CFG, seeds)
    row: dict = {"case": case.name, "frames": len(stamps), "seeds": seeds,
                 "skipped_pairs": int(np.sum(np.asarray(outs.status) != Status.OK))}
    jaxvo = [pose_budget(at_frames(t, stamps), Q) for t in trajs]
    row["jaxvo"] = _median_budget(jaxvo)
    row["jaxvo"]["ate_mm"] = [_ate_mm(gt, t) for t in trajs]
    log(f"{case.name}: oracles")
    motions, points = oracles(data, outs, Q, params)
    row["points"] = point_summary(points)
    row["oracles"] = {}
    for name, M in motions.items():
        tr = [Trajectory(stamps, chain(T0, M[s])) for s in range(seeds)]
        b = _median_budget([pose_budget(t.poses, Q) for t in tr])
        row["oracles"][name] = {"ate_mm": [_ate_mm(gt, t) for t in tr], "rpe": b["rpe"]}
    log(f"{case.name}: keyframes on")
    kf_trajs, _ = run_seeds(prepare(case, cache, KEYFRAMES), T0, params, KEYFRAMES, seeds)
    row["oracles"]["(iv) keyframes"] = {
        "ate_mm": [_ate_mm(gt, t) for t in kf_trajs],
        "rpe": _median_budget([pose_budget(at_frames(t, stamps), Q) for t in kf_trajs])["rpe"]}
    orbs, metas = orbslam3_runs(case, runs, orb_repeats)
    row["orbslam3_runs"] = metas
    if orbs:
        # the run of median ATE is the one budgeted (ORB-SLAM3 is not deterministic)
        ates = [_ate_mm(gt, o) for o in orbs]
        for m, a in zip(metas, ates):
            m["ate_mm"] = a
        orb = orbs[int(np.argsort(ates)[(len(ates) - 1) // 2])]
        O = at_frames(orb, stamps)
        row["orbslam3"] = pose_budget(O, Q)
        row["orbslam3"]["ate_mm"] = [_ate_mm(gt, orb)]
        # the two estimates against each other: where they agree better than either with
        # the ground truth, the truth's own error is in the figures above
        row["jaxvo_vs_orbslam3"] = _median_budget([pose_budget(at_frames(t, stamps), O)
                                                   for t in trajs])
        row["jaxvo_vs_orbslam3"]["ate_mm"] = [_ate_mm(orb, t) for t in trajs]
        row["hat"] = three_cornered_hat(row)
    row["peers_ate_mm"] = other_peers(case, cache, runs)
    row["seconds"] = time.perf_counter() - t0
    return row


# ---------------------------------------------------------------------------- report


def _f(x, spec=".1f") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def _ate(values) -> str:
    v = np.asarray(values)
    if len(v) == 1:
        return _f(v[0])
    return f"{np.median(v):.1f} [{v.min():.1f}-{v.max():.1f}]"


def _methods(r: dict):
    yield "jaxvo", r["jaxvo"]
    if "orbslam3" in r:
        yield "ORB-SLAM3", r["orbslam3"]
        yield "jaxvo against ORB-SLAM3", r["jaxvo_vs_orbslam3"]


def target_table(rows: list[dict]) -> str:
    """Issue 43's bar: jaxvo at most ORB-SLAM3 and below every OpenCV / Open3D peer."""
    head = ["case", "jaxvo ATE mm", "ORB-SLAM3 (median of its runs)", "jaxvo / ORB-SLAM3",
            "best OpenCV / Open3D peer", "met"]
    cells = []
    for r in rows:
        jax_mm = float(np.median(r["jaxvo"]["ate_mm"]))
        orb = [m["ate_mm"] for m in r["orbslam3_runs"] if "ate_mm" in m]
        orb_mm = float(np.median(orb)) if orb else float("nan")
        peers = r.get("peers_ate_mm", {})
        best = min(peers, key=peers.get) if peers else None
        met = (jax_mm <= orb_mm and all(jax_mm < v for v in peers.values())
               if orb and peers else None)
        cells.append([r["case"], _ate(r["jaxvo"]["ate_mm"]),
                      _ate(orb) if orb else "-", _f(jax_mm / orb_mm, ".2f"),
                      f"{peers[best]:.1f} ({best})" if best else "-",
                      "-" if met is None else ("yes" if met else "no")])
    return markdown_table(head, cells)


def error_table(rows: list[dict]) -> str:
    head = ["case", "method", "ATE mm", "rot deg @1 / 10 / 30", "trans mm @1 / 10 / 30",
            "world displacement mm @1 / 10 / 30",
            "growth exponent rot / trans / displacement, 1->30",
            "trans mm from rotation alone @10 / 30",
            "trans mm from translation alone @10 / 30", "bias share rot / trans",
            "scale @1 / 10 / 30"]
    cells = []
    for r in rows:
        for name, b in _methods(r):
            rpe = b["rpe"]
            cells.append([
                r["case"], name, _ate(b["ate_mm"]),
                " / ".join(_f(rpe[k]["rot_deg"], ".3f") for k in DELTAS),
                " / ".join(_f(rpe[k]["trans_mm"], ".1f") for k in DELTAS),
                " / ".join(_f(b["disp_mm"][k], ".1f") for k in DELTAS),
                " / ".join(_f(b["growth"][30][q], ".2f") for q in ("rot_deg", "trans_mm", "disp_mm")),
                " / ".join(_f(b["rot_only_mm"][k]) for k in DELTAS[1:]),
                " / ".join(_f(b["trans_only_mm"][k]) for k in DELTAS[1:]),
                f"{_f(b['bias_share']['rot'], '.2f')} / {_f(b['bias_share']['trans'], '.2f')}",
                " / ".join(_f(b["scale"][k], ".3f") for k in DELTAS)])
    return markdown_table(head, cells)


def points_table(rows: list[dict]) -> str:
    head = ["case", "points used median [p10-p90]", "valid", "depth m p10 / 50 / 90",
            "share left / centre / right", "share top / middle / bottom", "largest of 3x3",
            "bound, used: rot deg / trans mm (worst axis)", "bound, all valid",
            "noise at the truth / model, used: image / depth", "all valid",
            "noise at jaxvo's motion / model, used"]
    cells = []
    for r in rows:
        p = r["points"]
        cu, cv = p.get("crb_used"), p.get("crb_valid")
        nu, nv, nf = p.get("noise_used"), p.get("noise_valid"), p.get("noise_fit")
        cells.append([
            r["case"], f"{p['used']:.0f} [{p['used_p10_p90'][0]:.0f}-{p['used_p10_p90'][1]:.0f}]",
            f"{p['valid']:.0f}", " / ".join(_f(z, ".2f") for z in p.get("z", [])) or "-",
            " / ".join(_f(100 * x, ".0f") for x in p.get("x_thirds", [])) + " %",
            " / ".join(_f(100 * x, ".0f") for x in p.get("y_thirds", [])) + " %",
            f"{_f(100 * p.get('max_region', float('nan')), '.0f')} %",
            f"{_f(cu[0], '.3f')} / {_f(cu[1], '.2f')} ({_f(cu[2], '.2f')})" if cu else "-",
            f"{_f(cv[0], '.3f')} / {_f(cv[1], '.2f')} ({_f(cv[2], '.2f')})" if cv else "-",
            f"{_f(nu[0], '.2f')} / {_f(nu[1], '.2f')}" if nu else "-",
            f"{_f(nv[0], '.2f')} / {_f(nv[1], '.2f')}" if nv else "-",
            f"{_f(nf[0], '.2f')} / {_f(nf[1], '.2f')}" if nf else "-"])
    return markdown_table(head, cells)


def hat_table(rows: list[dict]) -> str:
    head = ["case", "rot deg @1 / 10 / 30: truth / jaxvo / ORB-SLAM3",
            "trans mm @1 / 10 / 30: truth / jaxvo / ORB-SLAM3",
            "world displacement mm @1 / 10 / 30: truth / jaxvo / ORB-SLAM3"]
    cells = []
    for r in rows:
        if "hat" not in r:
            continue
        spec = {"rot_deg": ".3f", "trans_mm": ".1f", "disp_mm": ".1f"}
        cells.append([r["case"], *(
            "; ".join(" / ".join(_f(r["hat"][q][k][w], spec[q])
                                 for w in ("truth", "jaxvo", "orbslam3")) for k in DELTAS)
            for q in ("rot_deg", "trans_mm", "disp_mm"))])
    return markdown_table(head, cells)


def length_table(rows: list[dict]) -> str:
    head = ["case", "method", "ATE mm, rigid / similarity alignment", "similarity's scale",
            "slope x / y / z @1", "slope x / y / z @10"]
    cells = []
    for r in rows:
        for name, b in _methods(r):
            if name.startswith("jaxvo against"):
                continue
            L = b["length"]
            cells.append([r["case"], name,
                          f"{_f(L['ate_se3_mm'])} / {_f(L['ate_sim3_mm'])}",
                          _f(L["sim3_scale"], ".3f"),
                          *(" / ".join(_f(L["axis_slope"][k][a], ".3f") for a in "xyz")
                            for k in DELTAS[:2])])
    return markdown_table(head, cells)


def oracle_table(rows: list[dict]) -> str:
    names = list(rows[0]["oracles"])
    head = ["case", "jaxvo", *names, "ORB-SLAM3"]
    cells = []
    for r in rows:
        def cell(b):
            rpe = b["rpe"][1]
            return (f"{np.median(b['ate_mm']):.1f} ({rpe['trans_mm']:.2f} mm, "
                    f"{rpe['rot_deg']:.3f} deg)")
        cells.append([r["case"], cell(r["jaxvo"]), *(cell(r["oracles"][k]) for k in names),
                      cell(r["orbslam3"]) if "orbslam3" in r else "-"])
    return markdown_table(head, cells)


def _at(d: dict, path: str):
    """``d[k1][k2]...`` for ``path`` "k1/k2/..." (a number key as a number)."""
    for k in path.split("/"):
        d = d[int(k) if k.isdigit() else k]
    return d


def _value(d: dict, path: str) -> float:
    v = _at(d, path)
    return float(np.median(v)) if isinstance(v, list) else float(v)


def summary(rows: list[dict]) -> dict:
    """Across the static cases of the two splits (the whole sequence's would count its
    frames twice): the median of each per-case figure or ratio of two."""
    static = [r for r in rows if r["case"].startswith(("static_dev", "static_val"))
              and "orbslam3" in r]
    if not static:
        return {}

    def med(num: str, den: str | None = None) -> float:
        return float(np.median([_value(r, num) / (_value(r, den) if den else 1.0)
                                for r in static]))

    out: dict = {"cases": len(static),
                 "ATE jaxvo / ORB-SLAM3": med("jaxvo/ate_mm", "orbslam3/ate_mm"),
                 "ATE after a similarity alignment jaxvo / ORB-SLAM3": med(
                     "jaxvo/length/ate_sim3_mm", "orbslam3/length/ate_sim3_mm")}
    for k in DELTAS:
        for q, unit in (("rot_deg", "rot"), ("trans_mm", "trans")):
            out[f"RPE{k} {unit} jaxvo / ORB-SLAM3"] = med(f"jaxvo/rpe/{k}/{q}",
                                                         f"orbslam3/rpe/{k}/{q}")
        out[f"world displacement @{k} jaxvo / ORB-SLAM3"] = med(f"jaxvo/disp_mm/{k}",
                                                                f"orbslam3/disp_mm/{k}")
    for k in DELTAS:
        out[f"RPE{k} rot: jaxvo against ORB-SLAM3 / jaxvo against the truth"] = med(
            f"jaxvo_vs_orbslam3/rpe/{k}/rot_deg", f"jaxvo/rpe/{k}/rot_deg")
        out[f"RPE{k} trans: jaxvo against ORB-SLAM3 / jaxvo against the truth"] = med(
            f"jaxvo_vs_orbslam3/rpe/{k}/trans_mm", f"jaxvo/rpe/{k}/trans_mm")
    for who, name in (("jaxvo", "jaxvo"), ("orbslam3", "ORB-SLAM3")):
        for q in ("rot_deg", "trans_mm", "disp_mm"):
            out[f"{name} growth exponent {q} 1->30"] = med(f"{who}/growth/30/{q}")
        for k in DELTAS[1:]:
            out[f"{name} RPE{k} trans from rotation alone / all"] = med(
                f"{who}/rot_only_mm/{k}", f"{who}/rpe/{k}/trans_mm")
            out[f"{name} RPE{k} trans from translation alone / all"] = med(
                f"{who}/trans_only_mm/{k}", f"{who}/rpe/{k}/trans_mm")
        for k in DELTAS[1:]:
            out[f"{name} scale @{k}"] = med(f"{who}/scale/{k}")
        out[f"{name} similarity's scale"] = med(f"{who}/length/sim3_scale")
        for a in "xyz":
            out[f"{name} slope {a} @10"] = med(f"{who}/length/axis_slope/10/{a}")
        out[f"{name} bias share rot"] = med(f"{who}/bias_share/rot")
        out[f"{name} bias share trans"] = med(f"{who}/bias_share/trans")
    for q in ("rot_deg", "trans_mm", "disp_mm"):
        for k in DELTAS:
            for w in ("truth", "jaxvo", "orbslam3"):
                out[f"three-cornered hat {q} @{k} {w}"] = med(f"hat/{q}/{k}/{w}")
    out["points used"] = med("points/used")
    out["jaxvo RPE1 trans / bound of the points used"] = med("jaxvo/rpe/1/trans_mm",
                                                             "points/crb_used/1")
    out["jaxvo RPE1 rot / bound of the points used"] = med("jaxvo/rpe/1/rot_deg",
                                                           "points/crb_used/0")
    for i, part in enumerate(("image", "depth")):
        out[f"noise {part} at the truth / model"] = med(f"points/noise_used/{i}")
        out[f"noise {part} at jaxvo's motion / model"] = med(f"points/noise_fit/{i}")
    for name in static[0]["oracles"]:
        out[f"ATE {name} / jaxvo"] = med(f"oracles/{name}/ate_mm", "jaxvo/ate_mm")
        out[f"RPE1 trans {name} / jaxvo"] = med(f"oracles/{name}/rpe/1/trans_mm",
                                                "jaxvo/rpe/1/trans_mm")
        out[f"RPE1 rot {name} / jaxvo"] = med(f"oracles/{name}/rpe/1/rot_deg",
                                              "jaxvo/rpe/1/rot_deg")
    return out


_INTRO = (
    "jaxvo: {seeds} seeds, the default `Config` (keyframes off) unless said; figures are "
    "medians over the seeds (ATE: median [best-worst]). ORB-SLAM3: RGB-D, **one run per "
    "case** unless said below (it is not deterministic), in its own process, associated with the frames by "
    "timestamp (frames before its initialisation left out); with several runs per case, "
    "the run of median ATE. {vocabulary}")
_TARGET = (
    "Issue 43's target on these frames: jaxvo's median ATE over the seeds at most "
    "ORB-SLAM3's (the median of its runs) and below every OpenCV and Open3D peer (one run "
    "each: they are deterministic). ORB-SLAM3 ATE: median [best-worst] of its runs.")
_ERRORS = (
    "RMSE over every pair 1, 10 and 30 frames apart (frames of the case: every 4th frame's "
    "10 is 40 of the sequence's). *trans*: the relative pose error's translation (evo's RPE: "
    "the displacement seen from camera i, so camera i's orientation error times the distance "
    "adds to it); *world displacement*: the error of `p_(i+k) - p_i` in the world, the "
    "estimate aligned on the truth as for the ATE (the path's shape, which the ATE "
    "integrates). Growth exponent `log(E_30 / E_1) / log 30`: 0.5 a random walk of "
    "independent per-frame errors, 1 a drift, below 0.5 an error that stops growing (a map "
    "holds it). *From rotation alone*: the translation RPE of the trajectory that takes each "
    "step's estimated rotation and true translation; *from translation alone*: the reverse. "
    "*Bias share*: the mean per-frame error vector's share of the mean squared error (0: "
    "pure noise). *Scale*: the estimated world displacements' length over the true ones "
    "(least squares slope; over 1 frame the truth's own noise pulls it below 1). "
    "*jaxvo against ORB-SLAM3*: the same figures with ORB-SLAM3 in place of the truth: where "
    "the two estimates agree better than either does with the truth, the truth's own "
    "per-frame error is in the rows above.")
_HAT_TEXT = (
    "Each one's own error from the three pairwise RMSEs of section 1 (jaxvo against the "
    "truth, ORB-SLAM3 against it, jaxvo against ORB-SLAM3), as if the three errors were "
    "independent (the three-cornered hat): `var_jaxvo = (jg^2 + jo^2 - og^2) / 2` and so on, "
    "a negative variance shown as 0. What the two estimates share (the same images and depth: "
    "misregistration, the sensor's depth error) is counted as the truth's, so the estimates' "
    "own errors are lower bounds.")
_POINTS = (
    "Medians over pairs and seeds. *Bound*: the Cramer-Rao bound of one pair's pose from "
    "those points under the noise model (image position and depth along the ray in their "
    "sigmas: `Params.pixel_sigma`, `depth_coeff`, the tracks' forward-backward error and the "
    "depth's slope): rotation and translation standard deviations, and the translation's in "
    "its weakest direction. *Noise at the truth / model*: the points' residuals under the "
    "true motion over the model's sigmas (robust: squared medians over chi-square's), image "
    "plane and depth; *at jaxvo's motion*: the same under jaxvo's estimate.")
_ORACLES = (
    "ATE mm (median over seeds), then RPE over 1 frame (translation, rotation). Each oracle "
    "replaces one thing with the truth on the same frames and seeds (see the script's "
    "docstring): *refit* is the control (the same fit on the points jaxvo used, from "
    "jaxvo's motion), *(i)* the same fit with the true motion as its start, *(ii)* "
    "Gauss-Newton from the truth in the sensor's units on the points used / on all valid "
    "points, *(iii)* the fit on all valid points, *(iv)* keyframes and their window on.")

_LENGTH = (
    "Medians over seeds. The ATE after the rigid alignment that section 1 uses and after a "
    "similarity alignment (a scale too, as for a monocular estimate): the difference is what "
    "the path's length costs. *Similarity's scale*: above 1, the estimated path is shorter "
    "than the truth. *Slope*: per axis of the camera (x right, y down, z forward), the "
    "least-squares slope of the estimated relative translations on the true ones over 1 and "
    "10 frames (over 1 frame the truth's own noise pulls it below 1): the image's scale "
    "shows across the view, the depth's along it. The 7-Scenes colour camera is not "
    "calibrated (its frames are the raw images, their depth read with the depth camera's "
    "585 px focal length), so both estimators may read a lateral scale the truth, made from "
    "the depth alone, does not have.")


def report(rows: list[dict], meta: dict) -> str:
    m = meta["machine"]
    L = ["# The error budget: jaxvo beside ORB-SLAM3 on the same frames (issue 43)", "",
         (f"Written by `bench/bench_budget.py` on {meta['date']}; {m['cpu_model']}, "
          f"{m['cores']} cores, jax {m['jax']}, opencv {m['opencv']}; load average "
          f"{meta['load_start']} at the start, {meta['load_end']} at the end."), "",
         _INTRO.format(seeds=meta["seeds"], vocabulary=meta["vocabulary"]), "",
         "## The bar", "", _TARGET, "", target_table(rows), "",
         "## 1. Relative pose errors against the ground truth", "", _ERRORS, "",
         error_table(rows), "",
         "### Whose error: the three-cornered hat", "", _HAT_TEXT, "", hat_table(rows), "",
         "## 2. The points the ego-motion used", "", _POINTS, "", points_table(rows), "",
         "## 3. The share of the error each stage leaves: oracles", "", _ORACLES, "",
         oracle_table(rows), "",
         "## 4. The path's length", "", _LENGTH, "", length_table(rows), ""]
    s = meta.get("summary")
    if s:
        L += ["## Summary over the static cases of the two splits (median over the cases)", "",
              markdown_table(["figure", "value"], [[k, _f(v, ".3f")] for k, v in s.items()]),
              ""]
    L += ["ORB-SLAM3 runs (ATE mm, frames tracked of the case's; the run of median ATE is "
          "the one budgeted above): " + "; ".join(
              f"{r['case']} " + ", ".join(
                  f"{m['ate_mm']:.1f} ({m['tracked']}/{m['frames']})" if "ate_mm" in m
                  else m.get("skipped", "-") for m in r["orbslam3_runs"]) for r in rows)
          + ".", ""]
    L += [f"{k}: skipped, {v}" for k, v in meta["skipped"].items()]
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--seeds", type=count(1), default=5)
    ap.add_argument("--cache", type=Path, default=Path("results/cache"),
                    help="the flow cache (bench_robustness.prepare)")
    ap.add_argument("--runs", type=Path, default=Path("results/budget_runs"),
                    help="where ORB-SLAM3's trajectories are kept")
    ap.add_argument("--orbslam3-runs", type=int, default=1,
                    help="ORB-SLAM3 runs per case; the run of median ATE is budgeted")
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)
    check_options(ap, args, cases=[c.name for c in budget_cases()])
    todo = [c for c in budget_cases() if not args.only or c.name in args.only]
    todo, skipped = runnable(todo)
    load_start = load_average()
    rows = []
    for case in todo:
        rows.append(budget_case(case, args.cache, args.runs, args.seeds, Params(),
                                args.orbslam3_runs))
        r = rows[-1]
        log(f"{case.name}: jaxvo ATE {_ate(r['jaxvo']['ate_mm'])} mm, ORB-SLAM3 "
            f"{_ate(r['orbslam3']['ate_mm']) if 'orbslam3' in r else '-'} mm; oracles "
            + ", ".join(f"{k} {np.median(v['ate_mm']):.1f}" for k, v in r["oracles"].items()))
    meta = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": machine(),
            "seeds": args.seeds, "load_start": load_start, "load_end": load_average(),
            "vocabulary": orbslam3_peer.vocabulary_note(), "skipped": skipped}
    meta["summary"] = summary(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    write_text(args.out / "budget.json", json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = report(rows, meta)
    write_text(args.out / "budget.md", md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
