"""The discriminator's 4x4 convolution: values against a direct numpy convolution, its hand-made
VJP against JAX's transpose of `lax.conv_general_dilated` and against finite differences."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax
from jax.test_util import check_grads

from gae_jax.edit import patchconv
from tests.test_gan import numpy_conv

# Float32 sums of up to 4 x 4 x Cin products, reordered: a few ulps of the largest term.
F32_TOLERANCE = 2e-5
# (stride, height, width, Cin, Cout): both strides, even and odd sides, one and many outputs.
SHAPES = [(2, 16, 16, 6, 5), (2, 15, 18, 3, 4), (2, 9, 7, 4, 1),
          (1, 12, 12, 5, 4), (1, 11, 8, 3, 1)]


def _inputs(shape, dtype, seed=0):
    stride, h, w, cin, cout = shape
    kx, kk = jax.random.split(jax.random.PRNGKey(seed))
    x = jax.random.normal(kx, (2, h, w, cin), dtype)
    kernel = jax.random.normal(kk, (4, 4, cin, cout), dtype)
    return stride, x, kernel


def _lax_conv(x, kernel, stride):
    return lax.conv_general_dilated(x, kernel, (stride, stride), ((1, 1), (1, 1)),
                                    dimension_numbers=("NHWC", "HWIO", "NHWC"))


@pytest.mark.parametrize("shape", SHAPES)
def test_conv_equals_a_direct_numpy_convolution(shape, x64):
    stride, x, kernel = _inputs(shape, jnp.float64)
    out = np.asarray(patchconv.conv(x, kernel, stride))
    for b in range(x.shape[0]):
        expected = numpy_conv(np.asarray(x[b]), np.asarray(kernel), 0.0, stride)
        np.testing.assert_allclose(out[b], expected, rtol=1e-12, atol=1e-12)
    assert out.shape[1:3] == (patchconv.output_size(shape[1], stride),
                              patchconv.output_size(shape[2], stride))


@pytest.mark.parametrize("shape", SHAPES)
def test_vjp_equals_the_transpose_of_lax_conv(shape):
    """Random cotangent, float32: the phase-split input gradient and the per-tap kernel gradient
    give what JAX's own transpose of the convolution gives."""
    stride, x, kernel = _inputs(shape, jnp.float32, seed=1)

    @functools.partial(jax.jit, static_argnums=0)
    def value_and_cotangents(conv, x, kernel):
        out, pullback = jax.vjp(lambda a, k: conv(a, k, stride), x, kernel)
        return out, pullback(jax.random.normal(jax.random.PRNGKey(7), out.shape))

    out, got = value_and_cotangents(patchconv.conv, x, kernel)
    expected_out, expected = value_and_cotangents(_lax_conv, x, kernel)
    np.testing.assert_allclose(out, expected_out, rtol=F32_TOLERANCE, atol=F32_TOLERANCE)
    for a, e in zip(got, expected):
        assert a.shape == e.shape
        scale = float(jnp.max(jnp.abs(e)))
        np.testing.assert_allclose(a, e, rtol=0, atol=F32_TOLERANCE * scale)


@pytest.mark.parametrize("shape", [(2, 8, 9, 2, 3), (2, 7, 6, 2, 1), (1, 6, 7, 2, 3),
                                   (1, 6, 6, 2, 1)])
def test_gradients_match_finite_differences_in_float64(shape, x64):
    stride, x, kernel = _inputs(shape, jnp.float64, seed=2)
    check_grads(lambda a, k: patchconv.conv(a, k, stride), (x, kernel), order=1, modes=["rev"])


def test_jitted_gradient_through_the_discriminator_stack_matches_lax():
    """Both strides chained under jit and grad, as the edit step uses them."""
    strides = (2, 2, 1, 1)
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    widths = (6, 8, 8, 8, 1)
    kernels = [0.2 * jax.random.normal(k, (4, 4, a, b))
               for k, a, b in zip(keys[1:], widths[:-1], widths[1:])]
    x = jax.random.uniform(keys[0], (1, 32, 32, 6))

    def loss(conv, x, kernels):
        for s, k in zip(strides, kernels):
            x = jax.nn.leaky_relu(conv(x, k, s), 0.2)
        return jnp.mean(jnp.square(x))

    got = jax.jit(jax.grad(lambda *a: loss(patchconv.conv, *a), (0, 1)))(x, kernels)
    expected = jax.grad(lambda *a: loss(_lax_conv, *a), (0, 1))(x, kernels)
    for a, e in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(expected)):
        scale = float(jnp.max(jnp.abs(e)))
        np.testing.assert_allclose(a, e, rtol=0, atol=F32_TOLERANCE * scale)


def test_bad_stride_or_shapes_are_refused():
    x = jnp.zeros((1, 8, 8, 3))
    with pytest.raises(ValueError, match="stride"):
        patchconv.conv(x, jnp.zeros((4, 4, 3, 2)), 3)
    with pytest.raises(ValueError, match="kernel"):
        patchconv.conv(x, jnp.zeros((3, 3, 3, 2)), 1)
