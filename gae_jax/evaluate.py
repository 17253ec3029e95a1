"""Scoring an edited avatar against the ideal edit, per protocol and per region.

Protocols on the default scene (the paper's three):
  * `novel_view`: the held-out camera on identity A's training frames;
  * `self_reenactment`: A's held-out sequence `mix` from training cameras;
  * `cross_identity`: identity B's motion (`b_mix`: expression, pose, jaw, eyes) driving A's
    avatar (A's shape), as GaussianAvatars' cross-identity reenactment.
The ideal edit is the ray-cast mesh with the instruction applied to its albedo
(`editors.semantic.ideal_albedo`); instructions outside the semantic vocabulary (styles) have no
ideal and are scored against the unedited truth only where regions must be preserved.

Scores pool squared errors over all pixels of a region across frames and cameras before taking
PSNR (a frame where a region is absent adds nothing): `whole`, the edited region, and each
preserved group (`teeth`, `eyes` = sclera + iris + pupil, `rest` = everything else).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax import data, head

PROTOCOLS = ("novel_view", "self_reenactment", "cross_identity")
PRESERVED_GROUPS = {"teeth": ("teeth",), "eyes": ("sclera", "iris", "pupil"),
                    "mouth": ("mouth",)}


@dataclasses.dataclass(frozen=True)
class ProtocolFrames:
    """What to render for one protocol: (sequence, frame) pairs, cameras, and A's shape."""

    name: str
    pairs: list
    cameras: tuple


def protocol_frames(scene, name: str, frames: int = 6, cameras: int = 3) -> ProtocolFrames:
    """The (sequence, frame) pairs and cameras of a protocol, evenly subsampled."""
    if name == "novel_view":
        from gae_jax.reconstruct import training_frames

        pairs = training_frames(scene)
        cams = tuple(scene.held_out_cameras)
    elif name in ("self_reenactment", "cross_identity"):
        seq = data.HELD_OUT_SEQUENCE if name == "self_reenactment" else data.CROSS_SEQUENCE
        pairs = [(seq, t) for t in range(scene.sequences[seq].num_frames)]
        train = scene.train_cameras
        cams = tuple(train[i] for i in np.linspace(0, len(train) - 1, cameras).round().astype(int))
        if name == "cross_identity":
            cams = tuple(scene.held_out_cameras) + cams[:max(cameras - 1, 0)]
    else:
        raise ValueError(f"unknown protocol {name!r}; choose from {PROTOCOLS}")
    pick = np.linspace(0, len(pairs) - 1, min(frames, len(pairs))).round().astype(int)
    return ProtocolFrames(name, [pairs[i] for i in pick], cams)


def ideal_frames(scene, model, assets, vertex_albedo, protocol: ProtocolFrames):
    """Ray-cast truth of A (shape A) with the given albedo: images (P, K, H, W, 3) uint8 and
    regions (P, K, H, W), for P pairs x K cameras."""
    colours = data.shaded_colors(model, vertex_albedo, scene.shapes["A"])
    intr = scene.intrinsics[list(protocol.cameras)]
    w2c = scene.w2c[list(protocol.cameras)]
    images, regions = [], []
    for name, t in protocol.pairs:
        img, reg = data.render_frame(model, assets.face_regions, colours, scene.shapes["A"],
                                     scene.sequences[name], t, intr, w2c, scene.width,
                                     scene.background, supersample=3)
        images.append(img)
        regions.append(reg)
    return np.stack(images), np.stack(regions)


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
    masks["rest"] = np.isin(regions, rest) | (regions < 0)
    return masks


def region_psnr(predicted: np.ndarray, truth: np.ndarray, regions: np.ndarray,
                edited_region: str | None) -> dict:
    """PSNR (dB) per mask over (..., H, W, 3) images in [0, 1] or uint8; None if a mask is empty."""
    p = _float(predicted)
    t = _float(truth)
    out = {}
    for name, mask in region_masks(regions, edited_region).items():
        if not mask.any():
            out[name] = None
            continue
        mse = float(np.mean((p[mask] - t[mask]) ** 2))
        out[name] = round(float(10 * np.log10(1.0 / max(mse, 1e-12))), 3)
    return out


def _float(x):
    x = np.asarray(x)
    return x.astype(np.float64) / 255.0 if x.dtype == np.uint8 else x.astype(np.float64)
