"""Renderer tests: brute-force agreement, capacity accounting, gradients, extremes, recompiles."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gae_jax.render import composite as comp
from gae_jax.render.composite_reference import composite_reference
from gae_jax.render import projection, splat, wabe
from gae_jax.render.camera import look_at_w2c, make_camera
from gae_jax.render.projection import project
from gae_jax.render.tiles import (EXTENT_ABSOLUTE_MARGIN, EXTENT_RELATIVE_MARGIN, bin_gaussians,
                           depth_order)
from tests import bruteforce
from tests.helpers import assert_tree_finite, random_unit_cotangent

BLENDS = [wabe.standard(), wabe.wabe(6.0), wabe.wabe_grad(6.0)]
RENDER_STATIC = ("blend", "tile_capacity", "max_pairs", "alpha_clamp", "unroll", "unroll_backward",
                 "tiles_per_chunk",
                 "visibility_contributors", "visibility_beta")
render = jax.jit(splat.render, static_argnames=RENDER_STATIC)
# float64 renderer vs float64 numpy: only summation order differs.
X64_TOLERANCE = 1e-9
# float32 renderer vs float64 numpy: a pixel whose alpha sits within rounding of a cut-off may
# flip; everything else agrees to float32 rounding accumulated over the ~50 terms composited per
# pixel (eps 1.2e-7 x 50 = 6e-6; measured max 1.3e-6 on these scenes).
F32_TOLERANCE = 6e-6
F32_MAX_FLIPPED_FRACTION = 0.002


def random_scene(seed, n=40, width=40, height=24, dtype=np.float32, channels=3,
                 scale_range=(0.02, 0.25), opacity_range=(0.05, 0.99)):
    """Gaussians scattered in front of a camera looking at the origin from z = -4."""
    rng = np.random.default_rng(seed)
    camera = make_camera(look_at_w2c([0.3, -0.2, -4.0], [0, 0, 0]), width, height,
                         fov_degrees=50.0, dtype=dtype)
    g = splat.Gaussians(
        means=jnp.asarray(rng.uniform(-1.2, 1.2, (n, 3)), dtype),
        quats=jnp.asarray(rng.normal(size=(n, 4)), dtype),
        scales=jnp.asarray(np.exp(rng.uniform(*np.log(scale_range), (n, 3))), dtype),
        opacities=jnp.asarray(rng.uniform(*opacity_range, n), dtype),
        colors=jnp.asarray(rng.uniform(0, 1, (n, channels)), dtype),
    )
    return g, camera


@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_render_matches_bruteforce_in_float64(x64, blend):
    g, camera = random_scene(0, n=60, dtype=np.float64)
    background = np.array([0.2, 0.5, 0.9])
    out = render(g, camera, background=jnp.asarray(background), blend=blend,
                       tile_capacity=64)
    assert int(out.stats.overflow_tiles) == 0 and int(out.stats.dropped_pairs) == 0
    image, alpha, depth = bruteforce.render(g, camera, background, mode=blend.mode,
                                            beta=blend.beta)
    np.testing.assert_allclose(out.image, image, atol=X64_TOLERANCE)
    np.testing.assert_allclose(out.alpha, alpha, atol=X64_TOLERANCE)
    covered = alpha > 1e-3
    np.testing.assert_allclose(np.asarray(out.depth)[covered], depth[covered], rtol=1e-7)
    assert alpha.max() > 0.9 and (alpha < 0.01).any(), "scene should have covered and empty pixels"


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_render_matches_bruteforce_in_float32(blend, seed):
    g, camera = random_scene(seed, n=80, width=48, height=33)
    out = jax.jit(lambda g, c: render(g, c, blend=blend, tile_capacity=128))(g, camera)
    image, alpha, _ = bruteforce.render(g, camera, mode=blend.mode, beta=blend.beta)
    err = np.abs(np.asarray(out.image, np.float64) - image).max(axis=-1)
    assert np.mean(err > F32_TOLERANCE) <= F32_MAX_FLIPPED_FRACTION, err.max()
    assert np.median(err) < 1e-5


def test_opaque_stack_stops_before_transmittance_underflow(x64):
    """Many opaque layers: compositing must stop before T < 1e-4, exactly as the reference."""
    n = 12
    camera = make_camera(np.eye(4), 16, 16, dtype=np.float64)
    g = splat.Gaussians(
        means=jnp.asarray(np.stack([np.zeros(n), np.zeros(n), np.linspace(2, 4, n)], -1)),
        quats=jnp.tile(jnp.asarray([1.0, 0, 0, 0]), (n, 1)),
        scales=jnp.full((n, 3), 1.0), opacities=jnp.full((n,), 0.97),
        colors=jnp.asarray(np.random.default_rng(0).uniform(size=(n, 3))))
    out = render(g, camera)
    image, alpha, _ = bruteforce.render(g, camera)
    np.testing.assert_allclose(out.image, image, atol=X64_TOLERANCE)
    assert float(np.min(1 - np.asarray(out.alpha))) >= 1e-4 * (1 - 0.97)
    assert int(np.max(out.stats.pixels > 0).sum()) > 0


@pytest.mark.parametrize("dilation", [0.1, 0.3], ids=["ours", "gsplat"])
def test_projection_matches_bruteforce_at_our_filter_and_gsplats(x64, dilation):
    g, camera = random_scene(11, n=60, width=40, height=24, dtype=np.float64)
    gg = {k: np.asarray(getattr(g, k), np.float64) for k in ("means", "quats", "scales")}
    m2, con, dep, ok = bruteforce.project(
        gg["means"], gg["quats"], gg["scales"], np.asarray(camera.intrinsics, np.float64),
        np.asarray(camera.w2c, np.float64), camera.width, camera.height, dilation=dilation)
    p = project(g.means, g.quats, g.scales, g.opacities, camera, dilation=dilation)
    sel = ok & np.asarray(p.visible)
    assert sel.sum() > 20
    np.testing.assert_allclose(np.asarray(p.means2d)[sel], m2[sel], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(np.asarray(p.conics)[sel], con[sel], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.asarray(p.depths), dep, rtol=1e-12, atol=1e-12)


def test_screen_covariance_entries_match_matrix_products_values_and_gradients(x64):
    """The entry-by-entry 2D covariance against numpy's J W R S S^T R^T W^T J^T."""
    rng = np.random.default_rng(5)
    n = 12
    quats, scales = rng.normal(size=(n, 4)), rng.uniform(0.05, 2.0, (n, 3))
    rotation = look_at_w2c([0.3, -0.2, -4.0], [0, 0, 0])[:3, :3]
    jac = rng.normal(size=(4, n))  # J's non-zero entries: xx, yy, xz, yz
    q = quats / np.linalg.norm(quats, axis=-1, keepdims=True)
    w, x, y, z = q.T
    rot = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                   -1).reshape(n, 3, 3)
    j = np.zeros((n, 2, 3))
    j[:, 0, 0], j[:, 1, 1], j[:, 0, 2], j[:, 1, 2] = jac
    m = j @ rotation @ rot @ (scales[:, :, None] * np.eye(3))
    cov = m @ np.swapaxes(m, -1, -2)
    got = projection.screen_covariance(jnp.asarray(quats), jnp.asarray(scales),
                                       jnp.asarray(rotation), *map(jnp.asarray, jac))
    np.testing.assert_allclose(got, cov[:, [0, 0, 1], [0, 1, 1]], rtol=1e-12, atol=1e-12)

    def entries(qq, ss, jx, jy, jxz, jyz):
        return projection.screen_covariance(qq, ss, jnp.asarray(rotation), jx, jy, jxz, jyz)

    check_grads(entries, (jnp.asarray(quats), jnp.asarray(scales), *map(jnp.asarray, jac)),
                order=1, modes=["rev"], eps=1e-6, atol=1e-6, rtol=1e-6)


def test_zero_quaternion_is_the_identity_with_finite_gradients():
    quats = jnp.asarray([[0.0, 0.0, 0.0, 0.0], [1.0, 2.0, 3.0, 4.0]])
    np.testing.assert_allclose(projection.quat_to_rotmat(quats)[0], np.eye(3), atol=0)
    weights = jnp.arange(18.0).reshape(2, 3, 3)
    grads = jax.grad(lambda q: jnp.sum(projection.quat_to_rotmat(q) ** 2 * weights))(quats)
    assert_tree_finite(grads)


def test_the_screen_filter_adds_to_the_covariance_and_is_a_render_option(x64):
    g, camera = random_scene(12, n=10, dtype=np.float64)
    sharp = projection.project(g.means, g.quats, g.scales, g.opacities, camera)
    wide = projection.project(g.means, g.quats, g.scales, g.opacities, camera, dilation=0.3)

    def covariance(conics):  # (N, 3) upper triangle of the inverse -> (N, 2, 2) covariance
        a, b, c = (np.asarray(conics)[:, i] for i in range(3))
        return np.linalg.inv(np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2))

    ok = np.asarray(sharp.visible & wide.visible)
    np.testing.assert_allclose(covariance(wide.conics)[ok] - covariance(sharp.conics)[ok],
                               np.broadcast_to(0.2 * np.eye(2), (int(ok.sum()), 2, 2)),
                               atol=1e-9)
    assert projection.COV2D_DILATION == 0.1
    default = splat.render(g, camera, tile_capacity=64).image
    same = splat.render(g, camera, tile_capacity=64, screen_filter=0.1).image
    softer = splat.render(g, camera, tile_capacity=64, screen_filter=0.3).image
    np.testing.assert_array_equal(np.asarray(default), np.asarray(same))
    assert not np.allclose(np.asarray(default), np.asarray(softer))


def _bbox_keep_mask(g, camera, capacity):
    """Independent emulation of per-tile capacity: nearest `capacity` touching each tile."""
    gg = {k: np.asarray(getattr(g, k), np.float64) for k in ("means", "quats", "scales")}
    intr, w2c = np.asarray(camera.intrinsics, np.float64), np.asarray(camera.w2c, np.float64)
    m2, con, dep, ok = bruteforce.project(gg["means"], gg["quats"], gg["scales"], intr, w2c,
                                          camera.width, camera.height)
    opac = np.asarray(g.opacities, np.float64)
    h, w, n = camera.height, camera.width, len(opac)
    keep = np.zeros((h, w, n), bool)
    ys, xs = np.mgrid[0:h, 0:w]
    tiles_y, tiles_x = -(-h // 16), -(-w // 16)
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            touching = []
            for i in np.flatnonzero(ok & (opac > 1 / 255)):
                a, b, c = con[i]
                cov = np.linalg.inv([[a, b], [b, c]])
                qmax = 2 * np.log(255 * opac[i])
                ex, ey = np.sqrt(qmax * cov[0, 0]), np.sqrt(qmax * cov[1, 1])
                # Binning's documented safety margin decides what "touches" a tile.
                ex = ex * (1 + EXTENT_RELATIVE_MARGIN) + EXTENT_ABSOLUTE_MARGIN
                ey = ey * (1 + EXTENT_RELATIVE_MARGIN) + EXTENT_ABSOLUTE_MARGIN
                cols = np.arange(tx * 16, min(tx * 16 + 16, w)) + 0.5
                rows = np.arange(ty * 16, min(ty * 16 + 16, h)) + 0.5
                if (np.abs(cols - m2[i, 0]) <= ex).any() and (np.abs(rows - m2[i, 1]) <= ey).any():
                    touching.append(i)
            touching.sort(key=lambda i: (dep[i], i))
            sel = (ys // 16 == ty) & (xs // 16 == tx)
            for i in touching[:capacity]:
                keep[sel, i] = True
    return keep, (m2, con, dep, ok)


def test_capacity_overflow_drops_farthest_and_is_counted(x64):
    g, camera = random_scene(4, n=50, width=32, height=32, dtype=np.float64)
    capacity = 6
    # A pair budget beyond the total, so that only the per-tile capacity drops anything.
    out = render(g, camera, tile_capacity=capacity, max_pairs=4096)
    keep, (m2, con, dep, ok) = _bbox_keep_mask(g, camera, capacity)
    image, _, _ = bruteforce.composite(m2, con, dep, ok, np.asarray(g.opacities),
                                       np.asarray(g.colors), 32, 32, np.zeros(3), keep=keep)
    np.testing.assert_allclose(out.image, image, atol=X64_TOLERANCE)
    full = render(g, camera, tile_capacity=64)
    assert int(full.stats.overflow_tiles) == 0
    touching = np.asarray(bin_gaussians_counts(g, camera))
    assert int(out.stats.overflow_tiles) == int(np.sum(touching > capacity)) > 0
    assert int(out.stats.dropped_pairs) == int(np.sum(np.maximum(touching - capacity, 0)))


def bin_gaussians_counts(g, camera):
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    return bin_gaussians(p.means2d, p.extents, p.depths, p.visible, camera.width, camera.height,
                         1024).counts


def test_pair_budget_drops_farthest_gaussians_and_counts_them(x64):
    g, camera = random_scene(5, n=30, width=32, height=32, dtype=np.float64)
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    full = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, 32, 32, 64)
    total = int(full.counts.sum())
    short = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, 32, 32, 64,
                          max_pairs=total - 5)
    assert int(short.dropped_pairs) == 5
    kept_ids = set(np.asarray(short.table).ravel()) - {-1}
    dropped_ids = set(np.asarray(full.table).ravel()) - {-1} - kept_ids
    depths = np.asarray(p.depths)
    assert dropped_ids and kept_ids, "the budget must drop some Gaussians and keep others"
    assert min(depths[list(dropped_ids)]) >= max(depths[list(kept_ids)]) - 1e-12


def test_tile_lists_are_depth_sorted_with_index_ties():
    camera = make_camera(np.eye(4), 32, 16)
    n = 6
    means = np.array([[0, 0, 3], [0.1, 0, 2], [0, 0.1, 3], [0, 0, 2.5], [0.05, 0, 3], [0, 0, 2]],
                     np.float32)
    g = splat.Gaussians(jnp.asarray(means), jnp.tile(jnp.asarray([1.0, 0, 0, 0]), (n, 1)),
                        jnp.full((n, 3), 0.3), jnp.full((n,), 0.5), jnp.ones((n, 3)))
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, 32, 16, 8)
    for row in np.asarray(bins.table):
        ids = [i for i in row if i >= 0]
        assert ids == sorted(ids, key=lambda i: (means[i, 2], i))
    assert list(np.asarray(bins.table)[0][:6]) == [1, 5, 3, 0, 2, 4]


@pytest.mark.parametrize("blend", BLENDS, ids=lambda b: b.mode)
def test_custom_vjp_matches_autodiff_of_dense_reference(x64, blend):
    g, camera = random_scene(6, n=40, width=32, height=32, dtype=np.float64)
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, 32, 32, 64)
    packed = jnp.concatenate([p.means2d, p.conics, p.opacities[:, None], p.depths[:, None],
                              g.colors], axis=-1)
    packed = jnp.where(p.visible[:, None], packed, 0.0)
    cfg = comp.CompositeConfig(blend=blend, alpha_clamp=0.99, tiles_x=2, tiles_y=2, unroll=3,
                               unroll_backward=5, tiles_per_chunk=3)

    def fused(x):
        return comp.composite(cfg, bins.table, bins.kept, x)[:3]

    def dense(x):
        return composite_reference(cfg, bins.table, x)

    out_f, vjp_f = jax.vjp(jax.jit(fused), packed)
    out_d, vjp_d = jax.vjp(jax.jit(dense), packed)
    for a, b in zip(out_f, out_d):
        np.testing.assert_allclose(a, b, atol=1e-10)
    for seed in range(3):
        cot = random_unit_cotangent(jax.random.PRNGKey(seed), out_f)
        (gf,), (gd,) = vjp_f(cot), vjp_d(cot)
        assert np.abs(np.asarray(gd)).max() > 1e-3
        np.testing.assert_allclose(gf, gd, rtol=1e-7, atol=1e-8)


@pytest.mark.parametrize("blend", BLENDS[:2], ids=lambda b: b.mode)
def test_render_gradients_match_finite_differences(x64, blend):
    """wabe_grad is left out on purpose: its gradient is deliberately not the image's."""
    g, camera = random_scene(7, n=8, width=16, height=16, dtype=np.float64,
                             scale_range=(0.2, 0.5), opacity_range=(0.3, 0.8))
    background = jnp.asarray([0.1, 0.2, 0.3])
    weights = jax.random.normal(jax.random.PRNGKey(0), (16, 16, 3), jnp.float64)

    def loss(means, quats, scales, opacities, colors):
        gg = splat.Gaussians(means, quats, scales, opacities, colors)
        out = render(gg, camera, background=background, blend=blend, tile_capacity=16)
        return jnp.sum(out.image * weights) + jnp.sum(out.alpha) + 0.1 * jnp.sum(
            out.depth * out.alpha)

    args = (g.means, g.quats, g.scales, g.opacities, g.colors)
    check_grads(jax.jit(loss), args, order=1, modes=["rev"], eps=1e-6, atol=1e-5, rtol=1e-5)


def test_wabe_grad_image_is_standard_but_gradients_are_weighted(x64):
    g, camera = random_scene(8, n=30, width=32, height=32, dtype=np.float64)

    def loss(colors, blend):
        gg = splat.Gaussians(g.means, g.quats, g.scales, g.opacities, colors)
        return jnp.sum(render(gg, camera, blend=blend).image)

    std = render(g, camera, blend=wabe.standard()).image
    wg = render(g, camera, blend=wabe.wabe_grad(6.0)).image
    np.testing.assert_array_equal(np.asarray(std), np.asarray(wg))
    g_std = jax.jit(jax.grad(loss), static_argnums=1)(g.colors, wabe.standard())
    g_wg = jax.jit(jax.grad(loss), static_argnums=1)(g.colors, wabe.wabe_grad(6.0))
    # Colour gradient per Gaussian is sum over pixels of alpha T (times w for wabe_grad).
    assert np.all(np.asarray(g_wg) <= np.asarray(g_std) + 1e-12)
    assert np.any(np.asarray(g_wg) < 0.5 * np.asarray(g_std))


def test_wabe_with_zero_beta_equals_standard(x64):
    g, camera = random_scene(9, n=40, dtype=np.float64)

    def run(blend):
        def loss(opacities, means):
            gg = splat.Gaussians(means, g.quats, g.scales, opacities, g.colors)
            out = render(gg, camera, blend=blend)
            return jnp.sum(out.image ** 2)
        return render(g, camera, blend=blend).image, jax.jit(jax.grad(loss, (0, 1)))(
            g.opacities, g.means)

    for blend in (wabe.wabe(0.0), wabe.wabe_grad(0.0)):
        a, b = run(blend), run(wabe.standard())
        np.testing.assert_allclose(a[0], b[0], atol=1e-12)
        np.testing.assert_allclose(a[1][0], b[1][0], atol=1e-10)
        np.testing.assert_allclose(a[1][1], b[1][1], atol=1e-10)


def test_wabe_occluded_gaussian_gets_almost_no_gradient():
    """A small Gaussian behind a wide opaque one: WABE cuts its colour gradient by ~exp(-beta)."""
    camera = make_camera(np.eye(4), 16, 16)
    g = splat.Gaussians(
        means=jnp.asarray([[0, 0, 2.0], [0, 0, 3.0]]), quats=jnp.asarray([[1.0, 0, 0, 0]] * 2),
        scales=jnp.asarray([[3.0] * 3, [0.1] * 3]), opacities=jnp.asarray([0.98, 0.9]),
        colors=jnp.asarray([[1.0, 0, 0], [0, 0, 1.0]]))

    def grad_colors(blend):
        def loss(colors):
            gg = splat.Gaussians(g.means, g.quats, g.scales, g.opacities, colors)
            return jnp.sum(render(gg, camera, blend=blend).image)
        return np.asarray(jax.jit(jax.grad(loss))(g.colors))

    std, wab = grad_colors(wabe.standard()), grad_colors(wabe.wabe(6.0))
    np.testing.assert_allclose(wab[0], std[0], rtol=1e-5)  # the occluder: T = 1, w = 1
    ratio = wab[1, 0] / std[1, 0]
    # Behind the occluder T <= 1 - 0.98 exp(-q/2) ~ 0.02 over the small Gaussian's footprint.
    assert np.exp(-6.0) < ratio < np.exp(-6.0 * 0.95), ratio


@pytest.mark.parametrize("beta", [0.0, 20.0])
def test_extremes_stay_finite(beta):
    """Near-plane, behind-camera, tiny and huge, fully opaque and invisible Gaussians together."""
    rng = np.random.default_rng(10)
    n = 30
    camera = make_camera(np.eye(4), 32, 32)
    z = np.concatenate([[-1.0, 0.0, 0.005, 0.01, 0.0100001], rng.uniform(0.02, 5, n - 5)])
    means = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), z], -1)
    opac = np.concatenate([[1.0, 0.9999999, 1 / 255, 0.0], rng.uniform(0.9, 1.0, n - 4)])
    scales = np.array([1e-6, 1e-3, 1e-1, 1.0, 1e3])[rng.integers(0, 5, (n, 3))]
    scales[5:10] = [[1e-6, 1e-6, 1e3], [1e3, 1e3, 1e3], [1e-6] * 3, [1e3, 1e-6, 1e-6], [1.0] * 3]
    g = splat.Gaussians(jnp.asarray(means, jnp.float32),
                        jnp.asarray(rng.normal(size=(n, 4)), jnp.float32),
                        jnp.asarray(scales, jnp.float32), jnp.asarray(opac, jnp.float32),
                        jnp.asarray(rng.uniform(size=(n, 3)), jnp.float32))
    for blend in (wabe.standard(), wabe.wabe(beta), wabe.wabe_grad(beta)):
        def loss(gg):
            out = render(gg, camera, blend=blend, tile_capacity=32)
            return jnp.sum(out.image) + jnp.sum(out.depth) + jnp.sum(out.alpha)
        value, grads = jax.jit(jax.value_and_grad(loss))(g)
        assert np.isfinite(float(value))
        assert_tree_finite(grads)


def test_second_call_does_not_recompile():
    g, camera = random_scene(11)
    fn = jax.jit(lambda g, c: jax.grad(lambda gg: jnp.sum(render(gg, c).image))(g))
    fn(g, camera)
    g2, camera2 = random_scene(12)
    with jax.log_compiles():
        before = fn._cache_size()
        jax.block_until_ready(fn(g2, camera2))
    assert fn._cache_size() == before == 1


def test_screen_offset_gives_screen_space_gradient(x64):
    g, camera = random_scene(13, n=20, dtype=np.float64)
    weights = jax.random.normal(jax.random.PRNGKey(1), (24, 40, 3), jnp.float64)

    def loss(offset):
        return jnp.sum(render(g, camera, screen_offset=offset).image * weights)

    grad = jax.jit(jax.grad(loss))(jnp.zeros((20, 2)))
    loss = jax.jit(loss)
    eps = 1e-6
    for i in range(3):
        e = jnp.zeros((20, 2)).at[i, 0].set(eps)
        fd = (loss(e) - loss(-e)) / (2 * eps)
        np.testing.assert_allclose(grad[i, 0], fd, rtol=1e-5, atol=1e-8)


def test_statistics_radii_and_contribution(x64):
    g, camera = random_scene(14, n=40, dtype=np.float64)
    out = render(g, camera, visibility_contributors=10)
    radii, pixels = np.asarray(out.stats.radii), np.asarray(out.stats.pixels)
    assert np.all(pixels[radii == 0] == 0)
    assert np.all(np.asarray(out.stats.contributed) == (pixels > 0))
    vis = np.asarray(out.stats.visibility)
    assert np.all((vis >= 0) & (vis <= 0.99 + 1e-12))
    assert np.all(vis[pixels == 0] == 0) and vis.max() > 0.5


def test_bad_inputs_raise_clear_errors():
    g, camera = random_scene(15)
    with pytest.raises(ValueError, match="quats"):
        render(splat.Gaussians(g.means, g.quats[:, :3], g.scales, g.opacities, g.colors),
                     camera)
    with pytest.raises(ValueError, match="background"):
        render(g, camera, background=jnp.zeros(4))
    with pytest.raises(ValueError, match="blend mode"):
        wabe.Blend("soft")
    with pytest.raises(ValueError, match="capacity"):
        render(g, camera, tile_capacity=0)


@pytest.mark.parametrize("with_ties", [False, True])
def test_depth_order_is_depth_then_index(with_ties):
    rng = np.random.default_rng(16)
    n = 500
    depths = rng.uniform(0.5, 9.0, n).astype(np.float32)
    if with_ties:
        depths[rng.integers(0, n, 60)] = depths[0]
    visible = rng.uniform(size=n) > 0.2
    order = np.asarray(jax.jit(depth_order)(jnp.asarray(depths), jnp.asarray(visible)))
    assert sorted(order) == list(range(n))
    vis_idx = np.flatnonzero(visible)
    expected = vis_idx[np.lexsort((vis_idx, depths[vis_idx]))]
    np.testing.assert_array_equal(order[: len(vis_idx)], expected)
    assert not visible[order[len(vis_idx):]].any()
