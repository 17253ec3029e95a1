"""`render.walk_count.replay` against the C++ compositor it counts: the same per-pixel
transmittance and last composited slot, and a pair count between the kernel's own lower bound
and the tile lists' size."""

import numpy as np

from gae_jax.render import walk_count
from gae_jax.render import cpu_kernel
from gae_jax.render import composite as comp
from gae_jax.render import wabe
from tests.test_cpu_kernel import tile_inputs

# numpy's exp against the kernel's polynomial (~1 ulp): a pixel at a cut-off may flip.
FLIPPED_PIXELS = 1e-3


def test_replay_reproduces_the_kernels_walk_and_counts_between_its_bounds():
    assert cpu_kernel.available(), cpu_kernel.unavailable_reason()
    # capacity 128 < the busiest lists: overflowing tiles are walked to their capacity
    grid, bins, packed = tile_inputs(5, n=4000, width=64, height=48, capacity=128)
    assert int(bins.overflow_tiles) > 0
    cfg = comp.CompositeConfig(blend=wabe.named("standard"), alpha_clamp=0.99, **grid)
    _, transmittance, _, last, _, _ = cpu_kernel.forward(cfg, bins.table, bins.kept, packed)
    walk = walk_count.replay(bins.table, bins.kept, packed, grid["tiles_x"])
    last, transmittance = np.asarray(last), np.asarray(transmittance)
    assert np.mean(walk["last"] != last) <= FLIPPED_PIXELS
    np.testing.assert_allclose(walk["transmittance"], transmittance, rtol=1e-5, atol=1e-6)
    # terminated pixels exist, so early termination is exercised
    assert np.any(transmittance < 1e-3)
    lists = np.asarray(bins.table) >= 0
    kept = np.minimum(np.asarray(bins.kept), lists.shape[1])
    held = np.array([lists[t, :k].sum() for t, k in enumerate(kept)])
    # at least every slot up to a pixel's last composited one, at most the whole list
    reached_last = np.array([lists[t, :m].sum() for t, m in enumerate(last.max(axis=1))])
    assert np.all(walk["slots"] >= reached_last)
    assert np.all(walk["slots"] <= held)
    assert walk["reached_pairs"] == 256 * int(walk["slots"].sum())
    assert 0 < walk["evaluated_pairs"] < walk["reached_pairs"]


def test_a_tile_stops_after_the_gaussian_that_ends_its_last_pixel_and_padding_is_not_counted():
    """Two tiles, hand-built: tile 0 holds three broad Gaussians of opacity 0.99 (T 1 -> 1e-2
    -> 1e-4 -> below 1e-4 at the third, which ends every pixel) then two more; tile 1 two faint
    wide ones, a small one and padding. Tile 0 reaches 3 of its 5 listed slots (the padding
    between them is skipped), tile 1 its three Gaussians. The small one (conic 1, opacity 0.5)
    reaches |y - 8| <= sqrt(2 ln 127.5) = 3.11 px: rows 5-10 of the tile, 3-12 with the row of
    margin on each side, so 160 of its 256 pixels are evaluated."""
    broad = [8.0, 8.0, 1e-4, 0.0, 1e-4, 0.99, 1.0, 1.0, 0.0, 0.0]
    faint = [24.0, 8.0, 0.1, 0.0, 0.1, 0.2, 1.0, 0.0, 1.0, 0.0]
    small = [24.0, 8.0, 1.0, 0.0, 1.0, 0.5, 1.0, 0.0, 0.0, 1.0]
    packed = np.array([broad] * 5 + [faint] * 2 + [small], np.float32)
    table = np.array([[0, -1, 1, 2, 3, 4], [5, 6, 7, -1, -1, -1]], np.int32)
    kept = np.array([6, 3], np.int32)
    walk = walk_count.replay(table, kept, packed, tiles_x=2)
    np.testing.assert_array_equal(walk["slots"], [3, 3])
    assert walk["reached_pairs"] == 256 * 6
    assert walk["evaluated_pairs"] == 256 * 5 + 160
    np.testing.assert_array_equal(walk["last"][0], 3)  # after the second broad one (slot 2)
    assert np.all((walk["transmittance"][0] > 1e-4) & (walk["transmittance"][0] < 3e-4))
    cfg = comp.CompositeConfig(blend=wabe.named("standard"), alpha_clamp=0.99, tiles_x=2,
                               tiles_y=1)
    _, transmittance, _, last, _, _ = cpu_kernel.forward(cfg, table, kept, packed)
    np.testing.assert_array_equal(walk["last"], last)
    # 1 - alpha near 0.01 magnifies the exps' ulp of difference a hundredfold
    np.testing.assert_allclose(walk["transmittance"], transmittance, rtol=1e-4)
