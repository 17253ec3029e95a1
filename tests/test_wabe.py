"""WABE's blending weights: the paper's formula, its derivative against autodiff, beta 0 is
standard blending, and finite values over the whole range."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.render import wabe

TRANSMITTANCE = np.linspace(0.0, 1.0, 101)


def test_weight_is_the_papers_formula():
    t = jnp.asarray([0.0, 0.25, 0.5, 1.0])
    # Hand-worked: w = exp(-6 (1 - T)).
    expected = [np.exp(-6.0), np.exp(-4.5), np.exp(-3.0), 1.0]
    np.testing.assert_allclose(wabe.wabe(6.0).weight(t), expected, rtol=1e-6)
    np.testing.assert_allclose(wabe.wabe_grad(6.0).weight(t), expected, rtol=1e-6)
    np.testing.assert_array_equal(wabe.standard().weight(t), np.ones(4))


@pytest.mark.parametrize("beta", [0.0, 1.0, 6.0, 20.0])
def test_derivative_of_weight_times_t_matches_autodiff(x64, beta):
    blend = wabe.wabe(beta)
    t = jnp.asarray(TRANSMITTANCE)
    auto = jax.vmap(jax.grad(lambda x: blend.weight(x) * x))(t)
    np.testing.assert_allclose(blend.weight_times_t_derivative(t), auto, rtol=1e-12, atol=1e-15)
    # The gradient-only mode leaves the image (and so d(T)/dT = 1) standard.
    np.testing.assert_array_equal(wabe.wabe_grad(beta).weight_times_t_derivative(t), 1.0)


def test_beta_zero_is_standard_blending():
    t = jnp.asarray(TRANSMITTANCE, jnp.float32)
    for blend in (wabe.wabe(0.0), wabe.wabe_grad(0.0)):
        np.testing.assert_array_equal(blend.weight(t), wabe.standard().weight(t))
    np.testing.assert_allclose(wabe.wabe(0.0).weight_times_t_derivative(t), 1.0, rtol=1e-7)


@pytest.mark.parametrize("beta", [0.0, 0.5, 6.0, 12.0, 20.0])
def test_weights_stay_finite_and_in_range(beta):
    t = jnp.asarray(TRANSMITTANCE, jnp.float32)
    for blend in (wabe.wabe(beta), wabe.wabe_grad(beta)):
        w = np.asarray(blend.weight(t))
        d = np.asarray(blend.weight_times_t_derivative(t))
        assert np.all(np.isfinite(w)) and np.all(np.isfinite(d))
        assert np.all((w > 0) & (w <= 1)) and np.all(np.diff(w) >= 0)


def test_bad_modes_and_betas_are_refused():
    with pytest.raises(ValueError, match="unknown blend mode"):
        wabe.Blend("additive", 1.0)
    for beta in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="beta must be"):
            wabe.wabe(beta)


def test_blends_are_found_by_name():
    assert wabe.named("standard", 3.0) == wabe.standard()
    assert wabe.named("wabe", 3.0) == wabe.wabe(3.0)
    assert wabe.named("wabe_grad") == wabe.wabe_grad()
    with pytest.raises(ValueError, match="unknown blend"):
        wabe.named("soft")
