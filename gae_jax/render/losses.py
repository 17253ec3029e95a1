"""Image losses and the regularisers that keep bound Gaussians near their triangles.

Images are (H, W, C) floats. SSIM follows 3DGS / GaussianAvatars (`utils/loss_utils.py`): an
11x11 Gaussian window with sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, 'valid' borders handled as zero
padding of the window ('same' size output, as the 3DGS conv2d with padding = 5), mean over pixels
and channels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
# GaussianAvatars' regularisers (local units: triangle scale).
POSITION_THRESHOLD = 1.0
SCALE_THRESHOLD = 0.6


def l1(a: jax.Array, b: jax.Array) -> jax.Array:
    """Mean absolute difference."""
    return jnp.mean(jnp.abs(a - b))


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """(size,) normalised 1D Gaussian."""
    x = np.arange(size) - size // 2
    w = np.exp(-(x ** 2) / (2 * sigma ** 2))
    return w / w.sum()


def _blur(x: jax.Array, window: jax.Array) -> jax.Array:
    """Separable 'same' convolution of (H, W, C) with zero padding."""
    pad = window.shape[0] // 2
    xp = jnp.pad(x, ((pad, pad), (0, 0), (0, 0)))
    rows = sum(window[i] * xp[i:i + x.shape[0]] for i in range(window.shape[0]))
    rp = jnp.pad(rows, ((0, 0), (pad, pad), (0, 0)))
    return sum(window[i] * rp[:, i:i + x.shape[1]] for i in range(window.shape[0]))


def ssim_map(a: jax.Array, b: jax.Array) -> jax.Array:
    """(H, W, C) per-pixel SSIM of two (H, W, C) images."""
    window = jnp.asarray(gaussian_window(), a.dtype)
    mu_a, mu_b = _blur(a, window), _blur(b, window)
    var_a = _blur(a * a, window) - mu_a ** 2
    var_b = _blur(b * b, window) - mu_b ** 2
    cov = _blur(a * b, window) - mu_a * mu_b
    return ((2 * mu_a * mu_b + SSIM_C1) * (2 * cov + SSIM_C2)) / (
        (mu_a ** 2 + mu_b ** 2 + SSIM_C1) * (var_a + var_b + SSIM_C2))


def ssim(a: jax.Array, b: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """Mean SSIM (optionally over an (H, W) mask's pixels)."""
    m = ssim_map(a, b)
    if mask is None:
        return jnp.mean(m)
    w = jnp.broadcast_to(mask[..., None].astype(m.dtype), m.shape)
    return jnp.sum(m * w) / jnp.maximum(jnp.sum(w), 1.0)


def psnr(a: jax.Array, b: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """PSNR in dB for images in [0, 1] (optionally over an (H, W) mask's pixels)."""
    se = (a - b) ** 2
    if mask is None:
        mse = jnp.mean(se)
    else:
        w = jnp.broadcast_to(mask[..., None].astype(se.dtype), se.shape)
        mse = jnp.sum(se * w) / jnp.maximum(jnp.sum(w), 1.0)
    return -10.0 * jnp.log10(jnp.maximum(mse, 1e-12))


def photometric(render: jax.Array, target: jax.Array, dssim_weight: float = 0.2) -> jax.Array:
    """GaussianAvatars' (1 - lambda) L1 + lambda (1 - SSIM), lambda = 0.2."""
    return (1.0 - dssim_weight) * l1(render, target) + dssim_weight * (1.0 - ssim(render, target))


def position_regulariser(local_means: jax.Array, visible: jax.Array | None = None,
                         threshold: float = POSITION_THRESHOLD) -> jax.Array:
    """Mean over (visible) Gaussians of relu(|mu_local| - threshold), in triangle units."""
    excess = jax.nn.relu(_safe_norm(local_means) - threshold)
    return _masked_mean(excess, visible)


def scale_regulariser(local_log_scales: jax.Array, visible: jax.Array | None = None,
                      threshold: float = SCALE_THRESHOLD) -> jax.Array:
    """Mean over (visible) Gaussians of |relu(exp(s_local) - threshold)|_2."""
    excess = jax.nn.relu(jnp.exp(local_log_scales) - threshold)
    return _masked_mean(_safe_norm(excess), visible)


def _safe_norm(x):
    """Euclidean norm over the last axis with a zero (not NaN) gradient at 0."""
    sq = jnp.sum(x * x, axis=-1)
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def _masked_mean(values, mask):
    if mask is None:
        return jnp.mean(values)
    w = mask.astype(values.dtype)
    return jnp.sum(values * w) / jnp.maximum(jnp.sum(w), 1.0)
