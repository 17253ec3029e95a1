"""`composite_reference`: the compositor written densely with `cumprod`, for autodiff.

It composites every (pixel, list slot) pair of a tile at once, (T, 256, capacity) in memory, so
only test-sized inputs fit; the tests differentiate it to check `composite`'s custom VJPs (the
pure-JAX walk and the C++ kernel).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from gae_jax.render.composite import (NUM_GEOMETRY_PARAMS, TRANSMITTANCE_MIN, CompositeConfig,
                                      pixel_centres)
from gae_jax.render.projection import ALPHA_THRESHOLD


def _scale_gradient(x, scale):
    """Identity in value; the gradient reaching x is multiplied by `scale` (no gradient)."""
    scale = lax.stop_gradient(scale)
    return x * scale + lax.stop_gradient(x * (1.0 - scale))


def composite_reference(cfg: CompositeConfig, table: jax.Array, packed: jax.Array):
    """Dense (T, 256, capacity) version of `composite` for autodiff; test-sized inputs only."""
    rows = jnp.concatenate([packed, jnp.zeros((1, packed.shape[1]), packed.dtype)])
    lists = rows[jnp.where(table < 0, packed.shape[0], table)]
    pix = pixel_centres(cfg.tiles_x, cfg.tiles_y, lists.dtype)
    g = lists[:, None, :, :]  # (T, 1, cap, K)
    dx = pix[..., 0:1] - g[..., 0]
    dy = pix[..., 1:2] - g[..., 1]
    q = g[..., 2] * dx * dx + 2.0 * g[..., 3] * dx * dy + g[..., 4] * dy * dy
    alpha = jnp.minimum(cfg.alpha_clamp, g[..., 5] * jnp.exp(-0.5 * q))
    valid = (alpha >= ALPHA_THRESHOLD) & (q >= 0.0)
    t_after = jnp.cumprod(jnp.where(valid, 1.0 - alpha, 1.0), axis=-1)
    use = valid & (t_after >= TRANSMITTANCE_MIN)
    one_minus = jnp.where(use, 1.0 - alpha, 1.0)
    t_before = jnp.cumprod(jnp.concatenate([jnp.ones_like(one_minus[..., :1]),
                                            one_minus[..., :-1]], axis=-1), axis=-1)
    blend = cfg.blend
    colour = jnp.broadcast_to(g[..., NUM_GEOMETRY_PARAMS:], alpha.shape + (g.shape[-1] - 7,))
    depth = jnp.broadcast_to(g[..., 6], alpha.shape)
    if blend.mode == "wabe_grad":
        w = blend.weight(t_before)
        alpha = _scale_gradient(alpha, w)
        colour = _scale_gradient(colour, w[..., None])
        depth = _scale_gradient(depth, w)
        one_minus = jnp.where(use, 1.0 - alpha, 1.0)
        t_before = jnp.cumprod(jnp.concatenate([jnp.ones_like(one_minus[..., :1]),
                                                one_minus[..., :-1]], axis=-1), axis=-1)
    contrib = jnp.where(use, alpha * t_before, 0.0)
    weighted = contrib * blend.weight(t_before) if blend.weights_forward else contrib
    color = jnp.sum(weighted[..., None] * colour, axis=2)
    return color, jnp.prod(one_minus, axis=-1), jnp.sum(contrib * depth, axis=-1)
