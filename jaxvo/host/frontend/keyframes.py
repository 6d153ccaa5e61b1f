"""The keyframes' grid points tracked into each new image (host side; our addition).

Frame to frame, every pair adds its error to the pose chain. The keyframe tracker follows
the grid points of the latest keyframe into each new image, so that the ego-motion also
fits those points and drift accrues per keyframe instead of per frame
(:mod:`jaxvo.core.keyframe`). When a new keyframe is taken, the points of the older
keyframes of the local window (``cfg.keyframe_window``) are tracked into it too: they are
what ties the window's keyframes to each other beyond consecutive ones, for the window's
joint refinement on the device.

Each kept frame's pair flow (:class:`jaxvo.host.frontend.flow.GridFlowTracker`) is composed onto
every window keyframe's points' positions in the previous image: that predicts where they
lie in the current image. For the latest keyframe one forward LK from there, on the finest
two levels, finds them every frame (a seeded track needs no coarse level, and no backward
pass: the patch similarity and the depth checks reject the failures, and the robust fits
the rest); the older keyframes' points are found the same way only when a new keyframe is
taken, from the positions the flow predicted (with ``cfg.keyframe_track_window``, every
pair, as the latest keyframe's are). The keyframe is renewed when fewer than
``cfg.keyframe_overlap`` of the points its first pair tracked are still tracked, and at the
latest ``cfg.keyframe_max_age`` pairs after it was taken: where a near mover holds most of
the keyframe's points, they stay tracked while the world's leave the view, and the test
over the keyframe (:mod:`jaxvo.core.separation`) would lose the world's points for good.
The decision uses host data only, so a recorded sequence's keyframes are known before the
scan and a stream takes the same ones.

Host only: numpy and OpenCV, never traced.
"""

from __future__ import annotations

import numpy as np

from jaxvo.core.inputs import KeyframeFlow, keyframe_index
from jaxvo.host.frontend.camera import backproject
from jaxvo.host.frontend.depth import depth_at
from jaxvo.host.frontend.patches import lk_converged, similar


class _Keyframe:
    """One keyframe of the window: its image, the points it offers and where the flow
    predicts them in the latest image."""

    def __init__(self, frame, sub: np.ndarray):
        # the tracker's float grey buffers take turns: the keyframe keeps its own copy
        self.frame = frame._replace(grey_f=frame.grey_f.copy())
        self.idx = np.flatnonzero(frame.z_grid_ok & sub)  # points with depth, subsampled
        self.track = frame.uv[self.idx].copy()  # (m, 2) their positions in the latest image

    def follow(self, found: np.ndarray, ok: np.ndarray) -> None:
        """The points' positions in the latest image: ``found`` (m, 2) where ``ok`` (m,)."""
        self.track = np.where(ok[:, None], found, self.track).astype(np.float32)


class KeyframeTracker:
    """The latest keyframe's points tracked into each new image, and the window's points
    into each new keyframe (module docstring).

    Args:
        tracker: the stream's :class:`jaxvo.host.frontend.flow.GridFlowTracker` (its grid, camera,
            LK settings and the frame last pushed).
    """

    def __init__(self, tracker):
        self.t = tracker
        cfg = tracker.cfg
        rows, cols = tracker.grid
        self._sub = np.zeros(rows * cols, bool)
        self._sub[keyframe_index(tracker.grid, cfg.keyframe_stride)] = True
        self._window = max(int(cfg.keyframe_window) - 1, 0)  # older keyframes observed: W
        self._keys: list[_Keyframe] = []  # the window's keyframes, oldest first
        self._ref = 0  # points the latest keyframe's first pair tracked
        self._age = 0  # pairs since the latest keyframe

    def start(self) -> None:
        """The frame just pushed to the tracker becomes the keyframe (a new chain: the
        window forgets the earlier keyframes)."""
        self._keys = [_Keyframe(self.t.last, self._sub)]
        self._ref, self._age = 0, 0

    def _renew(self) -> None:
        self._keys = (self._keys + [_Keyframe(self.t.last, self._sub)])[-(self._window + 1):]
        self._ref, self._age = 0, 0

    def _displacement(self, flow) -> np.ndarray:
        """The pair's flow displacement on the grid (rows, cols, 2); cells without a valid
        track take the median."""
        rows, cols = self.t.grid
        d = (flow.uv_cur - flow.uv_prev).reshape(rows, cols, 2).copy()
        v = np.asarray(flow.valid).reshape(rows, cols)
        d[~v] = np.median(d[v], axis=0) if v.any() else 0.0
        return d

    def _predict(self, d: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Positions ``uv`` (m, 2) in the pair's previous image moved by the pair's
        displacement ``d`` (:meth:`_displacement`), bilinear on the grid."""
        rows, cols = self.t.grid
        uv0, cell = self.t.uv_grid[0], self.t.cfg.cell
        gx = np.clip((uv[:, 0] - uv0[0]) / cell, 0, max(cols - 1.001, 0))
        gy = np.clip((uv[:, 1] - uv0[1]) / cell, 0, max(rows - 1.001, 0))
        x0, y0 = gx.astype(np.int64), gy.astype(np.int64)
        x1, y1 = np.minimum(x0 + 1, cols - 1), np.minimum(y0 + 1, rows - 1)
        fx, fy = (gx - x0)[:, None], (gy - y0)[:, None]
        disp = (d[y0, x0] * (1 - fx) * (1 - fy) + d[y0, x1] * fx * (1 - fy)
                + d[y1, x0] * (1 - fx) * fy + d[y1, x1] * fx * fy)
        return (uv + disp).astype(np.float32)

    def _find(self, key: _Keyframe, depth: np.ndarray, levels: int):
        """The keyframe's points found in the frame last pushed, from their predicted
        positions: ``(pts_kf (n, 3), pts_cur (n, 3), valid (n,), ok (m,) bool, found (m, 2))``."""
        t, cfg, kf, cur = self.t, self.t.cfg, key.frame, self.t.last
        p0 = kf.uv[key.idx]
        found, st = t.lk_seeded(kf.grey, cur.grey, p0, key.track, levels)
        ok = lk_converged(found, st, width=t.width, height=t.height)
        found = np.where(ok[:, None], found, key.track)
        sel = np.flatnonzero(ok)
        ok[sel] = similar(kf.grey_f, p0[sel], cur.grey_f, found[sel], side=cfg.patch,
                          least=cfg.min_similarity)
        sel = np.flatnonzero(ok)
        z1, has_depth = depth_at(depth, found[sel], cfg)
        ok[sel] = has_depth
        idx = key.idx[ok]
        n = t.n
        valid = np.zeros(n, bool)
        valid[idx] = True
        pts_kf = np.zeros((n, 3), np.float32)
        pts_cur = np.zeros((n, 3), np.float32)
        pts_kf[idx] = backproject(kf.uv[idx], kf.z_grid[idx], t.K)
        if len(idx):
            pts_cur[idx] = backproject(found[ok], z1[has_depth], t.K)
        return pts_kf, pts_cur, valid, ok, found

    def push(self, flow, depth: np.ndarray) -> KeyframeFlow:
        """The keyframe flow of the frame just pushed to the tracker, whose pair flow is
        ``flow`` and depth ``depth`` (H, W) metres; renews the keyframe when it says so."""
        cfg, n, W = self.t.cfg, self.t.n, self._window
        every = cfg.keyframe_track_window  # the older keyframes' points found every pair
        keys = self._keys[-W:] if W else []  # the window slots' keyframes, the latest last
        slots = list(enumerate(keys, start=W - len(keys)))
        cell_prev = np.full(n, -1, np.int32)
        cell_prev[self._keys[-1].idx] = self._cell(self._keys[-1].track)
        win_cell = np.full((W, n), -1, np.int32)
        if every:
            for w, key in slots:
                win_cell[w, key.idx] = self._cell(key.track)
        d = self._displacement(flow)
        for key in self._keys:
            key.track = self._predict(d, key.track)
        latest = self._keys[-1]
        pts_kf, pts_cur, valid, ok, found = self._find(latest, depth, levels=1)
        latest.follow(found, ok)
        count = int(ok.sum())
        self._age += 1
        if self._age == 1:
            self._ref = count
        renew = (count < cfg.keyframe_overlap * self._ref or count < max(cfg.sample_size, 3)
                 or 0 < cfg.keyframe_max_age <= self._age)
        win_cur = np.zeros((W, n, 3), np.float32)
        win_valid = np.zeros((W, n), bool)
        new_kf = np.zeros((n, 3), np.float32)
        if renew or every:
            for w, key in slots:
                if key is latest:
                    win_cur[w], win_valid[w] = pts_cur, valid
                elif every:  # found every pair, as the latest keyframe's points are
                    _, win_cur[w], win_valid[w], ok_w, found_w = self._find(key, depth, levels=1)
                    key.follow(found_w, ok_w)
                else:
                    # the older keyframes' points were not searched since they were taken:
                    # their predicted positions may be a few pixels off, one pyramid level more
                    _, win_cur[w], win_valid[w], _, _ = self._find(key, depth, levels=2)
        if renew:
            cur = self.t.last
            use = cur.z_grid_ok & self._sub
            new_kf[use] = backproject(cur.uv[use], cur.z_grid[use], self.t.K)
            self._renew()
        return KeyframeFlow(pts_kf, pts_cur, valid, np.bool_(renew), win_cur, win_valid, new_kf,
                            cell_prev, win_cell)

    def _cell(self, uv: np.ndarray) -> np.ndarray:
        """(m,) int32 the grid cell holding each position ``uv`` (m, 2), -1 off the grid."""
        rows, cols = self.t.grid
        cell = self.t.cfg.cell
        c = np.floor(uv[:, 0] / cell).astype(np.int64)
        r = np.floor(uv[:, 1] / cell).astype(np.int64)
        on = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        return np.where(on, r * cols + c, -1).astype(np.int32)
