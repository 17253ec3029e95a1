"""How many (pixel, Gaussian) pairs the C++ compositor's forward resolves and how many it
evaluates: a numpy replay of its walk (`gae_jax/render/kernel/composite_cpu.cc`, `forward_tile`).

A tile walks its list nearest first up to its kept length, skips padding (-1), and stops after
the Gaussian at which its last live pixel terminated. The standard tile algorithm evaluates all
256 pixels at every Gaussian it reaches: `reached_pairs` = 256 x the slots reached, fewer than
the lists hold (early termination) and than tiles x 256 x the longest list (what the pure-JAX
walk pads to). The kernel evaluates only the rows of the tile that the Gaussian's alpha can
reach (`reach` in the kernel, `reach_rows` here): `evaluated_pairs`, one exp each.
`benchmarks/render.py` divides these counts by the forward's time and sets them against the
kernel's exp rate.

The replay computes each pixel's state as the kernel does (numpy's float32 exp where the kernel
has its polynomial, ~1 ulp apart) and returns it, so `tests/test_walk_count.py` checks it against
the kernel's own outputs (transmittance and one past the last composited slot, per pixel).
"""

from __future__ import annotations

import numpy as np

ALPHA_THRESHOLD = 1.0 / 255.0
TRANSMITTANCE_MIN = 1e-4
TILE = 16


def reach_rows(oy, my, a, b, c, o):
    """(first, last) rows of a tile (inclusive; first > last: none) where a Gaussian's alpha can
    reach 1/255, as the kernel's `reach` computes them (float32, one row of margin), for arrays
    of tile origins oy and Gaussians (mean y, conic a, b, c, opacity)."""
    f32 = np.float32
    oy, my, a, b, c, o = (np.asarray(v, f32) for v in (oy, my, a, b, c, o))
    det = a * c - b * b
    every = ~((det > 0) & (a > 0))
    none = ~(o * f32(255) > 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        half = np.sqrt(f32(2) * np.log(f32(255) * o) * a / det)
    every |= ~(half < f32(TILE))
    low, high = my - half - oy - f32(0.5), my + half - oy - f32(0.5)
    with np.errstate(invalid="ignore"):
        first = np.maximum(0, np.floor(np.nan_to_num(low)).astype(np.int64) - 1)
        last = np.minimum(TILE - 1, np.ceil(np.nan_to_num(high)).astype(np.int64) + 1)
    first = np.where(every, 0, np.where(none, 1, first))
    last = np.where(every, TILE - 1, np.where(none, 0, last))
    return first, last


def replay(table, kept, packed, tiles_x: int, alpha_clamp: float = 0.99) -> dict:
    """The forward walk of every tile at once.

    Args:
      table: (T, cap) int32 tile lists, -1 padding; kept: (T,) int32 list lengths;
      packed: (N, 7 + C) float32 mean x, mean y, conic a, b, c, opacity, depth, colour.
    Returns dict: reached_pairs and evaluated_pairs (ints), slots (T,) non-padding slots each
      tile reached, transmittance (T, 256) and last (T, 256) int32 as the kernel returns them.
    """
    table = np.asarray(table)
    kept = np.asarray(kept)
    packed = np.asarray(packed, np.float32)
    num_tiles, capacity = table.shape
    tile = np.arange(num_tiles)
    pixel = np.arange(TILE * TILE)
    px = ((tile % tiles_x) * TILE)[:, None] + (pixel % TILE)[None, :] + np.float32(0.5)
    py = ((tile // tiles_x) * TILE)[:, None] + (pixel // TILE)[None, :] + np.float32(0.5)
    px, py = px.astype(np.float32), py.astype(np.float32)
    transmittance = np.ones((num_tiles, TILE * TILE), np.float32)
    last = np.zeros((num_tiles, TILE * TILE), np.int32)
    done = np.zeros((num_tiles, TILE * TILE), bool)
    stopped = np.zeros(num_tiles, bool)
    slots = np.zeros(num_tiles, np.int64)
    rows = np.zeros(num_tiles, np.int64)
    clamp = np.float32(alpha_clamp)
    for j in range(capacity):
        index = table[:, j]
        reached = (j < kept) & ~stopped & (index >= 0)
        if not reached.any():
            if not ((j < kept) & ~stopped).any():
                break
            continue
        slots += reached
        g = packed[np.maximum(index, 0)]
        first, last_row = reach_rows(py[:, 0] - np.float32(0.5), g[:, 1], g[:, 2], g[:, 3],
                                     g[:, 4], g[:, 5])
        rows += np.where(reached, np.maximum(last_row - first + 1, 0), 0)
        dx, dy = px - g[:, 0:1], py - g[:, 1:2]
        q = g[:, 2:3] * dx * dx + np.float32(2) * g[:, 3:4] * dx * dy + g[:, 4:5] * dy * dy
        with np.errstate(over="ignore", under="ignore"):
            alpha = np.minimum(clamp, g[:, 5:6] * np.exp(np.float32(-0.5) * q))
        valid = (alpha >= np.float32(ALPHA_THRESHOLD)) & (q >= 0)
        t_next = transmittance * (np.float32(1) - alpha)
        live = valid & ~done & reached[:, None]
        stop = live & (t_next < np.float32(TRANSMITTANCE_MIN))
        use = live & ~stop
        last = np.where(use, j + 1, last)
        transmittance = np.where(use, t_next, transmittance)
        done |= stop
        stopped |= reached & done.all(axis=1)
    return dict(reached_pairs=int(slots.sum()) * TILE * TILE,
                evaluated_pairs=int(rows.sum()) * TILE, slots=slots,
                transmittance=transmittance, last=last)
