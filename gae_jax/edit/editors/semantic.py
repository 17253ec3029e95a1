"""The built-in semantic editor: recolour or pattern named regions of a render.

The instruction is read by `instructions.parse` (a region word, a colour word and optionally
"stripes": "turn the lips blue", "add green stripes to the skin").

The 2D edit keeps the shading and changes the albedo: a pixel of the region becomes
colour x luminance(original pixel) / luminance(region albedo), the shading read from the
original (unedited) image the editor is conditioned on, as InstructPix2Pix is. (Reading it from
the render instead feeds back: once the render is partly recoloured its luminance no longer
measures shading, and a darker target colour darkens the next target, without end.) Regions come from `context["regions"]`
(labels rendered from the avatar's Gaussians, i.e. what is visible); stripes need
`context["canonical"]` (head-space positions per pixel) so that they stick to the head.

Outside the edited region the editor returns the render it edits (`keeps="render"`, the default:
a diffusion editor's output follows its input) or the original image (`keeps="original"`: what
image conditioning on the original pulls toward). With "render", anything the avatar does wrong
outside the region -- a halo of recoloured Gaussians, drift -- comes back as its own target and
is never corrected; see the README's ablation and stability findings.

`noise` in [0, 1] imitates a diffusion editor's inconsistency, all drawn from the key: per-call
colour jitter, a mask grown or shrunk by up to 2 px, a shift by up to 2 px, an occasional partial
edit (a random half of the region, probability 0.25 noise), and a global tone change.

`bleed` (pixels, default 0) imitates how a diffusion edit spills over a region's silhouette: the
edit's colour fades out over `bleed` px across the region's outline onto whatever borders it,
and recolours fully what lies behind the region (`BEHIND`: the mouth, teeth and tongue behind
the lips; the eyes behind the eyelids' skin) within 3 x `bleed` px of it, wherever the render
shows them. This is the leak WABE is meant to stop: the ideal edit never recolours those pixels.
Spilled pixels keep their own shading (luminance over their own region's albedo).

`modes` (default 1) makes the editor multimodal, as a diffusion editor is when several answers
fit a prompt: each call picks one of `modes` equally likely answers (m drawn from the key,
`instructions.mode_of`): stripes shifted by m / modes of a period, so two calls on the same view
may put the stripes on opposite halves of the region; a recolour in one of `modes` shades of
its colour, dark to light. Averaging such edits blurs them into a mean; the ideal of mode m is
`evaluation.truth.build(..., mode=m, modes=modes)`.

`instructions.ideal_albedo` applies the same instruction without noise to the mesh's vertex
albedo: its ray-cast render (`evaluation.truth`) is the ground truth of the edit.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from gae_jax.edit.editors.base import as_image
from gae_jax.instructions import mode_of, parse, stripe_on
from gae_jax.model import head

LUMA = np.array([0.299, 0.587, 0.114], np.float32)

KEEPS = ("render", "original")
# What an edit of a region bleeds into when visible (`bleed`): the regions it occludes.
BEHIND = {"lips": ("mouth", "teeth", "tongue"), "skin": ("sclera", "iris", "pupil"),
          "iris": ("pupil",), "sclera": ("iris", "pupil")}


@dataclasses.dataclass(frozen=True)
class SemanticEditor:
    """See the module docstring. `albedo`: region -> base RGB used to recover the shading."""

    noise: float = 0.0
    albedo: dict = dataclasses.field(default_factory=lambda: dict(head.ALBEDO))
    keeps: str = "render"  # outside the edit: "render" (the image edited) or "original"
    bleed: int = 0  # px the edit spills across the region's outline (3x into what it occludes)
    modes: int = 1  # answers a call picks from (stripe phases or shades; 1: always the same)

    def __post_init__(self):
        if not 0.0 <= self.noise <= 1.0:
            raise ValueError(f"noise must be in [0, 1], got {self.noise}")
        if not (isinstance(self.bleed, (int, np.integer)) and 0 <= self.bleed <= 16):
            raise ValueError(f"bleed must be an integer number of pixels in [0, 16], got "
                             f"{self.bleed!r}")
        if not (isinstance(self.modes, (int, np.integer)) and 1 <= self.modes <= 8):
            raise ValueError(f"modes must be an integer in [1, 8], got {self.modes!r}")
        if self.keeps not in KEEPS:
            raise ValueError(f"keeps must be one of {KEEPS}, got {self.keeps!r}")

    def edit(self, render, original, prompt: str, key, context: dict | None = None):
        instruction, phase = mode_of(parse(prompt), self.mode(key), self.modes)
        image = as_image(render, "render")
        source = as_image(original, "original")
        if source.shape != image.shape:
            raise ValueError(f"original {source.shape} and render {image.shape} differ in size")
        context = context or {}
        if "regions" not in context:
            raise ValueError("the semantic editor needs context['regions'], the (H, W) region "
                             "labels of the render")
        regions = np.asarray(context["regions"])
        if regions.shape != image.shape[:2]:
            raise ValueError(f"context['regions'] must be {image.shape[:2]}, got {regions.shape}")
        mask = regions == head.REGION_ID[instruction.region]
        if instruction.stripes:
            if "canonical" not in context:
                raise ValueError("stripes need context['canonical'], (H, W, 3) head-space "
                                 "positions of the render")
            mask &= stripe_on(np.asarray(context["canonical"])[..., 1], phase)
        keys = jax.random.split(key, 7)
        colour = np.asarray(instruction.colour, np.float32)
        if self.noise > 0:
            colour = colour + 0.12 * self.noise * np.asarray(
                jax.random.normal(keys[0], (3,)), np.float32)
            mask = _jitter_mask(mask, self.noise, keys[1:6])
        base = np.asarray(self.albedo[instruction.region], np.float32)
        shade = (source @ LUMA) / max(float(base @ LUMA), 1e-3)
        outside = image if self.keeps == "render" else source
        edited = np.where(mask[..., None], np.clip(colour, 0, 1) * shade[..., None], outside)
        if self.bleed:
            edited = self._bleed(edited, source, regions, mask, instruction.region,
                                 np.clip(colour, 0, 1))
        if self.noise > 0:
            edited = edited * (1 + 0.04 * self.noise * float(jax.random.normal(keys[6])))
        return np.clip(edited, 0, 1).astype(np.float32)

    def mode(self, key) -> int:
        """The mode (0 .. modes - 1) a call with `key` picks (0 when there is one)."""
        if self.modes == 1:
            return 0
        return int(jax.random.randint(jax.random.fold_in(key, 0x6D6F), (), 0, self.modes))

    def _bleed(self, edited, source, regions, mask, region, colour):
        """`edited` with the region's colour spilled around `mask` (see the module docstring)."""
        import cv2

        if not mask.any():
            return edited
        distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2,
                                         cv2.DIST_MASK_PRECISE)
        weight = np.clip(1.0 - distance / (self.bleed + 1.0), 0.0, 1.0)
        behind = np.isin(regions, [head.REGION_ID[n] for n in BEHIND.get(region, ())])
        weight = np.where(behind & (distance <= 3 * self.bleed), 1.0, weight)
        weight = np.where(mask, 0.0, weight)[..., None]
        own = np.ones(regions.shape, np.float32)
        for name, rgb in self.albedo.items():
            if name in head.REGION_ID:
                own[regions == head.REGION_ID[name]] = max(float(np.asarray(rgb) @ LUMA), 1e-3)
        spill = colour * np.clip((source @ LUMA) / own, 0.0, 1.5)[..., None]
        return (1.0 - weight) * edited + weight * spill


def _jitter_mask(mask: np.ndarray, noise: float, keys) -> np.ndarray:
    import cv2

    reach = int(round(2 * noise))
    if reach:
        grow = int(jax.random.randint(keys[0], (), -reach, reach + 1))
        kernel = np.ones((3, 3), np.uint8)
        m = mask.astype(np.uint8)
        if grow > 0:
            m = cv2.dilate(m, kernel, iterations=grow)
        elif grow < 0:
            m = cv2.erode(m, kernel, iterations=-grow)
        dy, dx = (int(v) for v in jax.random.randint(keys[1], (2,), -reach, reach + 1))
        mask = np.roll(m.astype(bool), (dy, dx), axis=(0, 1))
    if float(jax.random.uniform(keys[2])) < 0.25 * noise and mask.any():
        ys, xs = np.nonzero(mask)
        angle = float(jax.random.uniform(keys[3], (), maxval=2 * np.pi))
        yy, xx = np.mgrid[:mask.shape[0], :mask.shape[1]]
        side = (xx - xs.mean()) * np.cos(angle) + (yy - ys.mean()) * np.sin(angle) > 0
        mask = mask & side
    return mask
