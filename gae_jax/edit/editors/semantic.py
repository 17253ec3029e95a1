"""The built-in semantic editor: recolour or pattern named regions of a render.

The instruction is read by `instructions.parse` (a region, a colour and optionally "stripes":
"turn the lips navy blue", "add green stripes to the skin").

The 2D edit keeps the shading and changes the albedo: a pixel of the region becomes colour x
shading. Without `context["normals"]` the shading is the pixel's luminance over the region's
nominal albedo (`albedo`): exact for an untextured region, blotchy for a textured one (the
MakeHuman hair and brows are strokes of hair and skin colour). With head-space normals of the
render, the editor also fits a Lambertian lighting to the image, as face reconstructions do
(DECA, after Ramamoorthi and Hanrahan: nine spherical harmonics of the normal, robust least
squares over the interior pixels of every region whose albedo it knows, `shading`), and keeps
a pixel's own ratio only where it is a plausible shading that agrees with that light
(`shading.trust_ratio`): textured and dark regions get the named colour evenly shaded, uniform
ones stay exact. Either way the shading is read from the original (unedited) image the editor
is conditioned on, as InstructPix2Pix is: read from the current render, it feeds back (a darker
target colour darkens the next target, without end).

Regions come from `context["regions"]` (the training view's projected mesh labels, or labels
rendered from the avatar's Gaussians); stripes need `context["canonical"]` (head-space positions
per pixel: the tracked mesh's rest positions projected into the view, or the avatar's rendered
ones) so that they stick to the head, and a pixel that a stripe's edge crosses takes its share
of the stripe (`instructions.stripe_distance`), as a supersampled render does. A pixel on a
region's outline -- part region, part neighbour -- changes by the region's share of the
recolour only, as a perfect editor's antialiased edge would: with `context["samples"]` (the
region labels of several rays in each pixel, the tracked mesh projected along them as the
labels are) the share is theirs and the region's old colour and shading those of the nearest
pixel it covers whole; without them, on a thin uniform region only, the share is matted from
the image (its old colour: albedo x light; the neighbour's: seen two pixels out; in proportion
as the region is thin: 1 - its size factor below), and a wide or textured region's outline is
painted as its inside.

Outside the edited region the editor returns the render it edits (`keeps="render"`, the default:
a diffusion editor's output follows its input) or the original image (`keeps="original"`: what
image conditioning on the original pulls toward). With "render", anything the avatar does wrong
outside the region -- a halo of recoloured Gaussians, drift -- comes back as its own target and
is never corrected; see the README's ablation and stability findings.

`noise` in [0, 1] imitates a diffusion editor's inconsistency, all drawn from the key: per-call
colour jitter, the region's outline grown or shrunk and shifted (with label samples, the
outline as they place it, to a fraction of a pixel) by up to `4 noise` pixels scaled
by the size of the thinner of the two regions it separates (`min(1, thickness / 16 px)`, the
thickness being the widest inscribed disk's diameter: a 3-px iris's outline moves by a fraction
of a pixel, the skin's by up to 1.2 px at the default noise where it meets the hair, as little
as the lips' where it meets them, not at all where it meets the background; `border_size`),
an occasional partial edit (a random half of the region, probability 0.25 noise), and a global
tone change.

`bleed` (pixels at full size, scaled like the outline's jitter, default 0) imitates how a
diffusion edit spills over a region's silhouette: the edit's colour fades out over `bleed` px
across the region's outline onto whatever borders it, and recolours fully what lies behind the
region (`BEHIND`: the mouth, teeth and tongue behind the lips; the eyes behind the eyelids'
skin) within 3 x `bleed` px of it, wherever the render shows them. This is the leak WABE is
meant to stop: the ideal edit never recolours those pixels. Spilled pixels keep their own
shading (luminance over their own region's albedo).

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
from gae_jax.edit.editors.shading import shading_map, trust_ratio
from gae_jax.instructions import mode_of, parse, stripe_distance, stripe_on
from gae_jax.model import head

LUMA = np.array([0.299, 0.587, 0.114], np.float32)

KEEPS = ("render", "original")
OUTLINE_JITTER = 4.0  # px the outline moves at noise 1 for a region of full size
FULL_SIZE_THICKNESS = 16.0  # px: thinner regions' outlines (and bleed) move proportionally less
THIN = 10  # interior pixels below which a region is judged on all its pixels (an iris)
MATTE_CONTRAST = 0.1  # colour distance below which region and neighbour are too alike to matte
MATTE_RESIDUAL = 0.25  # off the two colours' line by more than this share: not a mix of them
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
        region_id = head.REGION_ID[instruction.region]
        rays = self.ray_labels(context, image.shape[:2])
        hits = None if rays is None else rays == region_id
        share = None if hits is None else hits.mean(-1, dtype=np.float32)
        own = regions == region_id
        region_distance = (_signed_distance(own) if hits is None else
                           _share_distance(hits, share))
        pattern = np.ones(regions.shape, bool)
        distance = region_distance
        if instruction.stripes:
            if "canonical" not in context:
                raise ValueError("stripes need context['canonical'], (H, W, 3) head-space "
                                 "positions of the render")
            height = np.asarray(context["canonical"])[..., 1]
            pattern = stripe_on(height, phase)
            # a stripe's edge crosses pixels: each takes its share of the stripe
            pixel = np.hypot(*np.gradient(height.astype(np.float64)))
            distance = np.minimum(region_distance, stripe_distance(height, pixel, phase))
        mask = own & pattern
        keys = jax.random.split(key, 7)
        colour = np.asarray(instruction.colour, np.float32)
        weight = np.clip(distance + 0.5, 0.0, 1.0)
        size = min(1.0, thickness(mask) / FULL_SIZE_THICKNESS)
        unmixed = None if rays is None else np.all(rays == rays[..., :1], axis=-1)
        shade, light, uniform = self.shading(source, regions, context.get("normals"),
                                             instruction.region, unmixed)
        # How much of a thin uniform region's outline stays where it is whatever the editor's
        # moves: with label samples, where they put it; without, the share matted from the
        # image. Most of a thin region's pixels are outline pixels.
        matte = uniform * (1.0 - size) if context.get("normals") is not None else 0.0
        if self.noise > 0:
            colour = colour + 0.12 * self.noise * np.asarray(
                jax.random.normal(keys[0], (3,)), np.float32)
            reach = OUTLINE_JITTER * self.noise * border_size(regions, mask, size)
            weight = _jitter(mask, reach, keys[1:6], self.noise, distance,
                             matte if share is not None else 0.0)
        colour = np.clip(colour, 0, 1)
        outside = image if self.keeps == "render" else source
        w = weight[..., None]
        base = np.asarray(self.albedo.get(instruction.region, colour), np.float32)
        edited = w * colour * shade[..., None] + (1 - w) * outside
        if share is not None:
            # Where the (moved) outline crosses a pixel, only the region's part of it changes,
            # by what recolouring changes next to it: the old colour and shading of the nearest
            # pixel the region covers whole.
            pure = mask & (share >= 1.0)
            old, near = _nearest(source, shade, pure, base * light[..., None], light)
            edited = np.where(((weight > 0) & (weight < 1))[..., None],
                              outside + w * (colour * near[..., None] - old), edited)
        elif matte > 0:
            # Without label samples, the share of an outline pixel is matted from the image:
            # the region's old colour known (a uniform region: albedo x light) and the
            # neighbour's seen nearby (`_matte`). That matters for a thin region, most of whose
            # pixels are on its outline; a wide one's is painted as its inside.
            inside = weight > 0.5
            share_of = _matte(source, inside, base * light[..., None]) * pattern
            repaint = outside + share_of[..., None] * (colour - base) * light[..., None]
            band = _outline_band(inside)[..., None]
            edited = np.where(band, matte * repaint + (1 - matte) * edited, edited)
        if self.bleed:
            edited = self._bleed(edited, source, regions, weight > 0.5, instruction.region,
                                 colour, self.bleed * size)
        if self.noise > 0:
            edited = edited * (1 + 0.04 * self.noise * float(jax.random.normal(keys[6])))
        return np.clip(edited, 0, 1).astype(np.float32)

    @staticmethod
    def ray_labels(context: dict, shape: tuple):
        """(H, W, S) int region labels of S rays on a grid in each pixel, `context["samples"]`
        (the tracked mesh projected along them, as the labels are), or None without them."""
        if context.get("samples") is None:
            return None
        samples = np.asarray(context["samples"])
        side = int(round(np.sqrt(samples.shape[-1]))) if samples.ndim == 3 else 0
        if samples.ndim != 3 or samples.shape[:2] != tuple(shape) or side ** 2 != samples.shape[-1]:
            raise ValueError(f"context['samples'] must be (H, W, S) with (H, W) = {shape} and S "
                             f"a square (rays on a grid in each pixel), got {samples.shape}")
        return samples

    def shading(self, source, regions, normals, region: str, unmixed=None) -> tuple:
        """((H, W) shading, (H, W) light, uniformity) of the original image: the pixels' ratios
        or the fitted lighting, as the module docstring says, the light alone (the fit
        rescaled to the region) and whether the region is uniform or textured
        (`shading.trust_ratio`) when `normals` are given; else luminance over `region`'s
        albedo, twice, and uniform. `unmixed`: (H, W) bool, the pixels all of whose rays see
        one region (from label samples): the light is fitted on them, and a thin region's
        judged on them, instead of on the pixels whose 3 x 3 neighbourhood has one label."""
        luminance = {n: max(float(np.asarray(rgb) @ LUMA), 1e-3)
                     for n, rgb in self.albedo.items() if n in head.REGION_ID}
        if normals is not None:
            normals = np.asarray(normals, np.float32)
            known = np.full(regions.shape, -1.0, np.float32)
            for name, value in luminance.items():
                known[regions == head.REGION_ID[name]] = value
            inner = _interior(regions) if unmixed is None else unmixed & (regions >= 0)
            ratio = (source @ LUMA) / luminance.get(region, 1.0)
            fitted = shading_map(source, normals, inner & (known > 0), known)
            if fitted is not None:
                own = regions == head.REGION_ID.get(region, -2)
                own_inner = own & inner
                thin = own_inner.sum() < THIN
                # a thin region is judged on all its pixels, unless label samples say which
                # of them it covers whole
                judged = own if thin and (unmixed is None or not own_inner.any()) else own_inner
                return trust_ratio(ratio, *fitted, judged, thin)
        ratio = (source @ LUMA) / luminance.get(region, max(float(LUMA.sum()), 1e-3))
        return ratio, ratio, 1.0

    def mode(self, key) -> int:
        """The mode (0 .. modes - 1) a call with `key` picks (0 when there is one)."""
        if self.modes == 1:
            return 0
        return int(jax.random.randint(jax.random.fold_in(key, 0x6D6F), (), 0, self.modes))

    def _bleed(self, edited, source, regions, mask, region, colour, bleed):
        """`edited` with the region's colour spilled `bleed` px around `mask` (see the module
        docstring)."""
        import cv2

        if not mask.any() or bleed <= 0:
            return edited
        distance = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2,
                                         cv2.DIST_MASK_PRECISE)
        weight = np.clip(1.0 - distance / (bleed + 1.0), 0.0, 1.0)
        behind = np.isin(regions, [head.REGION_ID[n] for n in BEHIND.get(region, ())])
        weight = np.where(behind & (distance <= 3 * bleed), 1.0, weight)
        weight = np.where(mask, 0.0, weight)[..., None]
        own = np.ones(regions.shape, np.float32)
        for name, rgb in self.albedo.items():
            if name in head.REGION_ID:
                own[regions == head.REGION_ID[name]] = max(float(np.asarray(rgb) @ LUMA), 1e-3)
        spill = colour * np.clip((source @ LUMA) / own, 0.0, 1.5)[..., None]
        return (1.0 - weight) * edited + weight * spill


def thickness(mask: np.ndarray) -> float:
    """Diameter (px) of the widest disk inside an (H, W) bool mask (0 for an empty one)."""
    import cv2

    if not mask.any():
        return 0.0
    inside = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2,
                                   cv2.DIST_MASK_PRECISE)
    return 2.0 * float(inside.max())


def border_size(regions: np.ndarray, mask: np.ndarray, size: float) -> np.ndarray:
    """(H, W) size factor in [0, `size`] of the outline near each pixel: where the (H, W) bool
    `mask` (of size factor `size`) meets another region, the thinner of the two decides how far
    their shared outline moves (a skin edit barely moves the lips' outline: a 3-px region's
    edge is as uncertain as the region is wide); where it meets the background it does not
    move (the silhouette is the image's clearest edge; `regions` -1), and where it meets
    unknown foreground (-2) or the region's own unmasked pixels (between stripes) `size`
    decides. Each pixel takes the nearest unmasked pixel's label."""
    import cv2

    outside = ~mask
    labels = np.unique(regions[outside])
    if labels.size == 0:
        return np.full(mask.shape, size, np.float32)
    own = regions[mask][0] if mask.any() else None
    distances, factors = [], []
    for label in labels:
        where = outside & (regions == label)
        distances.append(cv2.distanceTransform((~where).astype(np.uint8), cv2.DIST_L2,
                                               cv2.DIST_MASK_PRECISE))
        if label == -1:
            factors.append(0.0)
        elif label == -2 or label == own:
            factors.append(size)
        else:
            factors.append(min(size, thickness(regions == label) / FULL_SIZE_THICKNESS))
    nearest = np.argmin(np.stack(distances), 0)
    return np.asarray(factors, np.float32)[nearest]


def _interior(regions: np.ndarray) -> np.ndarray:
    """(H, W) bool: labelled pixels whose 3x3 neighbourhood has their label only (no mixed
    colours of two regions or of the background)."""
    import cv2

    kernel = np.ones((3, 3), np.uint8)
    lo = cv2.erode(regions.astype(np.int16) + 1, kernel, borderType=cv2.BORDER_REPLICATE)
    hi = cv2.dilate(regions.astype(np.int16) + 1, kernel, borderType=cv2.BORDER_REPLICATE)
    return (regions >= 0) & (lo == hi)


def _signed_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float: distance (px) to the mask's outline, positive inside, so that the outline
    sits at 0 and a pixel is inside where the value is above 0."""
    import cv2

    m = mask.astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return np.where(mask, inside - 0.5, 0.5 - outside).astype(np.float32)


def _share_distance(hits: np.ndarray, share: np.ndarray) -> np.ndarray:
    """(H, W) float signed distance (px, positive inside) from each pixel's centre to the
    outline of a region given by the (H, W, k * k) bool `hits` of k x k rays in each pixel
    (row-major in the pixel), whose (H, W) `share` is their mean. Where the region covers part
    of a pixel, share - 1/2 (a straight outline through a box-filtered pixel: the weight
    clip(d + 1/2, 0, 1) is the share); elsewhere `_signed_distance` of the k-times finer mask
    the rays form, in pixels and averaged over the pixel's rays, at least 1/2 where the region
    covers the pixel whole and at most -1/2 where it misses it. The field rises about a pixel
    per pixel across the outline, so that shifting it moves the region."""
    h, w, count = hits.shape
    k = int(round(np.sqrt(count)))
    fine = hits.reshape(h, w, k, k).transpose(0, 2, 1, 3).reshape(h * k, w * k)
    d = (_signed_distance(fine) / k).reshape(h, k, w, k).mean((1, 3))
    return np.where(share >= 1.0, np.maximum(d, 0.5),
                    np.where(share <= 0.0, np.minimum(d, -0.5), share - 0.5)).astype(np.float32)


def _nearest(source: np.ndarray, shade: np.ndarray, pure: np.ndarray, old: np.ndarray,
             light: np.ndarray) -> tuple:
    """((H, W, 3) the region's old colour, (H, W) its shading) at every pixel, taken from the
    nearest pixel the region covers whole (the (H, W) bool `pure`): its colour in the (H, W, 3)
    `source` and its (H, W) `shade`, so that a textured region's outline continues the texture
    beside it. Without a pure pixel (a region thinner than a pixel), the (H, W, 3) `old` and
    (H, W) `light` (a uniform region's albedo under the fitted light)."""
    import cv2

    if not pure.any():
        return old, light
    _, index = cv2.distanceTransformWithLabels((~pure).astype(np.uint8), cv2.DIST_L2,
                                               cv2.DIST_MASK_5,
                                               labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(pure)  # labels number the pure pixels in raster order from 1
    at = (ys[index - 1], xs[index - 1])
    return source[at], shade[at]


def _matte(image: np.ndarray, inside: np.ndarray, old: np.ndarray) -> np.ndarray:
    """(H, W) share of each pixel near the outline of the (H, W) bool region `inside` that the
    region covers, from the (H, W, 3) image: pixel = share x old + (1 - share) x neighbour,
    with `old` (H, W, 3) the region's colour and the neighbour's colour the mean of the pixels
    two pixels outside the region within a 5 x 5 window (alpha matting with known colours,
    the least-squares share, kept on the labels' side of one half: they come from the pixel's
    centre). Where the two colours are too alike to tell, the pixel is no mix of them (its
    distance to their line beyond `MATTE_RESIDUAL` of theirs: texture, a third colour) or no
    neighbour is seen, the labels decide: 1 inside, 0 outside."""
    import cv2

    m = inside.astype(np.uint8)
    ring = (cv2.dilate(m, np.ones((5, 5), np.uint8)) & ~cv2.dilate(m, np.ones((3, 3), np.uint8))
            ).astype(np.float32)
    count = cv2.boxFilter(ring, -1, (5, 5), normalize=False)
    total = cv2.boxFilter(np.asarray(image, np.float32) * ring[..., None], -1, (5, 5),
                          normalize=False)
    neighbour = total / np.maximum(count, 1.0)[..., None]
    contrast = old - neighbour
    strength = np.sum(contrast * contrast, -1)
    share = np.sum((image - neighbour) * contrast, -1) / np.maximum(strength, 1e-6)
    mixed = neighbour + np.clip(share, 0.0, 1.0)[..., None] * contrast
    residual = np.sum((image - mixed) ** 2, -1)
    share = np.where(inside, np.clip(share, 0.5, 1.0), np.clip(share, 0.0, 0.5))
    sure = ((count > 0) & (strength > MATTE_CONTRAST ** 2)
            & (residual < MATTE_RESIDUAL ** 2 * strength))
    return np.where(sure, share, inside.astype(np.float32))


def _outline_band(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels on either side of the mask's outline (a 3x3 neighbourhood holds
    both inside and outside pixels)."""
    import cv2

    m = mask.astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    return cv2.dilate(m, kernel).astype(bool) & ~cv2.erode(m, kernel).astype(bool)


def _jitter(mask: np.ndarray, reach: np.ndarray, keys, noise: float,
            distance: np.ndarray, steady: float = 0.0) -> np.ndarray:
    """(H, W) float weight in [0, 1]: `mask` grown (or shrunk) and shifted by a grow and a shift
    drawn uniformly in [-1, 1], each pixel's outline moving by them times its (H, W) `reach` in
    px (sub-pixel: its (H, W) signed `distance`, positive inside, is sampled with linear
    interpolation and clipped to a one-pixel ramp), a `steady` share of the weight staying
    with the unmoved outline; then with probability 0.25 noise cut to a random half."""
    import cv2

    weight = np.clip(distance + 0.5, 0.0, 1.0)
    reach = np.broadcast_to(np.asarray(reach, np.float32), mask.shape)
    if reach.max() > 0 and mask.any():
        grow = float(jax.random.uniform(keys[0], (), minval=-1.0, maxval=1.0))
        dy, dx = (float(v) for v in jax.random.uniform(keys[1], (2,), minval=-1.0,
                                                         maxval=1.0))
        yy, xx = np.mgrid[:mask.shape[0], :mask.shape[1]].astype(np.float32)
        moved = cv2.remap(distance, xx - dx * reach, yy - dy * reach,
                          cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        weight = (steady * weight
                  + (1.0 - steady) * np.clip(moved + grow * reach + 0.5, 0.0, 1.0))
    if float(jax.random.uniform(keys[2])) < 0.25 * noise and mask.any():
        ys, xs = np.nonzero(mask)
        angle = float(jax.random.uniform(keys[3], (), maxval=2 * np.pi))
        yy, xx = np.mgrid[:mask.shape[0], :mask.shape[1]]
        side = (xx - xs.mean()) * np.cos(angle) + (yy - ys.mean()) * np.sin(angle) > 0
        weight = weight * side
    return weight
