"""Per-region image scores against a reference, and temporal flicker.

Scores pool squared errors over all pixels of a region across frames and cameras before taking
PSNR (a frame where a region is absent adds nothing): `whole`, the edited region, and each
preserved group (`teeth`, `eyes` = sclera + iris + pupil, `mouth`, `tongue`, `rest` = the head's
other regions; background pixels count only in `whole`). Beside the error against a reference,
two scores of ours against the untouched avatar: `drift` (outside the dilated edit) and `change`
(over each occluded region wherever the truth shows it, the edit's border included).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.evaluation import lpips
from gae_jax.model import head
from gae_jax.render import losses

PRESERVED_GROUPS = {"teeth": ("teeth",), "eyes": ("sclera", "iris", "pupil"),
                    "mouth": ("mouth",), "tongue": ("tongue",)}
# Regions another part of the face hides most of the time, where an edit of the occluder leaks.
OCCLUDED_GROUPS = {"teeth": ("teeth",), "tongue": ("tongue",), "iris": ("iris", "pupil")}
MAX_PSNR = 99.0  # reported for identical pixels


def region_masks(regions: np.ndarray, edited_region: str | None) -> dict:
    """Boolean masks of `whole`, the edited region and the preserved groups."""
    masks = {"whole": np.ones(regions.shape, bool)}
    if edited_region is not None:
        masks["edited"] = regions == head.REGION_ID[edited_region]
    used = {edited_region}
    for group, names in PRESERVED_GROUPS.items():
        names = tuple(n for n in names if n != edited_region)
        masks[group] = np.isin(regions, [head.REGION_ID[n] for n in names])
        used |= set(names)
    rest = [head.REGION_ID[n] for n in head.REGIONS if n not in used]
    masks["rest"] = np.isin(regions, rest)  # the head's other regions; background is not "rest"
    return masks


def pooled_psnr(predicted: np.ndarray, reference: np.ndarray,
                mask: np.ndarray | None = None) -> float | None:
    """PSNR dB of (..., H, W, 3) images in [0, 1] with the squared errors pooled over the
    (..., H, W) mask's pixels of all images (all pixels without a mask); None for an empty
    mask."""
    se = np.mean((np.asarray(predicted, np.float64) - np.asarray(reference, np.float64)) ** 2, -1)
    if mask is not None:
        if not mask.any():
            return None
        se = se[mask]
    return float(10 * np.log10(1.0 / max(float(se.mean()), 1e-12)))


def region_scores(predicted: np.ndarray, truth: np.ndarray, regions: np.ndarray,
                  edited_region: str | None, perceptual: bool = True) -> dict:
    """{metric: {mask: value}} over (..., H, W, 3) images in [0, 1] or uint8.

    `psnr` pools squared errors over the mask's pixels of all images; `ssim` and `lpips` average
    the per-pixel SSIM map (11x11 window, on the whole image) and LPIPS map over the mask's
    pixels. A mask with no pixels gets None. `perceptual=False` skips LPIPS.
    """
    p = _float(predicted).reshape((-1,) + np.shape(predicted)[-3:])
    t = _float(truth).reshape(p.shape)
    masks = {k: m.reshape(p.shape[:-1]) for k, m in region_masks(regions, edited_region).items()}
    ssim = np.asarray(_ssim_maps(jnp.asarray(p, jnp.float32), jnp.asarray(t, jnp.float32)))
    maps = {"ssim": ssim.mean(-1)}
    if perceptual:
        maps["lpips"] = np.asarray(lpips.lpips_map(p, t))
    out = {"psnr": {}, **{k: {} for k in maps}}
    for name, mask in masks.items():
        empty = not mask.any()
        out["psnr"][name] = None if empty else round(pooled_psnr(p, t, mask), 3)
        for metric, m in maps.items():
            out[metric][name] = None if empty else round(float(m[mask].mean()), 4)
    return out


@jax.jit
def _ssim_maps(a, b):
    return jax.vmap(losses.ssim_map)(a, b)


DRIFT_DILATE = 3  # pixels (at 128 px) the edited region grows before "outside" begins


def outside_edit(regions: np.ndarray, edited_region: str | None,
                 dilate: int = DRIFT_DILATE) -> np.ndarray:
    """(..., H, W) bool: pixels farther than `dilate` pixels from the edited region (of the
    truth's region labels, (..., H, W) int, -1 background). Without a region (a style, which
    edits the whole head) only the background away from the head counts."""
    import cv2

    regions = np.asarray(regions)
    if edited_region is None:
        inside = regions >= 0
    else:
        inside = regions == head.REGION_ID[edited_region]
    flat = inside.reshape((-1,) + inside.shape[-2:]).astype(np.uint8)
    kernel = np.ones((2 * dilate + 1,) * 2, np.uint8)
    grown = np.stack([cv2.dilate(m, kernel) for m in flat]).astype(bool)
    return ~grown.reshape(inside.shape)


def drift_scores(ours: np.ndarray, untouched: np.ndarray, regions: np.ndarray,
                 edited_region: str | None) -> dict:
    """{mask: PSNR} of ours against the untouched avatar's render, over the pixels outside the
    dilated edit (`outside_edit`): what changed that should not have. Masks: `whole` (every
    such pixel), `background`, and the preserved groups of `region_masks`; None when empty,
    and at most 99 dB (identical pixels)."""
    p = _float(ours).reshape((-1,) + np.shape(ours)[-3:])
    u = _float(untouched).reshape(p.shape)
    regions = np.asarray(regions).reshape(p.shape[:-1])
    outside = outside_edit(regions, edited_region)
    masks = {k: m & outside for k, m in region_masks(regions, edited_region).items()
             if k != "edited"}
    masks["background"] = (regions < 0) & outside
    out = {}
    for name, mask in masks.items():
        if not mask.any():
            out[name] = None
            continue
        out[name] = _capped_psnr(p[mask], u[mask])
    return out


def change_scores(ours: np.ndarray, untouched: np.ndarray, regions: np.ndarray,
                  edited_region: str | None) -> dict:
    """{group: PSNR} of ours against the untouched avatar's render over every pixel of each
    occluded group (`OCCLUDED_GROUPS`: teeth, tongue, iris + pupil) that the truth's (..., H, W)
    labels show, next to the edit or not: how much an edit of the lips or lids leaked into what
    they hide. None where a group is absent or is the edited region; at most 99 dB."""
    p = _float(ours).reshape((-1,) + np.shape(ours)[-3:])
    u = _float(untouched).reshape(p.shape)
    regions = np.asarray(regions).reshape(p.shape[:-1])
    out = {}
    for group, names in OCCLUDED_GROUPS.items():
        mask = np.isin(regions, [head.REGION_ID[n] for n in names if n != edited_region])
        out[group] = _capped_psnr(p[mask], u[mask]) if mask.any() else None
    return out


def _capped_psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a - b) ** 2))
    return round(min(10 * np.log10(1.0 / max(mse, 1e-12)), MAX_PSNR), 3)


def flicker(ours: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Temporal flicker of (T, H, W, 3) consecutive frames: the mean absolute difference between
    our frame-to-frame change and the truth's, (ours_t+1 - ours_t) - (truth_t+1 - truth_t), in
    [0, 1] units over pixels (of an optional (T, H, W) mask, taken where either frame has it)."""
    o, t = _float(ours), _float(truth)
    if o.shape != t.shape or o.ndim != 4 or len(o) < 2:
        raise ValueError(f"flicker needs two (T >= 2, H, W, 3) clips, got {o.shape}, {t.shape}")
    diff = np.abs(np.diff(o, axis=0) - np.diff(t, axis=0)).mean(-1)
    if mask is None:
        return float(diff.mean())
    m = mask[1:] | mask[:-1]
    return float(diff[m].mean()) if m.any() else float("nan")


def _float(x):
    x = np.asarray(x)
    return x.astype(np.float64) / 255.0 if x.dtype == np.uint8 else x.astype(np.float64)
