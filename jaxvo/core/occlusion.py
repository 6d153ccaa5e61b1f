"""The occlusion memory: where the surface in view lies nearer than what was seen there
before (device side).

The static scene never comes nearer than itself: a surface that appears in front of what
the camera saw along the same ray is an occluder, a mover (after Kim, Kim and Kim's
Occlusion Accumulation, ICRA 2020). Each grid point of the new image is moved by the
camera's last motion into the last image and its depth compared with the last image's
depths around it; how much nearer it lies accumulates, carried by the camera's motion
(anchored in the world, not on the objects as the moving evidence is), and clears where
what lay behind appears again. The memory keeps no depth of the background itself, only
"nearer than before", so an occluder that stays in view keeps its mark while it covers what
was seen, and a mover in view from the first frame has none until it moves over what the
camera saw (depth order, :mod:`jaxvo.core.background`, speaks for that one).

It is a grid computation: one lookup of four neighbours per grid point and frame.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.config import Params, StepOptions
from jaxvo.core.geometry import invert_pose, tiny
from jaxvo.core.noise import NoiseScale


class OcclusionState(NamedTuple):
    """What the memory keeps of the last image (carried by the pipeline)."""

    depth: jax.Array  # (n,) float32 the last image's depth at its grid points, metres (0 none)
    # (n,) float32 on the last image's grid: how much nearer its surface lies than what was
    # seen there before, metres, where that is beyond the depth noise (else 0)
    nearer: jax.Array
    T_w_c: jax.Array  # (4, 4) float32 the last image's camera pose


def init_occlusion(*, grid: tuple[int, int]) -> OcclusionState:
    """No image seen yet: nothing to compare with."""
    n = grid[0] * grid[1]
    return OcclusionState(jnp.zeros((n,), jnp.float32), jnp.zeros((n,), jnp.float32),
                          jnp.eye(4, dtype=jnp.float32))


def forget_occlusion(state: OcclusionState, forget, T_w_c) -> OcclusionState:
    """The memory with its marks cleared where ``forget`` () bool (they were accumulated
    under a background that has been switched, :mod:`jaxvo.core.background`) and its
    image's pose the committed one ``T_w_c`` (4, 4) (after a switch, the new chain's)."""
    return state._replace(nearer=jnp.where(forget, 0.0, state.nearer), T_w_c=T_w_c)


class OcclusionInputs(NamedTuple):
    """What one image gives the occlusion memory (:func:`update_occlusion`)."""

    depth: jax.Array  # (n,) float32 this image's depth at its grid points, metres (0 none)
    uv: jax.Array  # (n, 2) float32 the grid points' pixels in this image
    T_w_c: jax.Array  # (4, 4) float32 this image's camera pose (camera-to-world)
    camera: jax.Array  # (4,) float32 the intrinsics fx, fy, cx, cy, pixels
    scale: NoiseScale  # the sensor noise (its depth_coeff: the depth readings' noise)
    tie: jax.Array  # () float32 the near-tie test chi2_1(confidence) (Points.tie)


class OcclusionOut(NamedTuple):
    """What the occlusion memory says of one image's grid points (:func:`update_occlusion`)."""

    # (n,) float32 how much nearer each point lies than what was seen there before, metres,
    # where that is beyond the depth noise (else 0)
    nearer: jax.Array
    occluded: jax.Array  # (n,) bool the points held nearer than what was seen: occluders


def _into_last(state: OcclusionState, depth, uv, T_w_c, camera):
    """Each grid point of this image (depth (n,), pixels uv (n, 2)) in the last camera:
    ``(depth there (n,), continuous grid column and row (n,), (n,))``."""
    fx, fy, cx, cy = camera[0], camera[1], camera[2], camera[3]
    x = (uv[:, 0] - cx) * depth / fx
    y = (uv[:, 1] - cy) * depth / fy
    T = invert_pose(state.T_w_c) @ T_w_c  # this camera's points into the last camera
    p = jnp.stack([x, y, depth])
    q = T[:3, :3] @ p + T[:3, 3:4]
    z = q[2]
    safe = jnp.where(z > tiny(), z, 1.0)
    u = fx * q[0] / safe + cx
    v = fy * q[1] / safe + cy
    return z, u, v


def update_occlusion(state: OcclusionState, inputs: OcclusionInputs, params: Params, *,
                     cfg: StepOptions, grid: tuple[int, int]
                     ) -> tuple[OcclusionState, OcclusionOut]:
    """One image of the occlusion memory: ``(state, OcclusionOut)`` on this image's grid.

    Each grid point with a depth reading is back-projected (``inputs.camera``;
    ``inputs.uv`` its pixel), moved into the last camera (the poses ``state.T_w_c`` and
    ``inputs.T_w_c``, this image's), and its depth there compared with the last image's depths at
    the four grid points around where it lands: by how much it lies outside their range
    (nearer: positive; farther: negative; within: 0, so that the grid's sampling of a
    sloping surface counts as nothing). That change is added to the memory of the nearest
    of the four (anchored in the world by the camera's motion); the sum stays where it is
    beyond the depth noise of two readings at the test ``inputs.tie`` (``chi2_1(confidence)``)
    and nearer (``occluded``), and is 0 elsewhere: a surface no nearer than what was seen,
    or one that receded to show what lay behind. A point without a reading, or landing
    where the last image had none, learns nothing (0).

    Args:
      state: the last image's depths, memory and pose; inputs: this image's
      :class:`OcclusionInputs`; params: unread (the memory has no numeric setting of its
      own: its test is ``inputs.tie``); cfg: static, ``cfg.cell`` the grid cell, pixels;
      grid: static (rows, cols).
    """
    del params  # every stage takes the same arguments; this one's test comes in inputs.tie
    depth, uv, T_w_c, camera, scale, tie = inputs
    rows, cols = grid
    cell = cfg.cell
    z_last, u, v = _into_last(state, depth, uv, T_w_c, camera)
    gx = (u + 0.5) / cell - 0.5  # grid point (c, r) sits at pixel ((c + .5) cell - .5, ...)
    gy = (v + 0.5) / cell - 0.5
    c0 = jnp.floor(gx).astype(jnp.int32)
    r0 = jnp.floor(gy).astype(jnp.int32)
    corners = [(r0 + dr, c0 + dc) for dr in (0, 1) for dc in (0, 1)]
    inside = jnp.stack([(r >= 0) & (r < rows) & (c >= 0) & (c < cols) for r, c in corners])
    idx = jnp.stack([jnp.clip(r, 0, rows - 1) * cols + jnp.clip(c, 0, cols - 1)
                     for r, c in corners])  # (4, n)
    seen = jnp.where(inside, state.depth[idx], 0.0)
    known = (depth > 0) & (z_last > tiny()) & jnp.all(seen > 0, axis=0)
    lo, hi = jnp.min(seen, axis=0), jnp.max(seen, axis=0)
    change = jnp.where(z_last < lo, lo - z_last, jnp.where(z_last > hi, hi - z_last, 0.0))
    near = jnp.clip(jnp.round(gy), 0, rows - 1).astype(jnp.int32) * cols + jnp.clip(
        jnp.round(gx), 0, cols - 1).astype(jnp.int32)
    acc = jnp.where(known, state.nearer[near] + change, 0.0)
    sigma = scale.depth_coeff * z_last * z_last
    occluded = known & (acc > 0) & (acc * acc > tie * 2.0 * sigma * sigma)
    nearer = jnp.where(occluded, acc, 0.0).astype(jnp.float32)
    new = OcclusionState(jnp.asarray(depth, jnp.float32), nearer,
                         jnp.asarray(T_w_c, jnp.float32))
    return new, OcclusionOut(nearer=nearer, occluded=occluded)
