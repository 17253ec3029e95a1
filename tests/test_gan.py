"""The PatchGAN against a numpy convolution stack, its losses against the closed form, pairs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gae_jax.edit import gan


def numpy_conv(x, kernel, bias, stride):
    """Direct 4x4 convolution, padding 1: x (H, W, Cin), kernel (4, 4, Cin, Cout)."""
    x = np.pad(x, ((1, 1), (1, 1), (0, 0)))
    h = (x.shape[0] - 4) // stride + 1
    w = (x.shape[1] - 4) // stride + 1
    out = np.zeros((h, w, kernel.shape[-1]))
    for i in range(h):
        for j in range(w):
            patch = x[i * stride:i * stride + 4, j * stride:j * stride + 4]
            out[i, j] = np.einsum("abc,abcd->d", patch, kernel) + bias
    return out


def test_discriminator_equals_a_numpy_convolution_stack(x64):
    model = gan.Discriminator(features=(4, 5, 5, 3), param_dtype=jnp.float64)
    x = jax.random.uniform(jax.random.PRNGKey(0), (1, 32, 32, 6), jnp.float64)
    params = model.init(jax.random.PRNGKey(1), x)
    # Non-zero biases so that they are checked too.
    params = jax.tree_util.tree_map_with_path(
        lambda p, v: v + 0.1 * (len(p) + 1) if "bias" in str(p[-1]) else v, params)
    out = np.asarray(model.apply(params, x))
    layers = sorted(params["params"])
    h = np.asarray(x[0])
    for n, (name, stride) in enumerate(zip(layers, (2, 2, 2, 1, 1))):
        layer = params["params"][name]
        h = numpy_conv(h, np.asarray(layer["kernel"]), np.asarray(layer["bias"]), stride)
        if n < 4:
            h = np.where(h > 0, h, gan.LEAK * h)
    assert out.shape == (1, gan.output_size(32), gan.output_size(32), 1) == (1,) + h.shape
    np.testing.assert_allclose(out[0], h, rtol=1e-10, atol=1e-12)


def test_default_widths_strides_and_init():
    model = gan.Discriminator()
    x = jnp.zeros((2, 64, 64, 6))
    params = model.init(jax.random.PRNGKey(0), x)["params"]
    kernels = [params[k]["kernel"] for k in sorted(params)]
    assert [k.shape[-1] for k in kernels] == [64, 128, 128, 128, 1]
    assert kernels[0].shape == (4, 4, 6, 64)
    allw = np.concatenate([np.ravel(k) for k in kernels[1:4]])
    assert abs(allw.std() - 0.02) < 0.001 and abs(allw.mean()) < 0.001
    assert model.apply({"params": params}, x).shape == (2, 6, 6, 1)  # 64-32-16-8-7-6
    assert gan.output_size(512) == 62


def test_one_draw_init_has_the_modules_shapes_and_distribution():
    """`init_params` (one normal draw cut into kernels) against flax's own init: the same tree,
    shapes and dtypes, zero biases, kernels N(0, 0.02) per layer, no two layers alike, the same
    key the same parameters."""
    key = jax.random.PRNGKey(3)
    ours = gan.init_params(key, (64, 48))
    flax_init = gan.Discriminator().init(key, jnp.zeros((1, 64, 48, 6)))
    assert jax.tree_util.tree_structure(ours) == jax.tree_util.tree_structure(flax_init)
    for a, b in zip(jax.tree_util.tree_leaves(ours), jax.tree_util.tree_leaves(flax_init)):
        assert a.shape == b.shape and a.dtype == b.dtype
    layers = ours["params"]
    for name in layers:
        np.testing.assert_array_equal(layers[name]["bias"], 0.0)
    for name in ("Conv_1", "Conv_2", "Conv_3"):  # >= 131k weights each
        w = np.asarray(layers[name]["kernel"])
        assert abs(w.std() - 0.02) < 0.0005 and abs(w.mean()) < 0.0005, name
    firsts = {float(np.ravel(layers[n]["kernel"])[0]) for n in layers}
    assert len(firsts) == len(layers)
    again = gan.init_params(key, (64, 48))
    for a, b in zip(jax.tree_util.tree_leaves(ours), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(a, b)
    other = gan.init_params(jax.random.PRNGKey(4), (64, 48))
    assert not np.array_equal(other["params"]["Conv_2"]["kernel"], layers["Conv_2"]["kernel"])


def test_losses_equal_the_closed_form(x64):
    real = np.array([[-3.0, 0.0], [2.0, 40.0]])
    fake = np.array([[1.5, -2.0], [0.3, -50.0]])
    sig = lambda z: 1 / (1 + np.exp(-z))  # noqa: E731
    d_ref = np.mean(-np.log(sig(real))) + np.mean(-np.log(1 - sig(fake)))
    g_ref = np.mean(-np.log(sig(fake)))
    assert float(gan.d_loss(jnp.asarray(real), jnp.asarray(fake))) == pytest.approx(d_ref, 1e-12)
    assert float(gan.g_loss(jnp.asarray(fake))) == pytest.approx(g_ref, 1e-12)
    # Extreme logits stay finite (a naive log(sigmoid) gives inf here).
    assert np.isfinite(float(gan.d_loss(jnp.asarray([1e4]), jnp.asarray([-1e4]))))
    assert np.isfinite(float(gan.g_loss(jnp.asarray([-1e4]))))
    check_grads(lambda r, f: gan.d_loss(r, f), (jnp.asarray(real), jnp.asarray(fake)), 2)
    check_grads(gan.g_loss, (jnp.asarray(fake),), 2)


def test_pairs_follow_the_paper_and_the_code():
    # Constant images with hand-worked values: E_t = 0.6, E_k = 0.2, C_t = 0.5.
    e_t, e_k, c_t = (jnp.full((2, 3, 3), v) for v in (0.6, 0.2, 0.5))
    real, fake = gan.make_pairs("paper", e_t, e_k, c_t)  # (E_t, E_t - E_k) / (C_t, C_t - E_k)
    np.testing.assert_allclose(real[0, 0], [0.6] * 3 + [0.4] * 3, rtol=1e-6)
    np.testing.assert_allclose(fake[0, 0], [0.5] * 3 + [0.3] * 3, rtol=1e-6)
    real, fake = gan.make_pairs("code", e_t, e_k, c_t)  # (E_t, 0) / (E_t, C_t - E_t)
    np.testing.assert_allclose(real[0, 0], [0.6] * 3 + [0.0] * 3, rtol=1e-6)
    np.testing.assert_allclose(fake[0, 0], [0.6] * 3 + [-0.1] * 3, rtol=1e-5)
    # An avatar that renders exactly the edit is indistinguishable from it in both modes.
    key = jax.random.PRNGKey(3)
    e_t, e_k = (jax.random.uniform(k, (5, 7, 3)) for k in jax.random.split(key, 2))
    for mode in gan.PAIR_MODES:
        real, fake = gan.make_pairs(mode, e_t, e_k, e_t)
        np.testing.assert_array_equal(real, fake)
    with pytest.raises(ValueError, match="pair mode"):
        gan.make_pairs("both", e_t, e_k, e_t)


def test_discriminator_gradient_matches_finite_differences(x64):
    model = gan.Discriminator(features=(3, 3, 3, 3), param_dtype=jnp.float64)
    x = jax.random.uniform(jax.random.PRNGKey(0), (1, 24, 24, 6), jnp.float64)
    # N(0, 0.02) weights make every gradient ~1e-6, where finite differences are all rounding.
    params = jax.tree_util.tree_map(lambda v: 25.0 * v + 0.05,
                                    model.init(jax.random.PRNGKey(1), x))
    with pytest.raises(ValueError, match="H, W >= 24"):
        model.apply(params, x[:, :16, :16])
    check_grads(lambda x: jnp.sum(model.apply(params, x) ** 2), (x,), 1, modes=["rev"])
    check_grads(lambda p: gan.d_loss(model.apply(p, x), model.apply(p, 1 - x)), (params,), 1,
                modes=["rev"])


def test_downscale_is_an_antialiased_triangle_filter():
    """Halving (64 -> 32 rows, 48 -> 24 columns): each output is the separable filter
    (1, 3, 3, 1) / 8 around input 2i + 0.5, the linear kernel stretched to the new pixel size
    (computed here in numpy inside the image); longer side capped, aspect kept; nothing changes
    at or under the cap, or with the cap 0."""
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(2, 64, 48, 6)).astype(np.float32)
    out = np.asarray(gan.downscale(jnp.asarray(x), 32))
    assert out.shape == (2, 32, 24, 6)
    w = np.array([1, 3, 3, 1]) / 8
    rows = np.einsum("k,bkwc->bwc", w, x[:, 2 * 5 - 1:2 * 5 + 3])  # output row 5
    ref = np.einsum("k,bkc->bc", w, rows[:, 2 * 7 - 1:2 * 7 + 3])  # output column 7
    np.testing.assert_allclose(out[:, 5, 7], ref, atol=1e-6)
    const = np.asarray(gan.downscale(jnp.full((1, 64, 48, 6), 0.3), 32))
    np.testing.assert_allclose(const, 0.3, atol=1e-6)
    for cap in (0, 64, 100):
        np.testing.assert_array_equal(gan.downscale(jnp.asarray(x), cap), x)


def test_gan_max_side_is_checked():
    from gae_jax.edit.config import EditConfig

    with pytest.raises(ValueError, match="gan_max_side"):
        EditConfig(gan_max_side=gan.MIN_SIZE - 1)
    assert EditConfig(gan_max_side=256).gan_max_side == 256
