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


def _band(size: int, window: np.ndarray) -> np.ndarray:
    """(size, size) matrix M with (M x)[i] = sum_k window[k] x[i + k - r] over the indices
    inside [0, size): the 'same' convolution with zero padding, r = len(window) // 2."""
    r = len(window) // 2
    offset = np.arange(size)[None, :] - np.arange(size)[:, None] + r
    return np.where((offset >= 0) & (offset < len(window)),
                    window[np.clip(offset, 0, len(window) - 1)], 0.0)


def _blur(x: jax.Array) -> jax.Array:
    """Separable 'same' Gaussian blur (zero padding) of (H, W, C), as two products with banded
    matrices: their backward is two more products, where shifted slices made XLA:CPU's SSIM
    gradient 4x slower (17 against 4.5 ms at 128 px, 540 against 164 ms at 512)."""
    window = gaussian_window()
    rows = jnp.asarray(_band(x.shape[0], window), x.dtype)
    cols = jnp.asarray(_band(x.shape[1], window), x.dtype)
    full = jax.lax.Precision.HIGHEST  # float32 products on TPU / GPU too
    x = jnp.einsum("ij,jwc->iwc", rows, x, precision=full)
    return jnp.einsum("kw,iwc->ikc", cols, x, precision=full)


def ssim_map(a: jax.Array, b: jax.Array) -> jax.Array:
    """(H, W, C) per-pixel SSIM of two (H, W, C) images."""
    mu_a, mu_b, aa, bb, ab = jnp.split(_blur(jnp.concatenate([a, b, a * a, b * b, a * b], -1)),
                                       5, axis=-1)
    var_a = aa - mu_a ** 2
    var_b = bb - mu_b ** 2
    cov = ab - mu_a * mu_b
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


def region_codes(num_regions: int) -> np.ndarray:
    """(R + 1, B) float32 codes: row 0 the background (all zeros), row r + 1 region r, each a
    distinct pair of ones among B bits (the smallest B with B (B - 1) / 2 >= R: 5 for 10
    regions). Rendered as a Gaussian's extra channels, B codes tell R regions apart where R
    one-hot channels would cost R (the compositor's time grows with the channels); any two
    regions, and a region and the background, differ in at least two bits, as one-hot codes
    do."""
    import itertools

    bits = 2
    while bits * (bits - 1) // 2 < num_regions:
        bits += 1
    codes = np.zeros((num_regions + 1, bits), np.float32)
    for r, pair in enumerate(itertools.islice(itertools.combinations(range(bits), 2),
                                              num_regions)):
        codes[r + 1, list(pair)] = 1.0
    return codes


def region_loss(weights: jax.Array, samples: jax.Array, codes: jax.Array,
                outline_weight: float = 1.0) -> jax.Array:
    """Mean over pixels of sum_b |W_b - target_b|: (H, W, B) composited region codes (each
    Gaussian's `region_codes` row as extra channels) against the mean code of each pixel's
    (H, W, S) int label samples (the regions its S rays project to; -1: background, coded all
    zeros; below -1: unknown, and a pixel with an unknown sample is not counted). With one
    sample, zero exactly where each pixel is covered by its own region's Gaussians alone, at
    full opacity; with several, a pixel a region's outline crosses asks for the regions'
    mix in the shares its rays say (as the antialiased image does), not for the region at
    its centre. `outline_weight` weighs the pixels near an outline (`outline_pixels`) that
    many times: the few pixels where one region's Gaussians reach into another's."""
    samples = samples.astype(jnp.int32)
    table = jnp.asarray(codes, weights.dtype)
    target = jnp.mean(table[jnp.maximum(samples + 1, 0)], axis=-2)
    per_pixel = jnp.sum(jnp.abs(weights - target), axis=-1)
    known = jnp.all(samples >= -1, axis=-1)
    if outline_weight != 1.0:
        per_pixel = per_pixel * jnp.where(outline_pixels(samples), outline_weight, 1.0)
    return jnp.mean(jnp.where(known, per_pixel, 0.0))


def outline_pixels(samples: jax.Array) -> jax.Array:
    """(H, W) bool: the pixels of (H, W, S) int label samples whose rays, or the rays of a
    pixel beside them (3 x 3 neighbourhood), see more than one label: a region's outline and
    the pixel on either side of it."""
    low = jnp.min(samples, axis=-1)
    high = jnp.max(samples, axis=-1)
    pad_low = jnp.pad(low, 1, mode="edge")
    pad_high = jnp.pad(high, 1, mode="edge")
    h, w = low.shape
    for dy in range(3):
        for dx in range(3):
            low = jnp.minimum(low, pad_low[dy:dy + h, dx:dx + w])
            high = jnp.maximum(high, pad_high[dy:dy + h, dx:dx + w])
    return low != high


# Added to a colour before its log (`change_coherence`): a change is a ratio for bright colours
# and closer to a difference near black, where a ratio is ill-defined (chosen when the prior was
# measured in the log, seed-0 probes of black teeth: 23.3 dB at 0.1 and 22.8 at 0.02 with the
# rising weight, 22.3 at 0.1 and 21.6 at 0.25 without it).
CHANGE_FLOOR = 0.1


def change_coherence(colors: jax.Array, origin: jax.Array, members: jax.Array,
                     groups: jax.Array, num_groups: int) -> jax.Array:
    """Sum over the (N,) bool `members` of the squared distance of each one's colour from the
    colour its group's mean change would give it: (c0 + f) exp(mean) - f, the mean change of
    log((c + f) / (c0 + f)) over the members of its group ((N,) int `groups` in [0,
    num_groups): its region), held constant (it pulls each member towards the others, not them
    towards it); (N, 3) RGB `colors` and `origin` (the colours before the edit), f =
    `CHANGE_FLOOR`. Measured in colour, not in the log (whose pull grows as 1 / (c + f) and
    outweighed the data on dark colours), so it weighs against the photometric loss alike on
    dark and light colours. A member that the data moves keeps its change when the data
    outweighs this; one the data barely sees takes its region's change."""
    change = jnp.log(colors + CHANGE_FLOOR) - jnp.log(origin + CHANGE_FLOOR)
    w = members.astype(change.dtype)[:, None]
    total = jax.ops.segment_sum(change * w, groups, num_segments=num_groups)
    count = jax.ops.segment_sum(w, groups, num_segments=num_groups)
    mean = (total / jnp.maximum(count, 1.0))[groups]
    target = jax.lax.stop_gradient((origin + CHANGE_FLOOR) * jnp.exp(mean) - CHANGE_FLOOR)
    return jnp.sum(w * (colors - target) ** 2)


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
