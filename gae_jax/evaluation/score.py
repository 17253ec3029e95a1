"""Scoring avatars on an `EvalSet`: per protocol and region, against the truth, for the edited
avatar and the untouched one; flicker over a clip; CLIP-S / CLIP-C when CLIP weights are given.

Rendering goes through `scene.rig.render_bound` (the one avatar-render composition) with the
blend the avatar was edited with.
"""

from __future__ import annotations

import numpy as np

from gae_jax import instructions
from gae_jax.evaluation import clip_score, metrics
from gae_jax.evaluation.truth import EvalSet
from gae_jax.model.avatar import Avatar
from gae_jax.render import losses, wabe
from gae_jax.render.projection import COV2D_DILATION
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import Scene, posed_vertices


def _check_capacity(tile_capacity: int) -> None:
    if tile_capacity < 1:  # the rig would clamp it to 1: one Gaussian per tile, a wrong image
        raise ValueError(f"tile_capacity must be >= 1, got {tile_capacity} (size it with "
                         "rig.required_capacity or take the edit's rig.tile_capacity)")


def _rig(evalset: EvalSet, avatar: Avatar, vertices, tile_capacity: int) -> rigs.Rig:
    _check_capacity(tile_capacity)
    return rigs.make_rig(evalset.faces, avatar, vertices, evalset.intrinsics, evalset.w2c,
                         evalset.background, evalset.width, evalset.height, tile_capacity)


def render_frames(render, avatar: Avatar, evalset: EvalSet, frames, tile_capacity: int):
    """(P, K, H, W, 3) float renders of `avatar` at an `EvalFrames`' poses and cameras."""
    rig = _rig(evalset, avatar, frames.vertices, tile_capacity)
    return rigs.render_views(render, avatar.trainable(), rig, frames.cameras)


def evaluate_avatars(evalset: EvalSet, edited: Avatar, original: Avatar, tile_capacity: int,
                     blend: wabe.Blend = wabe.standard(), clip_folder: str = "") -> dict:
    """{protocol: {ours, original_avatar: {metric: {region: value}}, flicker, [clip_s,
    clip_c]}, clip, truth}: the run's evaluation (metrics.json, evaluation.json). Ours also
    has `drift`: PSNR against the untouched avatar outside the dilated edit
    (`metrics.drift_scores`), and `change`: the same over each occluded region where the truth
    shows it (`metrics.change_scores`)."""
    _check_capacity(tile_capacity)
    render = rigs.make_view_renderer(blend)
    clip = clip_score.load_clip(clip_folder) if clip_folder else None
    captions = instructions.captions(evalset.prompt)
    region = evalset.edited_region
    results = {}
    for name, (frames, clip_frames) in evalset.protocols.items():
        ours = render_frames(render, edited, evalset, frames, tile_capacity)
        before = render_frames(render, original, evalset, frames, tile_capacity)
        scores = dict(ours=metrics.region_scores(ours, frames.truth, frames.regions, region),
                      original_avatar=metrics.region_scores(before, frames.truth,
                                                            frames.regions, region))
        scores["ours"]["drift"] = metrics.drift_scores(ours, before, frames.regions, region)
        scores["ours"]["change"] = metrics.change_scores(ours, before, frames.regions, region)
        clip_ours = render_frames(render, edited, evalset, clip_frames, tile_capacity)[:, 0]
        clip_before = render_frames(render, original, evalset, clip_frames, tile_capacity)[:, 0]
        masks = metrics.region_masks(clip_frames.regions[:, 0], region)
        truth = clip_frames.truth[:, 0]
        # A clip of one frame (a capture's one-timestep test split) has no flicker.
        scores["flicker"] = {
            who: {m: (round(metrics.flicker(c, truth, masks[m]), 5) if len(truth) > 1 else None)
                  for m in ("whole", "edited") if m in masks}
            for who, c in (("ours", clip_ours), ("original_avatar", clip_before))}
        if clip is not None:
            flat = (-1,) + ours.shape[-3:]
            scores["clip_s"] = round(clip_score.direction_similarity(
                clip, before.reshape(flat), ours.reshape(flat), *captions), 4)
            scores["clip_c"] = round(clip_score.direction_consistency(
                clip, clip_before, clip_ours), 4)
        results[name] = scores
    results["clip"] = (dict(source=captions[0], target=captions[1]) if clip is not None else
                       "skipped: no CLIP folder given (--clip-folder)")
    results["truth"] = evalset.truth_kind
    return results


def psnr_against_capture(avatar: Avatar, scene: Scene, pairs, cameras,
                         identity: str = "A", tile_capacity: int = 0,
                         blend: wabe.Blend = wabe.standard(),
                         screen_filter: float = COV2D_DILATION) -> float:
    """Mean PSNR (over views) of `avatar` rendered with `blend` and `screen_filter` against the
    scene's ground-truth images at cameras x (sequence, frame) pairs, posed with `identity`'s
    shape and motion."""
    rig = rigs.put_rig(scene, avatar, posed_vertices(scene, pairs, identity), tile_capacity,
                       capacity_cameras=cameras, screen_filter=screen_filter)
    images = rigs.render_views(rigs.make_view_renderer(blend), avatar.trainable(), rig, cameras)
    values = [float(losses.psnr(images[j, k], scene.images[n][c, t].astype(np.float32) / 255.0))
              for j, (n, t) in enumerate(pairs) for k, c in enumerate(cameras)]
    return float(np.mean(values))

