"""The editor's lighting fit: exact on its own model, robust to texture, close to a clamped
Lambertian light (the closed form it approximates)."""

import numpy as np
import pytest

from gae_jax.edit.editors import shading

# The nine-term SH approximation of a clamped cosine lobe (Ramamoorthi and Hanrahan 2001) has a
# mean relative error of a few percent over the sphere (3.1 % for the light below, by plain
# least squares); the robust fit may not be worse than 5 % of that.
ROBUST_OVER_PLAIN = 1.05


def unit_normals(n, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_sh_basis_is_the_nine_real_harmonics():
    n = unit_normals(5)
    b = shading.sh_basis(n)
    x, y, z = n.T
    np.testing.assert_allclose(b, np.stack([np.ones(5), x, y, z, x * y, y * z, x * z,
                                            x * x - y * y, 3 * z * z - 1], -1))


def test_fit_recovers_the_coefficients_of_its_own_model():
    n = unit_normals(500)
    truth = np.array([0.7, 0.1, 0.25, 0.3, -0.05, 0.02, 0.04, -0.03, 0.06])
    albedo = np.random.default_rng(1).uniform(0.2, 0.9, 500)
    coef = shading.fit_lighting(albedo * (shading.sh_basis(n) @ truth), albedo, n)
    # the ridge (1e-3 per pixel) biases the fit by about that much
    np.testing.assert_allclose(coef, truth, atol=5e-3)


def test_fit_ignores_texture_the_albedo_does_not_explain():
    """A fifth of the pixels carry a painted texture (albedo off by +-60 %): the Huber weights
    keep the light of the other four fifths."""
    rng = np.random.default_rng(2)
    n = unit_normals(800, seed=3)
    truth = np.array([0.6, 0.05, 0.3, 0.35, 0.0, 0.05, 0.0, 0.0, 0.02])
    light = shading.sh_basis(n) @ truth
    albedo = np.full(800, 0.7)
    painted = rng.random(800) < 0.2
    observed = albedo * light * np.where(painted, rng.uniform(0.4, 1.6, 800), 1.0)
    robust = shading.fit_lighting(observed, albedo, n)
    plain = np.linalg.lstsq(shading.sh_basis(n) * 0.7, observed, rcond=None)[0]
    err_robust = np.abs(shading.sh_basis(n) @ robust - light).mean()
    err_plain = np.abs(shading.sh_basis(n) @ plain - light).mean()
    assert err_robust < 0.005 and err_robust < 0.35 * err_plain, (err_robust, err_plain)


def test_fit_approximates_a_clamped_lambertian_light():
    n = unit_normals(4000, seed=4)
    light = np.array([0.35, 0.55, 0.75]) / np.linalg.norm([0.35, 0.55, 0.75])
    lambert = 0.45 + 0.55 * np.clip(n @ light, 0, 1)
    coef = shading.fit_lighting(0.6 * lambert, np.full(4000, 0.6), n)
    basis = shading.sh_basis(n)
    plain = np.linalg.lstsq(basis, lambert, rcond=None)[0]
    err = (np.abs(basis @ coef - lambert) / lambert).mean()
    best = (np.abs(basis @ plain - lambert) / lambert).mean()
    assert best < 0.05 and err < ROBUST_OVER_PLAIN * best, (err, best)


def test_shading_map_needs_enough_pixels_and_clips():
    n = unit_normals(64).reshape(8, 8, 3)
    image = np.full((8, 8, 3), 0.5)
    few = np.zeros((8, 8), bool)
    few[0, :5] = True
    assert shading.shading_map(image, n, few, np.full((8, 8), 0.5)) is None
    out, (low, high) = shading.shading_map(image, n, np.ones((8, 8), bool),
                                           np.full((8, 8), 0.5), floor=0.1, ceiling=0.9)
    assert out.shape == (8, 8) and out.min() >= 0.1 and out.max() <= 0.9
    np.testing.assert_allclose(out, 0.9, atol=1e-2)  # luminance 0.5 over albedo 0.5: light 1
    assert low == pytest.approx(shading.DARKER * 0.9, abs=1e-2)
    assert high == pytest.approx(shading.BRIGHTER * 0.9, abs=1e-2)


def test_a_pixels_ratio_is_kept_where_it_is_plausible_light_and_the_fit_elsewhere():
    """Uniform region: every plausible ratio kept, the light rescaled to the region (a fit
    that misses the region by 20 % does not matter); textured region (a third of its pixels
    far too bright for any light): the fitted light, except where a ratio agrees with it."""
    light = np.full((10, 10), 0.5, np.float32)
    uniform = np.full((10, 10), 0.4, np.float32)
    region = np.ones((10, 10), bool)
    shade, scaled, is_uniform = shading.trust_ratio(uniform, light, (0.3, 1.0), region)
    np.testing.assert_allclose(shade, uniform)
    np.testing.assert_allclose(scaled, 0.4, rtol=1e-5)
    assert is_uniform == 1.0
    textured = np.full((10, 10), 0.5, np.float32)
    textured[:, :4] = 3.0  # skin paint in dark hair: a ratio no light gives
    textured[:, 4] = 0.65  # 30 % off the light: not kept
    shade, scaled, is_uniform = shading.trust_ratio(textured, light, (0.3, 1.0), region)
    np.testing.assert_allclose(shade[:, :5], 0.5)
    np.testing.assert_allclose(shade[:, 5:], 0.5)
    np.testing.assert_allclose(scaled, light)
    assert is_uniform == 0.0


def test_a_thin_region_is_uniform_whatever_its_mixed_pixels_say():
    """A thin ring (an iris at 128 px) whose outline pixels mix with a dark pupil and a white
    sclera: implausible ratios on 60 % of its pixels. Judged by them it would be textured and
    take the head's fitted light (20 % too bright here); as a thin region its light is
    rescaled to its own plausible ratios (the median), and those ratios are kept."""
    light = np.full((10, 10), 0.5, np.float32)
    ring = np.full((10, 10), 0.4, np.float32)
    ring[:, :3] = 0.05  # mixed with the pupil
    ring[:, 3:6] = 4.0  # mixed with the sclera
    region = np.ones((10, 10), bool)
    _, scaled, is_uniform = shading.trust_ratio(ring, light, (0.3, 1.0), region)
    assert is_uniform == 0.0
    np.testing.assert_allclose(scaled, light)
    shade, scaled, is_uniform = shading.trust_ratio(ring, light, (0.3, 1.0), region, thin=True)
    assert is_uniform == 1.0
    np.testing.assert_allclose(scaled, 0.4, rtol=1e-5)
    np.testing.assert_allclose(shade[:, 6:], 0.4, rtol=1e-5)
