"""Front-to-back compositing of tile lists, with a memory-light custom VJP.

Per pixel, the Gaussians of its tile are walked nearest first (3DGS numerics):
  q = [dx dy] conic [dx dy]^T, alpha = min(alpha_clamp, o exp(-q/2)); alpha < 1/255 or q < 0 is
  skipped; when T (1 - alpha) would drop under 1e-4 the pixel stops before that Gaussian.
Outputs per pixel: colour sum_k w(T_k) c_k alpha_k T_k (weights from `wabe.Blend`), final
transmittance T, and accumulated depth sum_k d_k alpha_k T_k (depth and T use standard weights).

`composite` groups tiles into chunks of similar list length (longest first) and walks each chunk in
a `lax.while_loop` whose trip count is that chunk's longest list (not the capacity), a few slots
per iteration; chunks run one after another (`lax.map`) so their per-pixel state stays in cache.
The forward keeps, per pixel, only the final transmittance and one past its last composited slot.
The custom VJP walks each list back to front, as the reference CUDA backward does: a slot counts
iff its alpha passes the cut-offs and it lies before that last slot (no termination logic is
replayed), T is recovered as T_{j+1} / (1 - a_j) (a_j <= 0.99 keeps this stable), and the suffix
sums the gradient needs are accumulated on the way. Per-slot gradients are summed over the tile's
pixels immediately, so memory is O(tiles x capacity x params), never O(pixels x capacity).
`composite_reference.composite_reference` is the same function written densely with `cumprod`
for autodiff, used to test the custom VJP.

Packed per-Gaussian parameters, (N, 7 + C): mean x, mean y, conic a, b, c, opacity, depth, colour.
Pixels are laid out per tile: (num_tiles, 256, ...), tile-major in row order.
"""

from __future__ import annotations

import dataclasses
import math
from functools import partial

import jax
import jax.numpy as jnp
from jax import lax

from gae_jax.render import cpu_kernel, wabe
from gae_jax.render.projection import ALPHA_THRESHOLD
from gae_jax.render.tiles import TILE_SIZE

TRANSMITTANCE_MIN = 1e-4
PIXELS_PER_TILE = TILE_SIZE * TILE_SIZE
NUM_GEOMETRY_PARAMS = 7  # mean (2), conic (3), opacity, depth
KERNELS = ("auto", "jax")


@dataclasses.dataclass(frozen=True)
class CompositeConfig:
    """Static settings of the compositor (hashable, part of the jit cache key).

    Attributes:
      blend: colour weighting (`wabe.Blend`).
      alpha_clamp: upper bound on alpha (0.99 as in Inria 3DGS, so 1 - alpha >= 0.01).
      tiles_x, tiles_y: tile grid.
      unroll, unroll_backward: list slots processed per loop iteration of the forward and the
        backward walk (speed only; 8 and 8 measured best on a 2-core AVX-512 CPU).
      tiles_per_chunk: tiles walked together; chunks run one after another so that their
        per-pixel state stays in cache, and tiles are grouped by list length so that each chunk
        stops after its own longest list.
      front_contributors: how many first contributors of a pixel count for the visibility weight
        (0: the visibility statistic is not computed).
      visibility_beta: beta of the visibility weight exp(-beta (1 - T)) alpha.
      kernel: "auto" composites float32 on CPU with the C++ kernel (`cpu_kernel`) when it is
        built, and with the pure-JAX walk elsewhere (GPU/TPU, float64, kernel not built);
        "jax" always uses the pure-JAX walk (the reference the kernel is tested against).
      kernel_threads: the kernel's worker threads (0: one per hardware thread).
    """

    blend: wabe.Blend
    alpha_clamp: float
    tiles_x: int
    tiles_y: int
    unroll: int = 8
    unroll_backward: int = 8
    tiles_per_chunk: int = 32
    front_contributors: int = 0
    visibility_beta: float = wabe.PAPER_BETA
    kernel: str = "auto"
    kernel_threads: int = 0

    def __post_init__(self):
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {KERNELS}, got {self.kernel!r}")
        if self.kernel_threads < 0:
            raise ValueError(f"kernel_threads must be >= 0, got {self.kernel_threads}")


def pixel_centres(tiles_x: int, tiles_y: int, dtype=jnp.float32) -> jax.Array:
    """(num_tiles, 256, 2) pixel-centre coordinates (x, y) in the per-tile layout."""
    ty, tx = jnp.meshgrid(jnp.arange(tiles_y, dtype=dtype), jnp.arange(tiles_x, dtype=dtype),
                          indexing="ij")
    py, px = jnp.meshgrid(jnp.arange(TILE_SIZE, dtype=dtype), jnp.arange(TILE_SIZE, dtype=dtype),
                          indexing="ij")
    x = tx.reshape(-1, 1) * TILE_SIZE + px.reshape(1, -1) + 0.5
    y = ty.reshape(-1, 1) * TILE_SIZE + py.reshape(1, -1) + 0.5
    return jnp.stack([x, y], axis=-1)


def tiles_to_image(values: jax.Array, tiles_x: int, tiles_y: int, width: int,
                   height: int) -> jax.Array:
    """(num_tiles, 256, ...) per-tile layout -> (height, width, ...) image."""
    rest = values.shape[2:]
    v = values.reshape((tiles_y, tiles_x, TILE_SIZE, TILE_SIZE) + rest)
    v = jnp.moveaxis(v, 2, 1).reshape((tiles_y * TILE_SIZE, tiles_x * TILE_SIZE) + rest)
    return v[:height, :width]


def _alpha(pix, g, alpha_clamp):
    """Alpha of one list slot at every pixel of every tile of a chunk.

    Args:
      pix: (T, 256, 2) pixel centres; g: (T, K) packed parameters of this slot's Gaussians.
    Returns gauss = exp(-q/2), alpha (each (T, 256)), and valid (T, 256) bool.
    """
    dx = pix[..., 0] - g[:, None, 0]
    dy = pix[..., 1] - g[:, None, 1]
    q = g[:, None, 2] * dx * dx + 2.0 * g[:, None, 3] * dx * dy + g[:, None, 4] * dy * dy
    gauss = jnp.exp(-0.5 * q)
    alpha = jnp.minimum(alpha_clamp, g[:, None, 5] * gauss)
    valid = (alpha >= ALPHA_THRESHOLD) & (q >= 0.0)
    return gauss, alpha, valid


def _step_masks(transmittance, done, alpha, valid):
    """Which pixels composite this slot, which stop at it, and the transmittance after it."""
    t_next = transmittance * (1.0 - alpha)
    live = valid & ~done
    stop = live & (t_next < TRANSMITTANCE_MIN)
    use = live & ~stop
    return use, done | stop, jnp.where(use, t_next, transmittance)


def _moment_basis(dtype) -> jax.Array:
    """(256, 6) tile-local pixel-centre moments [1, x, y, x^2, x y, y^2] in the per-tile layout."""
    py, px = jnp.meshgrid(jnp.arange(TILE_SIZE, dtype=dtype), jnp.arange(TILE_SIZE, dtype=dtype),
                          indexing="ij")
    x = px.reshape(-1) + 0.5
    y = py.reshape(-1) + 0.5
    return jnp.stack([jnp.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)


@dataclasses.dataclass(frozen=True)
class _Chunking:
    """How tiles are grouped: `order` (num_chunks * tiles_per_chunk,) tile ids, longest lists first,
    padded with the id `num_tiles` (an empty tile)."""

    order: jax.Array
    num_chunks: int
    tiles_per_chunk: int
    num_tiles: int

    def split(self, per_tile, fill=0):
        """(T, ...) per-tile values -> (chunks, tiles_per_chunk, ...) in chunk order."""
        pad = jnp.full((1,) + per_tile.shape[1:], fill, per_tile.dtype)
        padded = jnp.concatenate([per_tile, pad])
        return padded[self.order].reshape(
            (self.num_chunks, self.tiles_per_chunk) + per_tile.shape[1:])

    def merge(self, per_chunk):
        """Inverse of `split`: (chunks, tiles_per_chunk, ...) -> (T, ...)."""
        flat = per_chunk.reshape((-1,) + per_chunk.shape[2:])
        out = jnp.zeros((self.num_tiles + 1,) + flat.shape[1:], flat.dtype)
        return out.at[self.order].set(flat)[: self.num_tiles]


def _chunking(kept, tiles_per_chunk: int) -> _Chunking:
    """Groups tiles into chunks of similar list length (longest first)."""
    num_tiles = kept.shape[0]
    per_chunk = max(1, min(tiles_per_chunk, num_tiles))
    num_chunks = -(-num_tiles // per_chunk)
    pad = num_chunks * per_chunk - num_tiles
    # Negated lengths sort descending; ties keep tile order (a stable integer sort).
    _, order = lax.sort((-kept, jnp.arange(num_tiles, dtype=jnp.int32)), num_keys=1)
    order = jnp.concatenate([order, jnp.full((pad,), num_tiles, jnp.int32)])
    return _Chunking(order=order, num_chunks=num_chunks, tiles_per_chunk=per_chunk,
                     num_tiles=num_tiles)


def _chunk_inputs(cfg, table, kept, packed):
    """Per-chunk lists (C, t, cap', K), pixel centres (C, t, 256, 2), origins (C, t, 2), slots (C,)."""
    chunks = _chunking(kept, cfg.tiles_per_chunk)
    block = math.lcm(cfg.unroll, cfg.unroll_backward)
    pad_slots = (-table.shape[1]) % block
    table = jnp.pad(table, ((0, 0), (0, pad_slots)), constant_values=-1)
    rows = jnp.concatenate([packed, jnp.zeros((1, packed.shape[1]), packed.dtype)])
    lists = rows[jnp.where(table < 0, packed.shape[0], table)]
    pix = pixel_centres(cfg.tiles_x, cfg.tiles_y, packed.dtype)
    origins = pix[:, 0, :] - 0.5
    slots = jnp.max(chunks.split(kept), axis=1)
    return chunks, (chunks.split(lists), chunks.split(pix), chunks.split(origins), slots)


def _forward_chunk(cfg: CompositeConfig, lists, pix, num_slots, num_channels):
    """Front-to-back walk over one chunk of tiles.

    Returns per-pixel colour (t, 256, C), transmittance, depth sum, one past the last slot that
    was composited (int32), and per-slot pixel counts and visibility weights (t, cap').
    """
    num_tiles, cap = lists.shape[0], lists.shape[1]
    shape = (num_tiles, PIXELS_PER_TILE)
    blend = cfg.blend
    dtype = lists.dtype
    carry0 = dict(
        j=jnp.int32(0),
        t=jnp.ones(shape, dtype),
        done=jnp.zeros(shape, bool),
        color=jnp.zeros(shape + (num_channels,), dtype),
        depth=jnp.zeros(shape, dtype),
        last=jnp.zeros(shape, jnp.int32),
        seen=jnp.zeros(shape, jnp.int32) if cfg.front_contributors > 0 else None,
        pixels=jnp.zeros((num_tiles, cap), dtype),
        visibility=jnp.zeros((num_tiles, cap), dtype) if cfg.front_contributors > 0 else None,
    )

    def cond(c):
        return (c["j"] < num_slots) & jnp.any(~c["done"])

    def body(c):
        c = dict(c)
        block = lax.dynamic_slice_in_dim(lists, c["j"], cfg.unroll, axis=1)
        uses, vis, weights, contribs = [], [], [], []
        for u in range(cfg.unroll):
            g = block[:, u]
            _, alpha, valid = _alpha(pix, g, cfg.alpha_clamp)
            t = c["t"]
            use, done, t_next = _step_masks(t, c["done"], alpha, valid)
            contrib = jnp.where(use, alpha * t, 0.0)
            weighted = contrib * blend.weight(t) if blend.weights_forward else contrib
            c["last"] = jnp.where(use, c["j"] + (u + 1), c["last"])
            # The barrier steers XLA's fusion so that alpha (and its exp) is not recomputed in
            # every consumer; measured faster, though XLA may still duplicate cheap ops.
            weighted, contrib, use, done, t_next = lax.optimization_barrier(
                (weighted, contrib, use, done, t_next))
            weights.append(weighted)
            contribs.append(contrib)
            uses.append(use)
            if cfg.front_contributors > 0:
                front = use & (c["seen"] < cfg.front_contributors)
                vis.append(jnp.where(front, jnp.exp(-cfg.visibility_beta * (1.0 - t)) * alpha,
                                     0.0))
                c["seen"] = c["seen"] + use.astype(jnp.int32)
            c["t"], c["done"] = t_next, done
        colours = block[:, :, NUM_GEOMETRY_PARAMS:]
        c["color"] = c["color"] + sum(
            w[..., None] * colours[:, None, u] for u, w in enumerate(weights))
        c["depth"] = c["depth"] + sum(w * block[:, None, u, 6] for u, w in enumerate(contribs))
        counts = jnp.sum(jnp.stack(uses, axis=1), axis=-1, dtype=dtype)
        c["pixels"] = lax.dynamic_update_slice_in_dim(c["pixels"], counts, c["j"], axis=1)
        if cfg.front_contributors > 0:
            c["visibility"] = lax.dynamic_update_slice_in_dim(
                c["visibility"], jnp.max(jnp.stack(vis, axis=1), axis=-1), c["j"], axis=1)
        c["j"] = c["j"] + cfg.unroll
        return c

    c = lax.while_loop(cond, body, carry0)
    return c["color"], c["t"], c["depth"], c["last"], c["pixels"], c["visibility"]


def _scatter_to_gaussians(per_slot, table, num_gaussians, reduce="sum"):
    """(T, cap', ...) per-slot values -> (N, ...) per-Gaussian, summed (or maxed) over tiles."""
    cap = table.shape[1]
    flat_index = jnp.where(table < 0, num_gaussians, table).reshape(-1)
    values = per_slot[:, :cap].reshape((-1,) + per_slot.shape[2:])
    seg = jax.ops.segment_sum if reduce == "sum" else jax.ops.segment_max
    out = seg(values, flat_index, num_segments=num_gaussians + 1)
    if reduce == "max":
        out = jnp.maximum(out, 0.0)
    return out[:num_gaussians]


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _composite(cfg: CompositeConfig, table, kept, packed):
    out, _ = _composite_fwd(cfg, table, kept, packed)
    return out


def _composite_fwd(cfg, table, kept, packed):
    num_channels = packed.shape[1] - NUM_GEOMETRY_PARAMS
    chunks, (lists, pix, _, slots) = _chunk_inputs(cfg, table, kept, packed)
    color, t, depth, last, pixels, vis = lax.map(
        lambda a: _forward_chunk(cfg, a[0], a[1], a[2], num_channels), (lists, pix, slots))
    color, t, depth, last, pixels = (chunks.merge(x) for x in (color, t, depth, last, pixels))
    vis = chunks.merge(vis) if cfg.front_contributors > 0 else None
    stats = _per_gaussian_stats(cfg, table, pixels, vis, packed.shape[0])
    return (color, t, depth, stats), (table, kept, packed, t, last)


def _backward_chunk(cfg, lists, pix, origins, last, cot):
    """Back-to-front gradient walk over one chunk (as the reference CUDA backward does).

    Args:
      lists: (t, cap', K) packed parameters; pix: (t, 256, 2); origins: (t, 2) tile corners.
      last: (t, 256) int32 one past each pixel's last composited slot (from the forward).
      cot: this chunk's per-pixel gC (t, 256, C), gD (t, 256), gT * T_final (t, 256) and
        T_final (t, 256).
    Returns per-slot packed-parameter gradients (t, cap', K).

    A slot j is composited at a pixel iff its alpha passes the cut-offs and j < last, so no
    termination logic is replayed. Walking back, T_j = T_{j+1} / (1 - a_j) and the suffix
        Q_j = gT T_final + sum_{k > j} a_k T_k (F'(T_k) gC . c_k + gD d_k)
    give dL/da_j = f_j gC . c_j + gD d_j T_j - Q_j / (1 - a_j), with f = w(T) T for WABE (T
    otherwise) and F' = d[f]/dT. Per slot only three planes are formed -- d_q = dL/dq and the
    colour and depth weights -- and every per-tile pixel sum is a matrix product: d_q with the
    moment basis gives the mean and conic gradients (and, since alpha = o exp(-q/2), the opacity
    gradient -2 sum(d_q) / o); the weights with [gC | gD] give the colour and depth gradients.
    """
    g_color, g_depth, g_t_final, t_final = cot
    num_tiles, cap, k = lists.shape
    num_channels = k - NUM_GEOMETRY_PARAMS
    blend = cfg.blend
    basis = _moment_basis(lists.dtype)
    g_planes = [g_color[..., ch] for ch in range(num_channels)]
    g_targets = jnp.concatenate([g_color, g_depth[..., None]], axis=-1)  # (t, 256, C + 1)
    unroll = cfg.unroll_backward
    top = jnp.max(last)
    top = (top + unroll - 1) // unroll * unroll

    def cond(c):
        return c["j"] > 0

    def body(c):
        c = dict(c)
        start = c["j"] - unroll
        block = lax.dynamic_slice_in_dim(lists, start, unroll, axis=1)
        dq_planes, weight_planes = [None] * unroll, [None] * (2 * unroll)
        for u in reversed(range(unroll)):
            g = block[:, u]
            _, alpha, valid = _alpha(pix, g, cfg.alpha_clamp)
            use = valid & (start + u < last)
            one_minus = 1.0 - alpha
            t = jnp.where(use, c["t"] / one_minus, c["t"])
            alpha, use, t = lax.optimization_barrier((alpha, use, t))
            gc_dot = sum(g_planes[ch] * g[:, None, NUM_GEOMETRY_PARAMS + ch]
                         for ch in range(num_channels))
            depth = g[:, None, 6]
            w = blend.weight(t)
            f = t * w if blend.weights_forward else t
            contrib = jnp.where(use, alpha * t, 0.0)
            d_alpha = f * gc_dot + g_depth * depth * t - c["q"] / one_minus
            q = c["q"] + contrib * (blend.weight_times_t_derivative(t) * gc_dot
                                    + g_depth * depth)
            colour_weight = jnp.where(use, alpha * f, 0.0)
            depth_weight = contrib
            if blend.mode == "wabe_grad":
                d_alpha, colour_weight, depth_weight = (d_alpha * w, colour_weight * w,
                                                        depth_weight * w)
            # A clamped alpha does not depend on the Gaussian's opacity or shape.
            d_q = jnp.where(use & (alpha < cfg.alpha_clamp), -0.5 * alpha * d_alpha, 0.0)
            c["t"], c["q"], d_q, colour_weight, depth_weight = lax.optimization_barrier(
                (t, q, d_q, colour_weight, depth_weight))
            dq_planes[u] = d_q
            weight_planes[2 * u], weight_planes[2 * u + 1] = colour_weight, depth_weight
        m = jnp.stack(dq_planes, axis=1) @ basis  # (t, U, 6): d_q x [1, x, y, xx, xy, yy]
        targets = jnp.einsum("tkp,tpc->tkc", jnp.stack(weight_planes, axis=1), g_targets)
        targets = targets.reshape(num_tiles, unroll, 2, num_channels + 1)
        mx = block[..., 0] - origins[:, None, 0]
        my = block[..., 1] - origins[:, None, 1]
        s_x = m[..., 1] - mx * m[..., 0]
        s_y = m[..., 2] - my * m[..., 0]
        s_xx = m[..., 3] - 2.0 * mx * m[..., 1] + mx * mx * m[..., 0]
        s_xy = m[..., 4] - mx * m[..., 2] - my * m[..., 1] + mx * my * m[..., 0]
        s_yy = m[..., 5] - 2.0 * my * m[..., 2] + my * my * m[..., 0]
        a_, b_, c_, o_ = block[..., 2], block[..., 3], block[..., 4], block[..., 5]
        d_opacity = -2.0 * m[..., 0] / jnp.where(o_ > 0, o_, 1.0)
        grads = jnp.concatenate([jnp.stack([
            -2.0 * (a_ * s_x + b_ * s_y),
            -2.0 * (b_ * s_x + c_ * s_y),
            s_xx, 2.0 * s_xy, s_yy, d_opacity, targets[:, :, 1, num_channels],
        ], axis=-1), targets[:, :, 0, :num_channels]], axis=-1)
        c["grads"] = lax.dynamic_update_slice_in_dim(c["grads"], grads, start, axis=1)
        c["j"] = start
        return c

    carry0 = dict(
        j=top.astype(jnp.int32),
        t=t_final,
        q=g_t_final,
        grads=jnp.zeros((num_tiles, cap, k), lists.dtype),
    )
    return lax.while_loop(cond, body, carry0)["grads"]


def _composite_bwd(cfg, residuals, cotangents):
    """Back-to-front gradient walk per chunk (see `_backward_chunk`), scattered to Gaussians."""
    table, kept, packed, t_final, last = residuals
    g_color, g_t, g_depth, _ = cotangents
    chunks, (lists, pix, origins, _) = _chunk_inputs(cfg, table, kept, packed)
    cot = tuple(chunks.split(x) for x in (g_color, g_depth, g_t * t_final, t_final))
    grads = lax.map(lambda a: _backward_chunk(cfg, a[0], a[1], a[2], a[3], a[4]),
                    (lists, pix, origins, chunks.split(last), cot))
    d_packed = _scatter_to_gaussians(chunks.merge(grads), table, packed.shape[0])
    return None, None, d_packed


_composite.defvjp(_composite_fwd, _composite_bwd)


def _per_gaussian_stats(cfg, table, pixels, visibility, num_gaussians):
    """Per-slot pixel counts and visibility weights (T, cap) -> per Gaussian (N,) each."""
    visibility = (_scatter_to_gaussians(visibility, table, num_gaussians, reduce="max")
                  if cfg.front_contributors > 0 else jnp.zeros((num_gaussians,), pixels.dtype))
    return _scatter_to_gaussians(pixels, table, num_gaussians), visibility


@partial(jax.custom_vjp, nondiff_argnums=(0,))
def _composite_kernel(cfg: CompositeConfig, table, kept, packed):
    out, _ = _composite_kernel_fwd(cfg, table, kept, packed)
    return out


def _composite_kernel_fwd(cfg, table, kept, packed):
    color, t, depth, last, pixels, vis = cpu_kernel.forward(cfg, table, kept, packed)
    stats = _per_gaussian_stats(cfg, table, pixels, vis, packed.shape[0])
    return (color, t, depth, stats), (table, kept, packed, t, last)


def _composite_kernel_bwd(cfg, residuals, cotangents):
    table, kept, packed, t_final, last = residuals
    g_color, g_t, g_depth, _ = cotangents
    grads = cpu_kernel.backward(cfg, table, kept, packed, t_final, last, g_color, g_t, g_depth)
    return None, None, _scatter_to_gaussians(grads, table, packed.shape[0])


_composite_kernel.defvjp(_composite_kernel_fwd, _composite_kernel_bwd)


def uses_kernel(cfg: CompositeConfig, dtype) -> bool:
    """True when `composite` runs the C++ kernel for `dtype` parameters on a CPU device."""
    return cfg.kernel == "auto" and jnp.dtype(dtype) == jnp.float32 and cpu_kernel.available()


def composite(cfg: CompositeConfig, table: jax.Array, kept: jax.Array, packed: jax.Array):
    """Composites tile lists.

    Args:
      table: (num_tiles, capacity) int32 Gaussian indices, nearest first, -1 padding.
      kept: (num_tiles,) int32 number of valid entries per row of `table`.
      packed: (N, 7 + C) packed parameters (see module docstring).
    Returns:
      color (T, 256, C), transmittance (T, 256), depth (T, 256) in the per-tile layout, and
      (pixels (N,), visibility (N,)): per Gaussian, the number of pixels it was composited into
      and its visibility weight (max over pixels of exp(-beta (1-T)) alpha among each pixel's
      first `front_contributors` contributors; zeros when that is 0). Statistics carry no
      gradient.
    """
    if uses_kernel(cfg, packed.dtype):
        color, t, depth, stats = lax.platform_dependent(
            table, kept, packed, cpu=partial(_composite_kernel, cfg),
            default=partial(_composite, cfg))
    else:
        color, t, depth, stats = _composite(cfg, table, kept, packed)
    return color, t, depth, jax.tree_util.tree_map(lax.stop_gradient, stats)
