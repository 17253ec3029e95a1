"""The C++ kernels: the compositor against the pure-JAX compositor, the brute-force renderer and float64
autodiff of the dense reference: values, VJPs, statistics, WABE modes, overflowing tiles, vmap,
and the dispatch (kernel for float32 on CPU; pure JAX for float64, kernel="jax", or no kernel);
the argsort against numpy's stable argsort."""

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.render import composite as comp
from gae_jax.render.composite_reference import composite_reference
from gae_jax.render import cpu_kernel, splat, tiles, wabe
from gae_jax.render.projection import project
from gae_jax.render.tiles import bin_gaussians
from tests import bruteforce
from tests.test_splat import BLENDS, random_scene

# float32 against float32: the kernel's exp polynomial and XLA's differ by an ulp or two, and
# the sums run in another order.
VALUE_TOLERANCE = 1e-5
GRADIENT_RELATIVE_TOLERANCE = 1e-5


def test_kernel_is_built_and_registered():
    assert cpu_kernel.available(), cpu_kernel.unavailable_reason()


def tile_inputs(seed, n, width, height, capacity, channels=3, dtype=np.float32):
    """(config kwargs, table, kept, packed) of a random scene binned at `capacity`."""
    g, camera = random_scene(seed, n=n, width=width, height=height, channels=channels,
                             scale_range=(0.02, 0.4), dtype=dtype)
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, width, height, capacity)
    packed = jnp.concatenate([p.means2d, p.conics, p.opacities[:, None], p.depths[:, None],
                              g.colors], axis=-1)
    packed = jnp.where(p.visible[:, None], packed, 0.0)
    return dict(tiles_x=bins.tiles_x, tiles_y=bins.tiles_y), bins, packed


def both_paths(blend, grid, bins, packed, front=0):
    """{kernel: (outputs, vjp)} for the kernel ("auto") and the pure-JAX path."""
    out = {}
    for kernel in ("auto", "jax"):
        cfg = comp.CompositeConfig(blend=blend, alpha_clamp=0.99, front_contributors=front,
                                   kernel=kernel, **grid)
        fn = jax.jit(lambda x, cfg=cfg: comp.composite(cfg, bins.table, bins.kept, x))
        outputs, vjp = jax.vjp(lambda x, fn=fn: fn(x)[:3], packed)
        out[kernel] = (fn(packed), vjp)
    return out


@pytest.mark.parametrize("front", [0, 10])
@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_kernel_matches_pure_jax_values_stats_and_vjp(blend, front):
    # capacity 48 < the busiest tile's list: overflowing tiles are part of the test
    grid, bins, packed = tile_inputs(3, n=300, width=70, height=50, capacity=48)
    assert int(bins.overflow_tiles) > 0
    paths = both_paths(blend, grid, bins, packed, front)
    (ours, ours_vjp), (ref, ref_vjp) = paths["auto"], paths["jax"]
    for a, b in zip(ours[:3], ref[:3]):
        np.testing.assert_allclose(a, b, atol=VALUE_TOLERANCE)
    np.testing.assert_array_equal(ours[3][0], ref[3][0])  # pixel counts
    np.testing.assert_allclose(ours[3][1], ref[3][1], atol=VALUE_TOLERANCE)  # visibility
    if front:
        assert float(jnp.max(ours[3][1])) > 0.1
    for seed in range(2):
        keys = jax.random.split(jax.random.PRNGKey(seed), 3)
        cot = tuple(jax.random.normal(k, o.shape) for k, o in zip(keys, ours[:3]))
        (g_ours,), (g_ref,) = ours_vjp(cot), ref_vjp(cot)
        scale = float(jnp.max(jnp.abs(g_ref)))
        assert scale > 1.0
        np.testing.assert_allclose(g_ours, g_ref, atol=GRADIENT_RELATIVE_TOLERANCE * scale)


@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_row_culling_keeps_every_pixel_a_gaussian_reaches(blend):
    """The kernel walks only the rows of a tile where a Gaussian's alpha can reach 1/255.
    Hand-built Gaussians probe that bound: thin rotated ellipses whose reach ends near row and
    tile borders, opacities from just above 1/255 to 0.99, one below 1/255 (no row), and an
    indefinite conic (q < 0 somewhere: every row kept). Every tile lists every Gaussian; values,
    pixel counts and VJP against the pure-JAX walk, which evaluates every pixel."""
    rng = np.random.default_rng(4)
    n = 40
    angle = rng.uniform(0, np.pi, n)
    # sigma across 0.3-1.5 px, along 2-12 px
    across, along = rng.uniform(0.3, 1.5, n), rng.uniform(2.0, 12.0, n)
    rot = np.stack([np.cos(angle), np.sin(angle), -np.sin(angle), np.cos(angle)], -1)
    rot = rot.reshape(n, 2, 2)
    cov = rot @ (np.eye(2) * np.stack([along, across], -1)[:, None, :] ** 2) @ np.swapaxes(rot, 1, 2)
    conic = np.linalg.inv(cov)
    opacity = np.concatenate([[1.02 / 255, 1.2 / 255, 0.9 / 255], rng.uniform(0.05, 0.99, n - 3)])
    # centres near tile rows' borders (16 px) and pixel centres
    centre = np.stack([rng.uniform(2, 30, n), 16 + rng.choice([-8.5, -0.5, 0.0, 0.49, 7.9], n)
                       + rng.uniform(-0.02, 0.02, n)], -1)
    packed = np.concatenate([centre, conic[:, 0, 0:1], conic[:, 0, 1:2], conic[:, 1, 1:2],
                             opacity[:, None], rng.uniform(1, 2, (n, 1)),
                             rng.uniform(0, 1, (n, 3))], -1)
    packed[0, 2:5] = [0.5, 1.0, 0.5]  # indefinite: q < 0 off its axes
    table = np.tile(np.arange(n, dtype=np.int32), (4, 1))
    bins = types.SimpleNamespace(table=jnp.asarray(table), kept=jnp.full((4,), n, jnp.int32))
    paths = both_paths(blend, dict(tiles_x=2, tiles_y=2), bins,
                       jnp.asarray(packed, jnp.float32))
    (ours, ours_vjp), (ref, ref_vjp) = paths["auto"], paths["jax"]
    for a, b in zip(ours[:3], ref[:3]):
        np.testing.assert_allclose(a, b, atol=VALUE_TOLERANCE)
    np.testing.assert_array_equal(ours[3][0], ref[3][0])
    assert float(jnp.min(ours[1])) < 0.5  # the tiles are well covered
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    cot = tuple(jax.random.normal(k, o.shape) for k, o in zip(keys, ours[:3]))
    (g_ours,), (g_ref,) = ours_vjp(cot), ref_vjp(cot)
    scale = float(jnp.max(jnp.abs(g_ref)))
    np.testing.assert_allclose(g_ours, g_ref, atol=GRADIENT_RELATIVE_TOLERANCE * scale)


@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_kernel_vjp_matches_float64_autodiff_of_dense_reference(x64, blend):
    grid, bins, packed = tile_inputs(6, n=60, width=32, height=32, capacity=64)
    assert packed.dtype == jnp.float32
    cfg = comp.CompositeConfig(blend=blend, alpha_clamp=0.99, **grid)
    out, vjp = jax.vjp(jax.jit(lambda x: comp.composite(cfg, bins.table, bins.kept, x)[:3]),
                       packed)
    packed64 = jnp.asarray(np.asarray(packed), jnp.float64)
    ref, ref_vjp = jax.vjp(lambda x: composite_reference(cfg, bins.table, x), packed64)
    rng = np.random.default_rng(0)
    cot = tuple(rng.normal(size=o.shape) for o in ref)
    (g_ref,) = ref_vjp(cot)
    for a, b in zip(out, ref):
        np.testing.assert_allclose(a, b, atol=VALUE_TOLERANCE)
    (g_ours,) = vjp(tuple(jnp.asarray(c, jnp.float32) for c in cot))
    scale = np.abs(g_ref).max()
    assert scale > 1e-2
    np.testing.assert_allclose(g_ours, g_ref, atol=1e-4 * scale)


@pytest.mark.parametrize("channels", [1, 5])
def test_kernel_render_matches_bruteforce_with_any_channel_count(channels):
    # 45 x 29: partial tiles at the right and bottom edges are cropped away
    g, camera = random_scene(2, n=80, width=45, height=29, channels=channels)
    background = np.linspace(0.1, 0.9, channels)
    out = jax.jit(lambda g: splat.render(g, camera, background=jnp.asarray(background),
                                         tile_capacity=128))(g)
    image, alpha, _ = bruteforce.render(g, camera, background)
    assert out.image.shape == (29, 45, channels)
    err = np.abs(np.asarray(out.image, np.float64) - image).max(axis=-1)
    assert np.mean(err > 6e-6) <= 0.002 and np.median(err) < 1e-5, err.max()
    np.testing.assert_allclose(out.alpha, alpha, atol=1e-5)


def lowered_text(fn, *args) -> str:
    return jax.jit(fn).lower(*args).as_text()


def test_dispatch_uses_the_kernel_only_for_float32_with_kernel_auto(monkeypatch):
    g, camera = random_scene(1, n=20, width=32, height=32)
    assert cpu_kernel.FORWARD_TARGET in lowered_text(
        lambda g: splat.render(g, camera, tile_capacity=32).image, g)
    assert cpu_kernel.FORWARD_TARGET not in lowered_text(
        lambda g: splat.render(g, camera, tile_capacity=32, kernel="jax").image, g)
    grad = jax.grad(lambda g: jnp.sum(splat.render(g, camera, tile_capacity=32).image))
    assert cpu_kernel.BACKWARD_TARGET in lowered_text(grad, g)
    # Without a built kernel the same call composites in pure JAX, with the same image.
    image = jax.jit(lambda g: splat.render(g, camera, tile_capacity=32).image)(g)
    monkeypatch.setattr(cpu_kernel, "available", lambda: False)
    fallback = lambda g: splat.render(g, camera, tile_capacity=32).image  # noqa: E731
    assert cpu_kernel.FORWARD_TARGET not in lowered_text(fallback, g)
    np.testing.assert_allclose(jax.jit(fallback)(g), image, atol=VALUE_TOLERANCE)


def test_float64_renders_in_pure_jax(x64):
    g, camera = random_scene(1, n=20, width=32, height=32, dtype=np.float64)
    text = lowered_text(lambda g: splat.render(g, camera, tile_capacity=32).image, g)
    assert "f64" in text and cpu_kernel.FORWARD_TARGET not in text


def test_kernel_under_vmap_matches_one_call_per_view():
    grid, bins, packed = tile_inputs(4, n=100, width=48, height=32, capacity=64)
    cfg = comp.CompositeConfig(blend=wabe.standard(), alpha_clamp=0.99, **grid)
    batch = jnp.stack([packed, packed.at[:, 7:].multiply(0.5)])

    def image(x):
        return comp.composite(cfg, bins.table, bins.kept, x)[0]

    batched = jax.jit(jax.vmap(image))(batch)
    for b in range(2):
        np.testing.assert_allclose(batched[b], jax.jit(image)(batch[b]), atol=1e-7)
    grads = jax.grad(lambda x: jnp.sum(jax.vmap(image)(x) ** 2))(batch)
    np.testing.assert_allclose(grads[1], jax.grad(lambda x: jnp.sum(image(x) ** 2))(batch[1]),
                               rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_argsort_is_numpys_stable_argsort_with_ties_and_extremes(n):
    rng = np.random.default_rng(n)
    keys = rng.integers(-5, 5, n).astype(np.int32)  # many ties
    keys[: n // 3] = rng.integers(np.iinfo(np.int32).min, np.iinfo(np.int32).max, n // 3)
    if n:
        keys[-1] = np.iinfo(np.int32).max
    ours = jax.jit(cpu_kernel.argsort)(jnp.asarray(keys))
    np.testing.assert_array_equal(ours, np.argsort(keys, kind="stable"))


@pytest.mark.parametrize("low, high", [(1000, 1100), (-300, -200), (7, 8)])
def test_argsort_of_keys_sharing_bytes_is_numpys_stable_argsort(low, high):
    """Keys in a narrow range share their high bytes (the radix passes the kernel skips)."""
    keys = np.random.default_rng(abs(low)).integers(low, high, 20000).astype(np.int32)
    ours = jax.jit(cpu_kernel.argsort)(jnp.asarray(keys))
    np.testing.assert_array_equal(ours, np.argsort(keys, kind="stable"))


def test_depth_order_is_the_same_with_the_kernel_and_with_lax_sort():
    rng = np.random.default_rng(0)
    depths = jnp.asarray(rng.choice([0.5, 1.0, 2.0, 3.5], 3000) * rng.uniform(1, 1.01, 3000)
                         ** rng.integers(0, 2, 3000), jnp.float32)
    visible = jnp.asarray(rng.uniform(size=3000) > 0.2)
    text = lowered_text(lambda d, v: tiles.depth_order(d, v), depths, visible)
    assert cpu_kernel.ARGSORT_TARGET in text
    np.testing.assert_array_equal(jax.jit(tiles.depth_order)(depths, visible),
                                  jax.jit(lambda d, v: tiles.depth_order(d, v, "jax"))(depths,
                                                                                       visible))


@pytest.mark.parametrize("n, size, capacity, budget", [
    (1, 16, 1, None), (400, 64, 4, None), (3000, 96, 64, None),
    (3000, 96, 16, 700), (3000, 80, 2000, None)])
def test_tile_lists_are_the_same_with_the_kernel_and_with_lax_sort(n, size, capacity, budget):
    """Overflowing tiles (capacity 4, 16), a short pair budget (700), a single Gaussian and
    tiles that hold every pair: the C++ walk and the sort-based lists agree entry for entry, and
    so do the statistics derived from them."""
    g, camera = random_scene(n, n=n, width=size, height=size, scale_range=(0.02, 0.4))
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    args = (p.means2d, p.extents, p.depths, p.visible, size, size, capacity, budget)
    text = lowered_text(lambda *a: bin_gaussians(*a, *args[4:]).table, *args[:4])
    assert cpu_kernel.BIN_TARGET in text
    ours = jax.jit(lambda *a: bin_gaussians(*a, *args[4:]))(*args[:4])
    ref = jax.jit(lambda *a: bin_gaussians(*a, *args[4:], kernel="jax"))(*args[:4])
    for field in ("table", "kept", "counts", "num_slots", "overflow_tiles", "dropped_pairs"):
        np.testing.assert_array_equal(getattr(ours, field), getattr(ref, field), err_msg=field)
    if n >= 400 and capacity < 64:
        assert int(ours.overflow_tiles) > 0 and int(ours.dropped_pairs) > 0


def test_bad_kernel_settings_raise_clear_errors():
    with pytest.raises(ValueError, match="kernel must be one of"):
        comp.CompositeConfig(blend=wabe.standard(), alpha_clamp=0.99, tiles_x=1, tiles_y=1,
                             kernel="cuda")
    with pytest.raises(ValueError, match="kernel_threads"):
        comp.CompositeConfig(blend=wabe.standard(), alpha_clamp=0.99, tiles_x=1, tiles_y=1,
                             kernel_threads=-1)
