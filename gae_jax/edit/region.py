"""Where an edit may act: the edit region per Gaussian, and its soft 2D mask per view.

`--region` chooses the Gaussians an edit may move:
  * `none`: every Gaussian (the paper's behaviour);
  * `prompt` (the default): the region the instruction names ("turn the lips blue": lips), as
    region names below; a prompt that names none (a style, a free-form InstructPix2Pix
    instruction) is traced as `auto`;
  * region names (`lips`, `hair,brows`, ...): the Gaussians bound to faces of those regions (the
    avatar's binding; a real FLAME model's regions come from `FLAME_masks.pkl`);
  * `auto`: traced from the 2D edits alone, GaussianEditor's semantic tracing. Each edit's change
    mask (where the edit differs from the unedited image of that view, which the editor is
    conditioned on) is voted per Gaussian with the Gaussian's blending weights over the pixels:
    vote_i = sum_p m(p) w_i(p), weight_i = sum_p w_i(p), accumulated over every edit made so far;
    a Gaussian is selected when vote / weight > 1/2. The change is measured against the unedited
    image, not the current render: the render converges to the edit, and a mask of their
    difference would shrink to nothing and deselect the region it is editing.
Outside the region no parameter moves (`edit.step` masks gradients and updates). The 2D target
is composited: the edit inside a soft, dilated mask rendered from the selected Gaussians, the
unedited image outside (GaussCtrl's / PortraitGen's `edit * M + original * (1 - M)`).

The contribution weights w_i(p) = alpha_i(p) T_i(p) are those of standard blending whatever the
edit's blend (they are what the Gaussian shows at the pixel); they are read as the VJP of a
render with one all-ones extra channel per Gaussian.
"""

from __future__ import annotations

import functools

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from gae_jax import instructions
from gae_jax.model import head
from gae_jax.render import wabe
from gae_jax.scene.rig import Rig, render_bound
from gae_jax.util.compile import fast_jit

MODES = ("none", "auto", "prompt")
SELECT_FRACTION = 0.5  # GaussianEditor: selected when the mean vote exceeds one half


def parse_region(spec: str, prompt: str | None = None) -> tuple:
    """`none` / `auto` -> (spec,); comma-separated region names -> their tuple; `prompt` -> the
    region `prompt` names, or ("auto",) if it names none (without a prompt: ("prompt",)).
    ValueError naming the known regions otherwise."""
    spec = spec.strip().lower()
    if spec == "prompt" and prompt is not None:
        try:
            return (instructions.parse(prompt).region,)
        except ValueError:
            return ("auto",)
    if spec in MODES:
        return (spec,)
    names = tuple(n.strip() for n in spec.split(",") if n.strip())
    unknown = [n for n in names if n not in head.REGION_ID]
    if not names or unknown:
        what = ", ".join(unknown) or repr(spec)
        raise ValueError(f"unknown region {what}; --region takes none, auto, prompt or region "
                         f"names among {', '.join(head.REGIONS)} (comma-separated)")
    return names


def named_selection(regions: np.ndarray, names: tuple) -> np.ndarray:
    """(N,) bool: the Gaussians whose region label is one of `names`.

    regions: (N,) int region label of each Gaussian (index into `head.REGIONS`)."""
    return np.isin(np.asarray(regions), [head.REGION_ID[n] for n in names])


def select(votes: np.ndarray) -> np.ndarray:
    """(N,) bool from (N, 2) accumulated [vote, weight]: mean vote above one half."""
    votes = np.asarray(votes)
    return votes[:, 0] > SELECT_FRACTION * np.maximum(votes[:, 1], 1e-12)


def change_mask(edit: np.ndarray, unedited: np.ndarray, threshold: float) -> np.ndarray:
    """(H, W) bool: where an (H, W, 3) edit differs from the unedited image by more than
    `threshold` in some channel, after a 3x3 box blur of the difference (so isolated pixels of
    editor noise or reconstruction error do not vote)."""
    diff = np.abs(np.asarray(edit, np.float32) - np.asarray(unedited, np.float32))
    return cv2.blur(diff, (3, 3)).max(-1) > threshold


def changed_share(edit: np.ndarray, unedited: np.ndarray, inside: np.ndarray,
                  threshold: float) -> float:
    """Share in [0, 1] of the (H, W) bool `inside` pixels where the (H, W, 3) edit differs from
    the unedited image by more than `threshold` in some channel (pixel by pixel: a blur would
    dilute a thin region's change into its unchanged neighbours)."""
    inside = np.asarray(inside, bool)
    if not inside.any():
        return 0.0
    diff = np.abs(np.asarray(edit, np.float32) - np.asarray(unedited, np.float32)).max(-1)
    return float((diff[inside] > threshold).mean())


def soft_mask(coverage: np.ndarray, dilate: int, blur: float) -> np.ndarray:
    """(H, W) float in [0, 1]: the region's rendered coverage (H, W), binarised at 1/2, dilated
    by `dilate` pixels and blurred with a Gaussian of sigma `blur` pixels (0: none); then the
    maximum with the coverage itself, so the region's pixels keep at least their coverage."""
    m = (np.asarray(coverage, np.float32) > 0.5).astype(np.float32)
    if dilate > 0:
        m = cv2.dilate(m, np.ones((2 * dilate + 1,) * 2, np.uint8))
    if blur > 0:
        m = cv2.GaussianBlur(m, (0, 0), blur)
    return np.clip(np.maximum(m, coverage), 0.0, 1.0)


def composite(edit: np.ndarray, unedited: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W, 3) target: the edit inside the (H, W) soft mask, the unedited image outside."""
    m = np.asarray(mask, np.float32)[..., None]
    return np.asarray(edit, np.float32) * m + np.asarray(unedited, np.float32) * (1 - m)


@functools.lru_cache(maxsize=None)
def make_tracer():
    """Jitted `trace(params, rig, cam, frame, change) -> (N, 2)` [sum_p m w_i, sum_p w_i] of one
    view: change (H, W) float in [0, 1] (a change mask), w_i(p) the standard blending weight of
    Gaussian i at pixel p."""

    @fast_jit
    def trace(params, rig: Rig, cam, frame, change):
        n = params["means"].shape[0]

        def channels(extra):
            return render_bound(params, rig, frame, cam, blend=wabe.standard(),
                                extra_channels=extra).image[..., 3:]

        _, pullback = jax.vjp(channels, jnp.ones((n, 2), jnp.float32))
        cotangent = jnp.stack([change, jnp.ones_like(change)], -1).astype(jnp.float32)
        (votes,) = pullback(cotangent)
        return votes

    return trace


@functools.lru_cache(maxsize=None)
def make_coverage():
    """Jitted `coverage(params, rig, cam, frame, selected) -> (H, W)` in [0, 1]: the alpha of
    the selected Gaussians (selected: (N,) bool) composited among all of them."""

    @fast_jit
    def coverage(params, rig: Rig, cam, frame, selected):
        extra = selected.astype(jnp.float32)[:, None]
        return render_bound(params, rig, frame, cam, blend=wabe.standard(),
                            extra_channels=extra).image[..., 3]

    return coverage
