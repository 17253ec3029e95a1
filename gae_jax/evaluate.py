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

import argparse
import dataclasses
import json
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.evaluation import clip_score
from gae_jax.scene import synthetic
from gae_jax.model import head
from gae_jax.render import losses

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
        seq = synthetic.HELD_OUT_SEQUENCE if name == "self_reenactment" else synthetic.CROSS_SEQUENCE
        pairs = [(seq, t) for t in range(scene.sequences[seq].num_frames)]
        train = scene.train_cameras
        cams = tuple(train[i] for i in np.linspace(0, len(train) - 1, cameras).round().astype(int))
        if name == "cross_identity":
            cams = tuple(scene.held_out_cameras) + cams[:max(cameras - 1, 0)]
    else:
        raise ValueError(f"unknown protocol {name!r}; choose from {PROTOCOLS}")
    pick = np.linspace(0, len(pairs) - 1, min(frames, len(pairs))).round().astype(int)
    return ProtocolFrames(name, [pairs[i] for i in pick], cams)


def temporal_frames(scene, name: str) -> ProtocolFrames:
    """A clip of consecutive frames at one camera for a protocol's flicker and CLIP-C: a whole
    training sequence at the held-out camera (novel view), the held-out sequence at a training
    camera (self-reenactment), identity B's sequence at the held-out camera (cross-identity)."""
    if name not in PROTOCOLS:
        raise ValueError(f"unknown protocol {name!r}; choose from {PROTOCOLS}")
    seq = {"novel_view": synthetic.TRAIN_SEQUENCES[0], "self_reenactment": synthetic.HELD_OUT_SEQUENCE,
           "cross_identity": synthetic.CROSS_SEQUENCE}[name]
    cam = scene.train_cameras[0] if name == "self_reenactment" else scene.held_out_cameras[0]
    return ProtocolFrames(name, [(seq, t) for t in range(scene.sequences[seq].num_frames)],
                          (cam,))


def ideal_frames(scene, model, assets, vertex_albedo, protocol: ProtocolFrames):
    """Ray-cast truth of A (shape A) with the given albedo: images (P, K, H, W, 3) uint8 and
    regions (P, K, H, W), for P pairs x K cameras."""
    colours = synthetic.shaded_colors(model, vertex_albedo, scene.shapes["A"])
    intr = scene.intrinsics[list(protocol.cameras)]
    w2c = scene.w2c[list(protocol.cameras)]
    images, regions = [], []
    for name, t in protocol.pairs:
        img, reg = synthetic.render_frame(model, assets.face_regions, colours, scene.shapes["A"],
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
        from gae_jax.evaluation import lpips

        maps["lpips"] = np.asarray(lpips.lpips_map(p, t))
    out = {"psnr": {}, **{k: {} for k in maps}}
    for name, mask in masks.items():
        empty = not mask.any()
        mse = float(np.mean((p[mask] - t[mask]) ** 2)) if not empty else None
        out["psnr"][name] = None if empty else round(10 * np.log10(1.0 / max(mse, 1e-12)), 3)
        for metric, m in maps.items():
            out[metric][name] = None if empty else round(float(m[mask].mean()), 4)
    return out


@jax.jit
def _ssim_maps(a, b):
    return jax.vmap(losses.ssim_map)(a, b)


def region_psnr(predicted, truth, regions, edited_region: str | None) -> dict:
    """PSNR (dB) per mask (see `region_scores`)."""
    return region_scores(predicted, truth, regions, edited_region, perceptual=False)["psnr"]


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


SUMMARY_COLUMNS = (("psnr", "whole"), ("psnr", "edited"), ("psnr", "teeth"), ("psnr", "eyes"),
                   ("psnr", "rest"), ("ssim", "whole"), ("ssim", "edited"), ("lpips", "whole"),
                   ("lpips", "edited"))


def summary_table(results: dict) -> str:
    """Markdown table of `train.evaluate_edit`'s results: a row per protocol and avatar."""
    head_cells = [f"{m.upper()} {r}" for m, r in SUMMARY_COLUMNS] + ["flicker", "CLIP-S",
                                                                      "CLIP-C"]
    lines = ["| protocol | avatar | " + " | ".join(head_cells) + " |",
             "|---" * (len(head_cells) + 2) + "|"]
    for name in PROTOCOLS:
        if name not in results:
            continue
        r = results[name]
        for who in ("ours", "original_avatar"):
            cells = [_cell(r[who].get(m, {}).get(k)) for m, k in SUMMARY_COLUMNS]
            cells.append(_cell(r["flicker"][who]["whole"]))
            cells += [_cell(r.get("clip_s")), _cell(r.get("clip_c"))] if who == "ours" else [
                "", ""]
            lines.append(f"| {name} | {who} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _cell(value) -> str:
    if value is None:
        return "-"
    return f"{value:.4f}" if abs(value) < 1 else f"{value:.2f}"


def main(argv=None) -> int:
    """`python -m gae_jax.evaluate RUN_DIR`: re-scores a run folder written by
    `python -m gae_jax.train`; writes RUN_DIR/evaluation.json and evaluation.md."""
    p = argparse.ArgumentParser(prog="python -m gae_jax.evaluate", description=main.__doc__)
    p.add_argument("run_dir", help="folder written by python -m gae_jax.train")
    p.add_argument("--frames", type=int, default=4, help="frames per protocol")
    p.add_argument("--clip-folder", default="", help="local CLIP folder for CLIP-S / CLIP-C")
    args = p.parse_args(argv)
    metrics_path = os.path.join(args.run_dir, "metrics.json")
    avatar_path = os.path.join(args.run_dir, "edited_avatar", "point_cloud.ply")
    for path in (metrics_path, avatar_path):
        if not os.path.isfile(path):
            print(f"error: {path} not found; is {args.run_dir!r} a run folder of "
                  "python -m gae_jax.train?", file=sys.stderr)
            return 2
    if args.frames < 1:
        print("error: --frames must be >= 1", file=sys.stderr)
        return 2
    if args.clip_folder:
        try:
            clip_score.check_folder(args.clip_folder)
        except FileNotFoundError as e:
            print(f"error: --clip-folder: {e}", file=sys.stderr)
            return 2
    from gae_jax import train
    from gae_jax.util.fileio import atomic_write_bytes

    with open(metrics_path) as f:
        saved = json.load(f)["config"]
    fields = {f.name for f in dataclasses.fields(train.EditConfig)}
    config = train.EditConfig(**{k: v for k, v in saved.items() if k in fields})
    session = train.setup(config)
    edited = train.load_avatar(avatar_path, session.assets)
    if edited.num != session.original.num:
        print(f"error: {avatar_path} has {edited.num} Gaussians, the run's original avatar "
              f"{session.original.num}", file=sys.stderr)
        return 2
    results = train.evaluate_edit(session, edited, frames=args.frames,
                                  clip_folder=args.clip_folder)
    table = summary_table(results)
    atomic_write_bytes(os.path.join(args.run_dir, "evaluation.json"),
                       json.dumps(results, indent=1).encode())
    atomic_write_bytes(os.path.join(args.run_dir, "evaluation.md"), (table + "\n").encode())
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
