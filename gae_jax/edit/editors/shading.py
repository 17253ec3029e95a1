"""Shading of an image from its normals: a Lambertian lighting fitted by robust least squares.

A Lambertian surface under distant light has an irradiance that nine spherical harmonics of the
normal reproduce to within a few percent (Ramamoorthi and Hanrahan 2001; Basri and Jacobs 2003);
face editors and reconstructions fit those nine coefficients to an image given an albedo (DECA
does so for FLAME). Here: luminance(pixel) = albedo_luminance(region) x (b(n) . c), with b the
nine real SH basis functions of the unit normal n, fitted over chosen pixels with Huber weights
(iteratively reweighted), so that texture the albedo does not explain (painted hair, a blush)
counts as outliers rather than light.
"""

from __future__ import annotations

import numpy as np

LUMA = np.array([0.299, 0.587, 0.114])
HUBER = 1.345  # Huber's constant: 95 % efficiency on Gaussian residuals
IRLS_STEPS = 6
RIDGE = 1e-3  # on the eight non-constant coefficients, relative to the pixel count
MIN_PIXELS = 30  # three per coefficient and more
MARGIN = 0.15  # a ratio this far (in log) beyond the plausible range is texture, not light
DARKER, BRIGHTER = 0.75, 1.1  # the plausible range around the fitted light's own
UNIFORM, TEXTURED = 0.05, 0.2  # fractions of implausible pixels: a uniform / textured region
# A pixel's ratio is kept within 7 % of the light (twice the nine-term fit's mean error on a
# clamped Lambertian) and dropped beyond 20 %.
AGREE, DISAGREE = 0.07, 0.2


def sh_basis(normals: np.ndarray) -> np.ndarray:
    """(..., 9) real spherical harmonics of bands 0-2 (unnormalised) of (..., 3) unit normals:
    1, x, y, z, xy, yz, xz, x^2 - y^2, 3 z^2 - 1."""
    n = np.asarray(normals, np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, y * z, x * z, x * x - y * y,
                     3 * z * z - 1], -1)


def fit_lighting(luminance: np.ndarray, albedo_luminance: np.ndarray,
                 normals: np.ndarray) -> np.ndarray:
    """(9,) SH coefficients c with luminance ~ albedo_luminance x (sh_basis(normals) . c).

    luminance, albedo_luminance: (P,) of P pixels; normals: (P, 3) unit normals. Robust: Huber
    weights on the residuals' scale (1.4826 x their median absolute value), `IRLS_STEPS`
    reweightings; a small ridge keeps the fit defined when the normals span little.
    """
    a = sh_basis(normals) * np.asarray(albedo_luminance, np.float64)[:, None]
    y = np.asarray(luminance, np.float64)
    weights = np.ones_like(y)
    ridge = RIDGE * len(y) * np.diag([0.0] + [1.0] * 8)
    coef = np.zeros(9)
    for _ in range(IRLS_STEPS):
        aw = a * weights[:, None]
        coef = np.linalg.solve(aw.T @ a + ridge, aw.T @ y)
        residual = np.abs(y - a @ coef)
        scale = max(1.4826 * float(np.median(residual)), 1e-6)
        weights = np.minimum(1.0, HUBER * scale / np.maximum(residual, 1e-12))
    return coef


def shading_map(image: np.ndarray, normals: np.ndarray, fit_mask: np.ndarray,
                albedo_luminance: np.ndarray, floor: float = 0.02,
                ceiling: float = 2.0) -> tuple | None:
    """((H, W) shading, (low, high)) of an (H, W, 3) image: the lighting fitted over the (H, W)
    bool `fit_mask`'s pixels, whose albedo luminance is the (H, W) `albedo_luminance`, evaluated
    at every pixel's (H, W, 3) unit normal and clipped to [floor, ceiling]; (low, high) is the
    range of plausible shading: the fitted light's 1st and 99th percentiles over the fitted
    pixels, widened by `DARKER` and `BRIGHTER` (a shadowed or back-lit part may be darker than
    any fitted one). None when fewer than `MIN_PIXELS` pixels are given."""
    if int(fit_mask.sum()) < MIN_PIXELS:
        return None
    luminance = np.asarray(image, np.float64) @ LUMA
    coef = fit_lighting(luminance[fit_mask], albedo_luminance[fit_mask], normals[fit_mask])
    light = np.clip(sh_basis(normals) @ coef, floor, ceiling).astype(np.float32)
    low, high = np.percentile(light[fit_mask], [1, 99])
    return light, (DARKER * float(low), BRIGHTER * float(high))


def trust_ratio(ratio: np.ndarray, light: np.ndarray, plausible: tuple,
                region: np.ndarray, thin: bool = False) -> tuple:
    """((H, W) shading, (H, W) light, uniformity in [0, 1]) of a region: the shading is the
    pixel's own luminance ratio to the region's albedo
    (`ratio`, exact where the albedo is what the editor assumes) where it agrees with the
    fitted `light`, the light where it does not (texture the albedo does not explain: a blush,
    skin paint in the hair, dark strokes in the brows).

    A ratio outside the `plausible` (low, high) shading range by more than a factor
    exp(MARGIN) is texture whatever the light says. The region's interior (the (H, W) bool
    `region`) tells a uniform region (at most `UNIFORM` of its pixels implausible) from a
    textured one (more than `TEXTURED`): in a uniform region the light is first rescaled by
    the median of ratio / light over the region's plausible pixels (the nine-term fit misses
    a region whose normals it saw little of, e.g. eyeballs facing away from the skin's), in a
    textured one it is taken as fitted. A pixel then keeps its ratio within a factor
    exp(AGREE) of that light and takes the light beyond exp(DISAGREE) (linear blends in the log
    gap and in the fraction between). The light returned is that light (rescaled or not), the
    uniformity 1 for a uniform region, 0 for a textured one.

    A `thin` region (an iris at 128 px: nearly every pixel on its outline) is taken as uniform:
    its implausible ratios are pixels mixed with the neighbours (the pupil, the sclera), not
    texture, and the light fitted to the head misses its own (an eye socket's)."""
    low, high = plausible
    r = np.maximum(ratio, 1e-6)
    outside = np.maximum(np.log(low / r), np.log(r / high)).clip(min=0.0)
    plausible_w = np.clip(1.0 - outside / MARGIN, 0.0, 1.0)
    log_gap = np.log(r / np.maximum(light, 1e-6))
    scale, uniform = 0.0, 1.0
    inside = region & (plausible_w >= 0.5)
    if region.any():
        textured = float(np.mean(plausible_w[region] < 0.5))
        uniform = 1.0 if thin else float(
            np.clip((TEXTURED - textured) / (TEXTURED - UNIFORM), 0.0, 1.0))
        if inside.any():
            scale = uniform * float(np.median(log_gap[inside]))
    agree_w = np.clip((DISAGREE - np.abs(log_gap - scale)) / (DISAGREE - AGREE), 0.0, 1.0)
    w = plausible_w * agree_w
    light = (np.exp(scale) * light).astype(np.float32)
    return (w * ratio + (1 - w) * light).astype(np.float32), light, uniform
