"""Frame-to-keyframe tracking: the keyframe's static points in the ego-motion (device side).

Frame to frame, every pair adds its error to the pose chain, also while the camera hovers
over the same view. The host tracks the latest keyframe's grid points into each new image
(:class:`jaxvo.host.flow.KeyframeTracker`); here those tracks join the pair's points in one
ego-motion fit. A keyframe point ``p_kf`` enters as the pair ``(T_prev_kf p_kf, p_cur)``
with ``T_prev_kf = inv(T_w_prev) T_w_kf``: the same rigid motion ``T_cur_prev`` explains
it, so the fit, its robust weights and its noise model are those of the pair
(:func:`jaxvo.core.egomotion.fit_egomotion`), and the keyframe's points anchor the pose to
the keyframe's instead of to the previous frame's only. Only the points the temporal
model held static on the keyframe's image (no moving evidence) are used; with too few the
fit is the pair's alone. The per-frame pair flow stays what the segmentation and the
temporal model read.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params
from jaxvo.core.geometry import invert_pose
from jaxvo.core.noise import NoiseScale, Points, frame_points


class KeyframeState(NamedTuple):
    """The latest keyframe (carried by the pipeline)."""

    T_w_kf: jax.Array  # (4, 4) float32, the keyframe's pose (camera-to-world)
    static: jax.Array  # (n,) bool, grid points of the keyframe's image held static then
    count: jax.Array  # () int32, keyframes taken so far (the first frame is one)


def init_keyframe(T_w_c0, n: int) -> KeyframeState:
    """The first frame is the first keyframe; nothing is known to move yet."""
    return KeyframeState(jnp.asarray(T_w_c0, jnp.float32), jnp.ones((n,), bool), jnp.int32(1))


def keyframe_points(state: KeyframeState, kf, T_w_prev, params: Params, *, focal,
                    scale: NoiseScale) -> Points:
    """The keyframe's static tracked points as pairs ``(previous frame, current frame)``.

    Args:
      state: the keyframe; kf: the pair's ``KeyframeFlow`` (``pts_kf``, ``pts_cur`` (n, 3)
        metres, ``valid`` (n,)); T_w_prev: (4, 4) pose of the pair's previous camera.
      params, focal, scale: as :func:`jaxvo.core.noise.frame_points`.
    Returns:
      :class:`Points` with ``src`` in the previous camera's frame.
    """
    T_prev_kf = invert_pose(T_w_prev) @ state.T_w_kf
    src = kf.pts_kf @ T_prev_kf[:3, :3].T + T_prev_kf[:3, 3]
    return frame_points(src, kf.pts_cur, kf.valid & state.static, params, focal=focal,
                        scale=scale)


def join_points(a: Points, b: Points) -> Points:
    """The points of ``a`` then those of ``b`` (n_a + n_b) as one set, ``a``'s tests."""
    cat = lambda x, y: jnp.concatenate([x, y], axis=-1)
    return Points(cat(a.src, b.src), cat(a.dst, b.dst), jax.tree.map(cat, a.noise, b.noise),
                  cat(a.valid, b.valid), a.thr, a.tie)


def update_keyframe(state: KeyframeState, renew, T_w_c, static) -> KeyframeState:
    """After the pair: the current frame becomes the keyframe where ``renew`` () bool (the
    host's decision), at its pose ``T_w_c`` (4, 4), with ``static`` (n,) bool its grid
    points held static (on the current image's grid)."""
    return KeyframeState(jnp.where(renew, T_w_c, state.T_w_kf),
                         jnp.where(renew, static, state.static),
                         state.count + renew.astype(jnp.int32))
