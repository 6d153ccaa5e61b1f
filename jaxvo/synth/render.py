"""Ray-cast renderer of textured boxes and an RGB-D sensor model (device side, pure JAX).

Every surface in the synthetic scenes is a face of an oriented box: the room is a box seen
from inside, furniture and moving objects are boxes seen from outside. One ray per pixel
centre, slab intersection with every box, nearest hit wins (an exact z-buffer); the result
is a texture coordinate into an atlas image per pixel, looked up on the host. Depth is the hit's z in the camera frame (the ray
direction is ``K^-1 [u, v, 1]``, so the ray parameter is the depth itself).

No cv2 here: the host side (``jaxvo.synth.sequence``) builds the scene arrays, the atlas and the
poses, remaps the atlas, and hands the colour back to ``finish_frame`` / ``composite_frame``
for shading and the sensor model.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

_NEAR = 1e-3  # metres; hits closer than this along the ray are ignored
_EPS = 1e-12
# Brightness per box face (-x, +x, -y, +y, -z, +z in the box frame): a fixed "light" so
# that the edges between faces of one box show as edges in the image.
_SHADE = (0.82, 0.94, 1.0, 0.72, 0.88, 0.78)


class Boxes(NamedTuple):
    """The boxes of a scene, ``B`` of them; shapes are static, values change per frame."""

    T_b_c: jax.Array  # (B, 4, 4) float32, camera points -> box frame (per frame)
    half: jax.Array  # (B, 3) float32 half extents, metres
    inside: jax.Array  # (B,) bool, seen from inside (the room)
    enabled: jax.Array  # (B,) bool, drawn at all (False also for boxes out of view)
    tex: jax.Array  # (B,) int32 first atlas texture of the box; face f uses tex + f
    density: jax.Array  # (B,) float32 texels per metre on the box's faces
    label: jax.Array  # (B,) int32 object id written to the mask, 0 = static


@dataclass(frozen=True)
class SensorModel:
    """The sensor effects applied on the device (static: each switch changes the program).

    Host code builds it from ``synth.SensorOptions``; see there for the meaning.
    """

    depth_noise: float = 0.0  # sigma = depth_noise * z^2 (metres); 0 = off
    edge_holes: bool = False
    min_depth: float = 0.0  # readings outside [min_depth, max_depth] become 0; 0/inf = off
    max_depth: float = float("inf")
    edge_threshold: float = 0.04  # relative depth jump between neighbours that makes a hole
    colour_sigma: float = 0.0  # 8-bit levels; 0 = off


def _hit_box(best, box, x, y, layout):
    """Merge one box's hits into the nearest-so-far ``best`` over a tile of rays.

    ``best`` is (depth, map_x, map_y, code) over the tile, ``x``, ``y`` the rays' normalised
    image coordinates (z = 1), ``layout`` the atlas's (n_tex, tile, cols).
    """
    n_tex, tile, cols = layout
    T_b_c, h, inside, _, tex, dens, lab = box
    R = T_b_c[:3, :3]
    o = T_b_c[:3, 3]
    d = [R[i, 0] * x + R[i, 1] * y + R[i, 2] for i in range(3)]  # ray in box frame
    lo, hi = [], []
    for i in range(3):
        inv = 1.0 / jnp.where(jnp.abs(d[i]) < _EPS, _EPS, d[i])
        t1 = (-h[i] - o[i]) * inv
        t2 = (h[i] - o[i]) * inv
        lo.append(jnp.minimum(t1, t2))
        hi.append(jnp.maximum(t1, t2))
    t_in = jnp.maximum(jnp.maximum(lo[0], lo[1]), lo[2])
    t_out = jnp.minimum(jnp.minimum(hi[0], hi[1]), hi[2])
    t = jnp.where(inside, t_out, t_in)
    # Face axis: the slab that sets the entry (outside) or the exit (inside).
    one, two = jnp.float32(1), jnp.float32(2)
    ax_in = jnp.where((lo[0] >= lo[1]) & (lo[0] >= lo[2]), 0.0,
                      jnp.where(lo[1] >= lo[2], one, two))
    ax_out = jnp.where((hi[0] <= hi[1]) & (hi[0] <= hi[2]), 0.0,
                       jnp.where(hi[1] <= hi[2], one, two))
    ax = jnp.where(inside, ax_out, ax_in)
    p = [o[i] + t * d[i] for i in range(3)]
    d_ax = jnp.where(ax == 0, d[0], jnp.where(ax == 1, d[1], d[2]))
    # Entering through the face the ray points away from; leaving through the one ahead.
    positive = jnp.where(inside, d_ax > 0, d_ax < 0)
    face = 2 * ax + positive.astype(jnp.float32)
    a1 = jnp.where(ax == 0, p[1], jnp.where(ax == 1, p[2], p[0]))
    a2 = jnp.where(ax == 0, p[2], jnp.where(ax == 1, p[0], p[1]))
    # Texture coordinates in texels; offsets per face and per box keep faces that share
    # a texture from showing the same texels.
    inv_tile = 1.0 / tile
    tu = (a1 + 31.7 * face + 5.3 * tex) * dens
    tv = (a2 + 17.3 * face + 2.9 * tex) * dens
    tu = tu - tile * jnp.floor(tu * inv_tile)
    tv = tv - tile * jnp.floor(tv * inv_tile)
    # Atlas image coordinates: tiles of ``tile`` texels in a grid of ``cols`` columns,
    # each padded by one wrapped texel so that bilinear look-ups never bleed into a
    # neighbour. Float arithmetic throughout: integer division does not vectorise.
    ti = tex + face
    ti = jnp.where(ti >= n_tex, ti - n_tex, ti)
    row = jnp.floor((ti + 0.5) * (1.0 / cols))
    col = ti - cols * row
    map_x = col * (tile + 2) + 1 + tu
    map_y = row * (tile + 2) + 1 + tv
    # Face and label packed in one float (exact: small integers), so the carry holds
    # four arrays: XLA's CPU loops recompute shared work once per carried array.
    code = face + 6 * lab
    better = (t_out >= t_in) & (t > _NEAR) & (t < best[0])
    # Materialise this box's hit once; the merges below then only read it.
    new = jax.lax.optimization_barrier(
        (jnp.where(better, t, best[0]), map_x, map_y, code))
    better = new[0] < best[0]
    return tuple(jnp.where(better, n, c) for n, c in zip(new, best))


@partial(jax.jit, static_argnames=("height", "width", "intr", "n_tex", "tile", "cols", "grid"))
def cast(boxes: Boxes, overlap: jax.Array, *, height: int, width: int,
         intr: tuple[float, float, float, float], n_tex: int, tile: int, cols: int,
         grid: tuple[int, int]):
    """Ray-cast one view (jitted entry point).

    The image is cut into ``grid`` tiles and each box is cast only in the tiles that its
    projection may touch (``overlap``, worked out on the host): a small box costs a few
    tiles, not a full frame. The texture look-up itself happens on the host
    (``cv2.remap`` of the atlas image with the maps returned here): XLA's CPU gathers are
    an order of magnitude slower.

    Args:
      boxes: the scene (``Boxes``) with ``T_b_c`` for this view.
      overlap: (B, gy * gx) bool, box b may show in tile k (row-major tiles); a
        conservative superset is fine, a missing tile loses pixels.
      height, width: image size, pixels (static), divisible by the grid.
      intr: (fx, fy, cx, cy) pixels (static).
      n_tex, tile, cols: atlas layout: textures, texels per tile side, tiles per row.
      grid: (gy, gx) tiles per column and per row (static).

    Returns:
      map_x, map_y (H, W) float32 atlas coordinates, texels; shade (H, W) float32 face
      brightness (0 where nothing is hit); depth (H, W) float32 metres (``inf`` where no box
      is hit); label (H, W) int32 (the box's ``label``, 0 where nothing is hit).
    """
    fx, fy, cx, cy = intr
    gy, gx = grid
    th, tw = height // gy, width // gx
    xs_box = (boxes.T_b_c, boxes.half, boxes.inside, boxes.enabled,
              boxes.tex.astype(jnp.float32), boxes.density, boxes.label.astype(jnp.float32))

    def one_tile(args):
        oy, ox, over, init = args
        xt = ((ox + jnp.arange(tw, dtype=jnp.float32) - cx) / fx)[None, :]
        yt = ((oy + jnp.arange(th, dtype=jnp.float32) - cy) / fy)[:, None]

        # A scan over boxes with the nearest hit so far as the carry: each step is
        # elementwise over the tile and the loop materialises the carry. Unrolled, XLA's
        # CPU fusion recomputes the chain per output and runs many times slower. Boxes that
        # cannot show in this tile skip the work (cond), not just the result.
        def step(best, item):
            box, flag = item
            return jax.lax.cond(flag & box[3], lambda b: _hit_box(b, box, xt, yt, layout),
                                lambda b: b, best), None

        rest = jax.tree.map(lambda a: a[1:], xs_box)
        best, _ = jax.lax.scan(step, init, (rest, over))
        return best

    # The first box (the room, seen everywhere) over the full frame, where XLA uses every
    # core; the others tile by tile on top of it (lax.map runs tiles one after another).
    layout = (n_tex, tile, cols)
    x = ((jnp.arange(width, dtype=jnp.float32) - cx) / fx)[None, :]
    y = ((jnp.arange(height, dtype=jnp.float32) - cy) / fy)[:, None]
    first = jax.tree.map(lambda a: a[0], xs_box)
    empty = (jnp.full((height, width), jnp.inf, jnp.float32),) + (
        jnp.zeros((height, width), jnp.float32),) * 3
    full = jax.lax.cond(first[3] & jnp.any(overlap[0]),
                        lambda b: _hit_box(b, first, x, y, layout), lambda b: b, empty)

    def totile(a):
        return a.reshape(gy, th, gx, tw).transpose(0, 2, 1, 3).reshape(gy * gx, th, tw)

    def untile(a):
        return a.reshape(gy, gx, th, tw).transpose(0, 2, 1, 3).reshape(height, width)

    oy = jnp.repeat(jnp.arange(gy, dtype=jnp.float32) * th, gx)
    ox = jnp.tile(jnp.arange(gx, dtype=jnp.float32) * tw, gy)
    tiles = jax.lax.map(one_tile, (oy, ox, overlap[1:].T, tuple(totile(a) for a in full)))

    best_t, map_x, map_y, code = (untile(a) for a in tiles)
    any_hit = jnp.isfinite(best_t)
    lab = jnp.floor((code + 0.5) * (1.0 / 6.0))
    face = code - 6 * lab
    # A where-chain, not a table gather: XLA's CPU gather is slow on a full frame.
    shade = jnp.zeros((height, width), jnp.float32)
    for f, val in enumerate(_SHADE):
        shade = jnp.where(any_hit & (face == f), val, shade)
    label = jnp.where(any_hit, lab, 0).astype(jnp.int32)
    return map_x, map_y, shade, best_t, label




def _hash32(x: jax.Array) -> jax.Array:
    """A 32-bit integer mixing function (lowbias32; C. Wellons, "hash-prospector")."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def _normal(seed: jax.Array, shape: tuple[int, ...], stream: int) -> jax.Array:
    """Near-normal noise (zero mean, unit variance) from hashed element counters.

    Counter-based like ``jax.random`` and as reproducible, but about ten times cheaper on
    CPU than threefry plus Box-Muller (no transcendental functions): the sum of the four
    bytes of a hash, i.e. the Irwin-Hall sum of four uniforms, whose tails stop at 3.46
    sigma. That is plenty for sensor noise.
    """
    n = 1
    for s in shape:
        n *= s
    idx = jnp.arange(n, dtype=jnp.uint32).reshape(shape)
    h = _hash32(_hash32(idx) ^ _hash32(seed + jnp.uint32(0x9E3779B9 * stream & 0xFFFFFFFF)))
    total = (h & 0xFF) + ((h >> 8) & 0xFF) + ((h >> 16) & 0xFF) + (h >> 24)
    # Four uniforms on [0, 1] (bytes / 255): mean 2, variance 4 / 12.
    return (total.astype(jnp.float32) * (1.0 / 255.0) - 2.0) * jnp.float32(3.0 ** 0.5)


def _depth_edges(depth: jax.Array, threshold: float) -> jax.Array:
    """Pixels next to a depth jump larger than ``threshold`` times the depth (4-neighbours)."""
    pad = jnp.pad(depth, 1, mode="edge")
    c = pad[1:-1, 1:-1]
    jump = jnp.zeros_like(c, dtype=bool)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        nb = pad[dy:dy + depth.shape[0], dx:dx + depth.shape[1]]
        jump = jump | (jnp.abs(nb - c) > threshold * jnp.minimum(nb, c))
    # Grow by one pixel: real sensors lose a band of 2-3 pixels along silhouettes.
    pj = jnp.pad(jump, 1)
    grown = jump
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        grown = grown | pj[dy:dy + depth.shape[0], dx:dx + depth.shape[1]]
    return grown


def apply_sensor(key: jax.Array, bgr: jax.Array, depth: jax.Array, synthetic: jax.Array,
                 gain: jax.Array, *, model: SensorModel):
    """Sensor effects on the pixels where ``synthetic`` is true.

    Args:
      key: PRNG key for this frame.
      bgr: (H, W, 3) float32 ideal colour, [0, 255].
      depth: (H, W) float32 ideal depth, metres (``inf`` / 0 = nothing).
      synthetic: (H, W) bool, pixels the effects apply to (all, or the inserted objects).
      gain: () float32 exposure gain applied to synthetic pixels.
      model: the static ``SensorModel``.

    Returns:
      bgr (H, W, 3) uint8 and depth (H, W) float32 metres with 0 = no reading.
    """
    seed = jax.random.bits(key, (), jnp.uint32)
    out = bgr * jnp.where(synthetic[..., None], gain, 1.0)
    if model.colour_sigma > 0:
        noise = model.colour_sigma * _normal(seed, bgr.shape, 1)
        out = out + jnp.where(synthetic[..., None], noise, 0.0)
    out = jnp.clip(jnp.round(out), 0, 255).astype(jnp.uint8)

    z = jnp.where(jnp.isfinite(depth), depth, 0.0)
    dz = jnp.zeros_like(z)
    if model.depth_noise > 0:
        dz = model.depth_noise * z * z * _normal(seed, z.shape, 2)
    drop = jnp.zeros(z.shape, bool)
    if model.edge_holes:
        drop = _depth_edges(jnp.where(z > 0, z, 1e3), model.edge_threshold)
    zs = z + dz
    drop = drop | (zs < model.min_depth) | (zs > model.max_depth)
    zs = jnp.where(synthetic & drop, 0.0, jnp.where(synthetic, zs, z))
    return out, zs


@partial(jax.jit, static_argnames=("model",))
def finish_frame(key: jax.Array, texels: jax.Array, shade: jax.Array, depth: jax.Array,
                 gain: jax.Array, *, model: SensorModel):
    """Shade the textured colour and apply the sensor model to a fully synthetic frame.

    Args:
      key: PRNG key for this frame.
      texels: (H, W, 3) uint8 or float32 texture colour (the remapped atlas).
      shade: (H, W) float32 face brightness; depth: (H, W) float32 metres (``inf`` = none).
      gain: () float32 exposure gain.

    Returns:
      bgr (H, W, 3) uint8 and depth (H, W) float32 metres, 0 = no reading.
    """
    bgr = texels.astype(jnp.float32) * shade[..., None]
    synthetic = jnp.ones(depth.shape, bool)
    return apply_sensor(key, bgr, depth, synthetic, gain, model=model)


@partial(jax.jit, static_argnames=("model",))
def composite_frame(key: jax.Array, texels: jax.Array, shade: jax.Array, depth: jax.Array,
                    label: jax.Array, gain: jax.Array, bg_bgr: jax.Array, bg_depth: jax.Array,
                    *, model: SensorModel):
    """Insert rendered objects into a real frame, z-buffered against its depth.

    A real pixel without a reading (0) counts as far away, so an object covers it.

    Args:
      texels, shade, depth, label: the rendered objects (as from ``cast`` + remap).
      bg_bgr: (H, W, 3) uint8 real colour; bg_depth: (H, W) float32 real depth, metres.
      Others as in ``finish_frame``; the sensor effects touch only the inserted pixels.

    Returns:
      bgr (H, W, 3) uint8, depth (H, W) float32 metres (0 = no reading), label (H, W) int32.
    """
    front = jnp.isfinite(depth) & ((bg_depth <= 0) | (depth < bg_depth))
    obj = texels.astype(jnp.float32) * shade[..., None]
    mixed_bgr = jnp.where(front[..., None], obj, bg_bgr.astype(jnp.float32))
    mixed_z = jnp.where(front, depth, bg_depth)
    bgr8, z = apply_sensor(key, mixed_bgr, mixed_z, front, gain, model=model)
    return bgr8, z, jnp.where(front, label, 0)
