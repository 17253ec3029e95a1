"""Spherical harmonics: orthonormal basis, equal to scipy's real SH up to sign, view-dependent render."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special
from jax.test_util import check_grads

from gae_jax.render import sh, splat
from gae_jax.render.camera import look_at_w2c, make_camera
from tests import bruteforce

# Quadrature on a (theta, phi) product grid integrates degree <= 6 polynomials on the sphere
# essentially exactly at this resolution.
QUADRATURE_TOLERANCE = 1e-6


def sphere_quadrature(n_theta=64, n_phi=128):
    nodes, weights = np.polynomial.legendre.leggauss(n_theta)  # in cos(theta)
    phi = np.linspace(0, 2 * np.pi, n_phi, endpoint=False)
    ct, ph = np.meshgrid(nodes, phi, indexing="ij")
    st = np.sqrt(1 - ct ** 2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    w = (weights[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).reshape(-1)
    return dirs, w


def test_basis_is_orthonormal_on_the_sphere(x64):
    dirs, w = sphere_quadrature()
    y = np.asarray(sh.basis(jnp.asarray(dirs), 3))
    gram = (y * w[:, None]).T @ y
    np.testing.assert_allclose(gram, np.eye(16), atol=QUADRATURE_TOLERANCE)


def test_basis_matches_scipy_real_harmonics_up_to_sign(x64):
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    theta = np.arccos(dirs[:, 2])
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    ours = np.asarray(sh.basis(jnp.asarray(dirs), 3))
    col = 0
    for l in range(4):
        for m in range(-l, l + 1):
            y = scipy.special.sph_harm_y(l, abs(m), theta, phi)
            if m < 0:
                ref = np.sqrt(2) * y.imag
            elif m == 0:
                ref = y.real
            else:
                ref = np.sqrt(2) * y.real
            corr = np.dot(ours[:, col], ref) / (np.linalg.norm(ours[:, col]) * np.linalg.norm(ref))
            assert abs(abs(corr) - 1) < 1e-10, (l, m, corr)
            np.testing.assert_allclose(np.abs(ours[:, col]), np.abs(ref), atol=1e-10)
            col += 1


def test_rgb_dc_round_trip():
    rgb = jnp.asarray([[0.0, 0.5, 1.0]])
    np.testing.assert_allclose(sh.dc_to_rgb(sh.rgb_to_dc(rgb)), rgb, atol=1e-6)


@pytest.mark.parametrize("bad", [0, 2, 5, 17])
def test_bad_coefficient_count_is_rejected(bad):
    with pytest.raises(ValueError, match="coefficient count"):
        sh.degree_of(bad)


def test_sh_render_matches_bruteforce_with_view_dependent_colour(x64):
    rng = np.random.default_rng(1)
    n = 25
    camera = make_camera(look_at_w2c([1.0, -0.5, -3.0], [0, 0, 0]), 32, 32, dtype=np.float64)
    coeffs = rng.normal(scale=0.3, size=(n, 16, 3))
    g = splat.Gaussians(jnp.asarray(rng.uniform(-0.8, 0.8, (n, 3))),
                        jnp.asarray(rng.normal(size=(n, 4))),
                        jnp.asarray(rng.uniform(0.05, 0.2, (n, 3))),
                        jnp.asarray(rng.uniform(0.2, 0.9, n)), jnp.asarray(coeffs))
    out = jax.jit(splat.render)(g, camera)
    # Independent colour: SH evaluated in numpy towards the camera centre.
    cam_pos = -np.asarray(camera.w2c)[:3, :3].T @ np.asarray(camera.w2c)[:3, 3]
    d = np.asarray(g.means) - cam_pos
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rgb = np.maximum(np.einsum("nk,nkc->nc", np.asarray(sh.basis(jnp.asarray(d), 3)), coeffs)
                     + 0.5, 0)
    plain = splat.Gaussians(g.means, g.quats, g.scales, g.opacities, jnp.asarray(rgb))
    image, _, _ = bruteforce.render(plain, camera)
    np.testing.assert_allclose(out.image, image, atol=1e-9)


def test_sh_colour_gradient_matches_finite_differences(x64):
    rng = np.random.default_rng(2)
    n = 6
    camera = make_camera(look_at_w2c([0.5, 0.0, -3.0], [0, 0, 0]), 16, 16, dtype=np.float64)
    means = jnp.asarray(rng.uniform(-0.3, 0.3, (n, 3)))
    coeffs = jnp.asarray(rng.normal(scale=0.2, size=(n, 9, 3)))

    def loss(means, coeffs):
        g = splat.Gaussians(means, jnp.tile(jnp.asarray([1.0, 0, 0, 0]), (n, 1)),
                            jnp.full((n, 3), 0.3), jnp.full((n,), 0.6), coeffs)
        return jnp.sum(splat.render(g, camera).image ** 2)

    check_grads(jax.jit(loss), (means, coeffs), order=1, modes=["rev"], eps=1e-6, atol=1e-5,
                rtol=1e-5)
