"""Static-shape tile binning: per 16x16 tile, the depth-sorted list of Gaussians that touch it.

Every shape here is fixed at trace time:
  * `capacity` entries per tile (the per-tile list length); a tile that is touched by more Gaussians
    keeps its nearest `capacity` and the rest are counted in `overflow_tiles` / `dropped_pairs`;
  * `max_pairs` (Gaussian, tile) pairs in all; pairs are generated nearest-Gaussian first, so when
    the budget is short it is again the farthest Gaussians that are dropped, and counted.
With `max_pairs = num_tiles * capacity` (the default) the result is exact whenever no tile overflows.

Order inside a tile is by camera depth, ties broken by Gaussian index (3DGS sorts on the 64-bit key
tile|depth; we sort Gaussians by (depth, index) once, then pairs on the 32-bit key tile|rank).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jax import lax

from gae_jax.render import cpu_kernel

TILE_SIZE = 16
# Safety margin on the extent so that rounding in the compositor can never give alpha >= 1/255 to
# a pixel that binning left out; over-inclusion only costs work.
EXTENT_RELATIVE_MARGIN = 1e-3
EXTENT_ABSOLUTE_MARGIN = 1e-2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TileBins:
    """Per-tile Gaussian lists.

    Attributes:
      table: (num_tiles, capacity) int32 Gaussian indices, nearest first, -1 as padding.
      kept: (num_tiles,) int32 number of valid entries in each row.
      counts: (num_tiles,) int32 number of Gaussians that touch each tile (before capacity).
      num_slots: () int32 max of `kept`: how many list positions the compositor has to walk.
      overflow_tiles: () int32 tiles whose count exceeded the capacity.
      dropped_pairs: () int32 (Gaussian, tile) pairs lost to the capacity or the pair budget.
      tiles_x, tiles_y: grid size (static).
    """

    table: jax.Array
    kept: jax.Array
    counts: jax.Array
    num_slots: jax.Array
    overflow_tiles: jax.Array
    dropped_pairs: jax.Array
    tiles_x: int = dataclasses.field(metadata=dict(static=True))
    tiles_y: int = dataclasses.field(metadata=dict(static=True))


def grid_size(width: int, height: int) -> tuple[int, int]:
    """(tiles_x, tiles_y) covering a width x height image."""
    return -(-width // TILE_SIZE), -(-height // TILE_SIZE)


def tile_rectangles(means2d, extents, visible, width: int, height: int):
    """Inclusive tile ranges (x0, x1, y0, y1), each (N,) int32, touched by each Gaussian.

    A pixel column j is touched when |j + 0.5 - mean_x| <= extent_x (same for rows); culled
    Gaussians and Gaussians touching no pixel get an empty range (x1 < x0).
    """
    ext = extents * (1.0 + EXTENT_RELATIVE_MARGIN) + EXTENT_ABSOLUTE_MARGIN

    def axis_range(mean, e, size):
        lo = jnp.ceil(jnp.clip(mean - e - 0.5, -1.0, size + 1.0)).astype(jnp.int32)
        hi = jnp.floor(jnp.clip(mean + e - 0.5, -1.0, size + 1.0)).astype(jnp.int32)
        lo = jnp.maximum(lo, 0)
        hi = jnp.minimum(hi, size - 1)
        return lo // TILE_SIZE, jnp.where(hi >= lo, hi // TILE_SIZE, lo // TILE_SIZE - 1)

    x0, x1 = axis_range(means2d[:, 0], ext[:, 0], width)
    y0, y1 = axis_range(means2d[:, 1], ext[:, 1], height)
    empty = ~visible | (x1 < x0) | (y1 < y0)
    return (jnp.where(empty, 0, x0), jnp.where(empty, -1, x1),
            jnp.where(empty, 0, y0), jnp.where(empty, -1, y1))


def depth_order(depths, visible, kernel: str = "auto"):
    """(N,) int32 permutation: visible Gaussians by (depth, index), culled ones last. `kernel`
    "auto" sorts with the C++ argsort on CPU where it is built (XLA:CPU's stable two-operand
    sort is several times slower), "jax" with `lax.sort`; the permutation is the same."""
    n = depths.shape[0]
    # Non-negative IEEE floats order like their bit patterns, and integer sorts are far faster on
    # CPU than float sorts (which go through a total-order comparator).
    bits = lax.bitcast_convert_type(jnp.maximum(depths, 0.0).astype(jnp.float32), jnp.int32)
    key = jnp.where(visible, bits, jnp.iinfo(jnp.int32).max)

    def in_jax(key):
        return lax.sort((key, jnp.arange(n, dtype=jnp.int32)), num_keys=1, is_stable=True)[1]

    if kernel == "auto" and cpu_kernel.available():
        return lax.platform_dependent(key, cpu=cpu_kernel.argsort, default=in_jax)
    return in_jax(key)


def bin_gaussians(means2d, extents, depths, visible, width: int, height: int, capacity: int,
                  max_pairs: int | None = None, kernel: str = "auto") -> TileBins:
    """Builds the per-tile lists for an image of width x height.

    Args:
      means2d: (N, 2) projected means; extents: (N, 2) half-widths; depths: (N,); visible: (N,).
      capacity: list length per tile.
      max_pairs: static budget of (Gaussian, tile) pairs; defaults to num_tiles * capacity.
      kernel: "auto" sorts the depth order (see `depth_order`) and builds the lists
        (`cpu_kernel.bin_tiles`, one walk over the Gaussians) with the C++ kernels on CPU where
        they are built; "jax" with `lax.sort` both times. The lists are the same.
    """
    if capacity < 1:
        raise ValueError(f"tile capacity must be >= 1, got {capacity}")
    n = means2d.shape[0]
    tiles_x, tiles_y = grid_size(width, height)
    num_tiles = tiles_x * tiles_y
    budget = num_tiles * capacity if max_pairs is None else int(max_pairs)
    if budget < 1:
        raise ValueError(f"max_pairs must be >= 1, got {max_pairs}")

    x0, x1, y0, y1 = tile_rectangles(means2d, extents, visible, width, height)
    span_x = x1 - x0 + 1
    per_gaussian = span_x * (y1 - y0 + 1)

    # Exact per-tile counts from a 2D difference array (independent of the pair budget).
    diff = jnp.zeros((tiles_y + 1, tiles_x + 1), jnp.int32)
    touched = per_gaussian > 0
    one = touched.astype(jnp.int32)
    diff = diff.at[y0, x0].add(one).at[y0, x1 + 1].add(-one)
    diff = diff.at[y1 + 1, x0].add(-one).at[y1 + 1, x1 + 1].add(one)
    counts = jnp.cumsum(jnp.cumsum(diff, axis=0, dtype=jnp.int32), axis=1, dtype=jnp.int32)[:tiles_y, :tiles_x].reshape(-1)

    order = depth_order(depths, visible, kernel)
    total = jnp.sum(per_gaussian, dtype=jnp.int32)

    def in_jax(x0, x1, y0, y1, order):
        return _lists_in_jax(x0, x1, y0, y1, order, tiles_x, num_tiles, capacity, budget)

    if kernel == "auto" and cpu_kernel.available():
        def in_cpp(x0, x1, y0, y1, order):
            return cpu_kernel.bin_tiles(x0, x1, y0, y1, order, tiles_x, num_tiles, capacity,
                                        budget)
        table, kept_all = lax.platform_dependent(x0, x1, y0, y1, order, cpu=in_cpp,
                                                 default=in_jax)
    else:
        table, kept_all = in_jax(x0, x1, y0, y1, order)
    kept = jnp.minimum(kept_all, capacity)
    return TileBins(
        table=table,
        kept=kept,
        counts=counts,
        num_slots=jnp.max(kept) if num_tiles > 0 else jnp.int32(0),
        overflow_tiles=jnp.sum(counts > capacity, dtype=jnp.int32),
        dropped_pairs=total - jnp.sum(kept, dtype=jnp.int32),
        tiles_x=tiles_x,
        tiles_y=tiles_y,
    )


def _lists_in_jax(x0, x1, y0, y1, order, tiles_x: int, num_tiles: int, capacity: int,
                  budget: int):
    """(table (T, capacity) int32, pairs of the budget per tile (T,) int32) by sorting the
    budget's (tile, rank) keys; `cpu_kernel.bin_tiles` gives the same by one walk."""
    n = x0.shape[0]
    span_x = x1 - x0 + 1
    count_by_rank = (span_x * (y1 - y0 + 1))[order]
    ends = jnp.cumsum(count_by_rank, dtype=jnp.int32)
    starts = ends - count_by_rank
    total = ends[-1] if n > 0 else jnp.int32(0)

    # Pair p belongs to the Gaussian of rank r with starts[r] <= p < ends[r].
    marks = jnp.zeros(budget + 1, jnp.int32).at[jnp.minimum(ends, budget)].add(1)
    rank = jnp.minimum(jnp.cumsum(marks, dtype=jnp.int32)[:budget], max(n - 1, 0))
    pair = jnp.arange(budget, dtype=jnp.int32)
    valid = pair < total
    local = pair - starts[rank]
    g = order[rank]
    width_g = jnp.maximum(span_x[g], 1)
    tile = (y0[g] + local // width_g) * tiles_x + x0[g] + local % width_g
    tile = jnp.where(valid, tile, num_tiles)

    rank_bits = max(1, math.ceil(math.log2(max(n, 2))))
    tile_bits = max(1, math.ceil(math.log2(num_tiles + 1)))
    if rank_bits + tile_bits <= 31:
        key = jnp.where(valid, (tile << rank_bits) | rank, jnp.iinfo(jnp.int32).max)
        key = lax.sort(key)
        sorted_tile = jnp.where(key == jnp.iinfo(jnp.int32).max, num_tiles, key >> rank_bits)
        sorted_rank = key & ((1 << rank_bits) - 1)
    else:
        sorted_tile, sorted_rank = lax.sort((tile, rank), num_keys=2)

    kept_all = jnp.zeros(num_tiles + 1, jnp.int32).at[sorted_tile].add(1)[:num_tiles]
    first = jnp.cumsum(kept_all, dtype=jnp.int32) - kept_all
    kept = jnp.minimum(kept_all, capacity)
    slot = jnp.arange(capacity, dtype=jnp.int32)
    src = jnp.minimum(first[:, None] + slot[None, :], budget - 1)
    table = jnp.where(slot[None, :] < kept[:, None], order[sorted_rank[src]], -1)
    return table.astype(jnp.int32), kept_all
