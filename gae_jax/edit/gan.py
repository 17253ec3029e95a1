"""The conditional PatchGAN discriminator, its pairs and its losses (temporal adversarial learning).

Architecture (GenN2N / GaussianAvatar-Editor `thmodel.py`): 6 input channels, 4x4 convolutions
with padding 1, 64-128-128-128-1 channels, strides 2-2-2-1-1, LeakyReLU 0.2 after all but the
last, no normalisation, weights N(0, 0.02) (biases start at zero here; PyTorch draws them
uniformly). The output is a map of logits, one per patch; the sigmoid lives inside the losses,
which are written on logits so that they never take log(0).

Pairs (`make_pairs`), images (..., H, W, 3) in [0, 1]:
  * "paper": real = (E_t, E_t - E_k), fake = (C_t, C_t - E_k), E_k the edit of an adjacent time;
  * "code":  real = (E_t, 0),         fake = (E_t, C_t - E_t), as the authors' released code.
"""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from gae_jax.edit import patchconv

PAIR_MODES = ("paper", "code")
LEAK = 0.2
MIN_SIZE = 24  # smallest input side whose patch map is not empty


class Conv(nn.Module):
    """4x4 convolution, padding 1, with a bias: `patchconv.conv` (its VJP is the fast one on
    CPU) under the parameter names and initialisers of `nn.Conv`."""

    features: int
    stride: int
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.normal(0.02),
                            (patchconv.KERNEL, patchconv.KERNEL, x.shape[-1], self.features),
                            self.param_dtype)
        bias = self.param("bias", nn.initializers.zeros, (self.features,), self.param_dtype)
        y = patchconv.conv(x, kernel.astype(x.dtype), self.stride)
        return y + bias.astype(x.dtype).reshape(1, 1, 1, -1)


class Discriminator(nn.Module):
    """PatchGAN: (B, H, W, 6) -> (B, h, w, 1) logits."""

    features: Sequence[int] = (64, 128, 128, 128)
    strides: Sequence[int] = (2, 2, 2, 1)
    param_dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        if x.shape[-1] != 6 or min(output_size(x.shape[-3]), output_size(x.shape[-2])) < 1:
            raise ValueError(f"the discriminator takes (B, H, W, 6) pairs with H, W >= "
                             f"{MIN_SIZE}, got {x.shape}")
        for n, (f, s) in enumerate(zip(self.features, self.strides)):
            x = nn.leaky_relu(Conv(f, s, self.param_dtype, name=f"Conv_{n}")(x), LEAK)
        return Conv(1, 1, self.param_dtype, name=f"Conv_{len(self.features)}")(x)


def init_params(key: jax.Array, image_size: tuple) -> dict:
    """Parameters of `Discriminator()` for (H, W) inputs, as its own initialisers define them
    (kernels N(0, 0.02), biases zero), with every kernel cut from one draw of normals: XLA:CPU
    compiles one threefry program in ~0.3 s and took ~2.2 s for one per layer; the kernels
    are cut and the biases made in that program too (eagerly, each slice compiled its own)."""
    shapes = jax.eval_shape(Discriminator().init, key,
                            jax.ShapeDtypeStruct((1,) + tuple(image_size) + (6,), jnp.float32))
    leaves, treedef = jax.tree_util.tree_flatten_with_path(shapes)
    leaves = [(path[-1].key == "kernel", leaf) for path, leaf in leaves]

    def draw(k):
        normals = 0.02 * jax.random.normal(k, (sum(x.size for kernel, x in leaves if kernel),))
        out, start = [], 0
        for kernel, leaf in leaves:
            if kernel:
                out.append(normals[start:start + leaf.size].reshape(leaf.shape).astype(
                    leaf.dtype))
                start += leaf.size
            else:
                out.append(jnp.zeros(leaf.shape, leaf.dtype))
        return jax.tree_util.tree_unflatten(treedef, out)

    return jax.jit(draw)(key)


def output_size(size: int, strides: Sequence[int] = (2, 2, 2, 1, 1)) -> int:
    """Side of the logit map for a square input (k 4, padding 1)."""
    for s in strides:
        size = (size + 2 - 4) // s + 1
    return size


def downscale(pairs: jax.Array, max_side: int) -> jax.Array:
    """(B, H, W, C) pairs resized (linear, antialiased) so that their longer side is at most
    `max_side` (0 or a larger side: unchanged), aspect kept. What the discriminator sees when
    its cost at full resolution is too high: its convolutions cost ~(H W), 16x less at 1/4."""
    height, width = pairs.shape[-3], pairs.shape[-2]
    if max_side <= 0 or max(height, width) <= max_side:
        return pairs
    scale = max_side / max(height, width)
    size = (max(1, round(height * scale)), max(1, round(width * scale)))
    return jax.image.resize(pairs, pairs.shape[:-3] + size + pairs.shape[-1:], "linear",
                            antialias=True)


def make_pairs(mode: str, edit_t: jax.Array, edit_k: jax.Array, render_t: jax.Array):
    """(real, fake) pairs, each (..., H, W, 6), for the given pair `mode`."""
    if mode == "paper":
        real = jnp.concatenate([edit_t, edit_t - edit_k], axis=-1)
        fake = jnp.concatenate([render_t, render_t - edit_k], axis=-1)
    elif mode == "code":
        real = jnp.concatenate([edit_t, jnp.zeros_like(edit_t)], axis=-1)
        fake = jnp.concatenate([edit_t, render_t - edit_t], axis=-1)
    else:
        raise ValueError(f"pair mode must be one of {PAIR_MODES}, got {mode!r}")
    return real, fake


def d_loss(real_logits: jax.Array, fake_logits: jax.Array) -> jax.Array:
    """L_D = E[-log D(real)] + E[-log(1 - D(fake))] with D = sigmoid(logits)."""
    return jnp.mean(jax.nn.softplus(-real_logits)) + jnp.mean(jax.nn.softplus(fake_logits))


def g_loss(fake_logits: jax.Array) -> jax.Array:
    """L_G = E[-log D(fake)]."""
    return jnp.mean(jax.nn.softplus(-fake_logits))
