"""Fit an avatar to multi-view video: the embedded scene, or your own NeRSemble folder.

    python -m gae_jax.reconstruct [--data DIR [--flame-model FILE] [--flame-masks FILE]]
                                  --out DIR [--iterations 400] ...

Writes GaussianAvatars' files into DIR: `point_cloud.ply` (Gaussians bound to the model's
triangles) and `flame_param.npz` (the training motion), plus `reconstruct.json` (config,
timings, held-out PSNR). The fit itself is `fit.fit.fit`; this module only reads flags, loads
the scene and writes the files.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from typing import Callable, Optional

from gae_jax import cli
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import CHECKPOINT_NAME, fit
from gae_jax.model import avatar_io
from gae_jax.scene.load import SceneConfig, SCENE_HELP, load_scene
from gae_jax.scene.types import Scene, stacked_params, training_frames
from gae_jax.util.fileio import atomic_write_bytes

HELP = dict(
    iterations="optimisation steps", per_face="Gaussians per triangle at the start",
    init_opacity="initial opacity", init_scale="initial in-plane scale (triangle units)",
    normal_scale="initial scale along the normal, relative to the in-plane one",
    lr_means="Adam rate of local positions (decays)", lr_means_final="final position rate",
    lr_quats="Adam rate of rotations", lr_scales="Adam rate of log-scales",
    lr_opacity="Adam rate of opacity logits", lr_colors="Adam rate of colours",
    dssim_weight="weight of D-SSIM against L1", position_weight="position regulariser weight",
    scale_weight="scale regulariser weight", region_weight="weight of the region loss: the "
    "rendered regions against the tracked mesh's labels projected into the training views "
    "(0: colour alone)", label_samples="the region loss reads the labels of several rays "
    "in each pixel, so that a pixel an outline crosses asks for the regions' mix (false: "
    "the centre ray's label alone)", region_outline_weight="how many times the pixels near "
    "an outline count in the training views' region loss (1: as every pixel)",
    unseen_outline_weight="the same in the views no camera took", unseen_weight="weight of the region loss in views no "
    "camera took: cameras between two training cameras, poses between two training frames "
    "with the expression up to 1.25x as strong, labelled by the tracked mesh alone (0: off)",
    unseen_views="how many such views are drawn once before the fit",
    unseen_from="fraction of the iterations after which those views join the loss (0: from "
    "the first step)", sh_degree="SH degree (empty: plain RGB)",
    sh_every="steps between SH band growths", densify_every="steps between densify rounds "
    "(0: never)", densify_from="first densify step", densify_until="last densify step as a "
    "fraction of the iterations", grad_threshold="screen-gradient threshold of densification",
    split_scale="scale above which a Gaussian is split instead of cloned",
    prune_opacity="opacity below which a Gaussian is pruned",
    prune_unseen="prune Gaussians that no sampled view saw", max_gaussians="cap (0: none)",
    tile_capacity="per-tile list length (0: sized from the busiest tile)",
    tiles_per_chunk="tiles the compositor walks together (speed only)",
    screen_filter="px^2 added to each projected covariance (3DGS and gsplat: 0.3)",
    checkpoint_every="steps between atomic checkpoints (0: none)", seed="random seed")


def run(config: ReconstructConfig, workdir: str, scene: Scene, resume: bool = False,
        progress_fn: Optional[Callable[[int, dict], None]] = None,
        progress: bool = True) -> dict:
    """Fits `scene` and writes the avatar files and `reconstruct.json` into `workdir`."""
    from gae_jax.evaluation.score import psnr_against_capture

    os.makedirs(workdir, exist_ok=True)
    start = time.perf_counter()
    avatar, history = fit(scene, config, progress_fn=progress_fn, checkpoint_dir=workdir,
                          resume=resume, progress=progress)
    seconds = time.perf_counter() - start
    avatar_io.save_avatar_folder(workdir, avatar, scene.shapes["A"],
                                 stacked_params(scene, scene.sequences_of("train")),
                                 scene.static_offsets.get("A"), scene.model.num_vertices)
    report = dict(config=dataclasses.asdict(config), fit_seconds=round(seconds, 1),
                  gaussians=int(avatar.num), final=history[-1] if history else {})
    if scene.held_out_cameras:
        frames = training_frames(scene)
        report["held_out_camera_psnr"] = round(psnr_against_capture(
            avatar, scene, frames[::max(1, len(frames) // 4)], scene.held_out_cameras), 2)
    atomic_write_bytes(os.path.join(workdir, "reconstruct.json"),
                       json.dumps(report, indent=1).encode())
    return report


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gae_jax.reconstruct",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (the avatar)")
    p.add_argument("--resume", action="store_true", help="continue from the folder's checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace an avatar already in --out")
    cli.add_config_flags(p, SceneConfig, SCENE_HELP, "scene")
    cli.add_config_flags(p, ReconstructConfig, HELP, "reconstruction")
    cli.add_compile_cache_flag(p)
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    cli.prepare_process(args.compile_cache)
    loaded = {}

    def prepare():
        loaded["config"] = ReconstructConfig(**cli.given(args, ReconstructConfig))
        cli.check_run_folder(args.out, args.resume, args.overwrite, CHECKPOINT_NAME,
                             marker="reconstruct.json")
        source = SceneConfig(**cli.given(args, SceneConfig))
        loaded["scene"] = load_scene(source, progress=True)
        return 0

    if cli.main_guard(prepare):
        return 2
    report = run(loaded["config"], args.out, loaded["scene"], resume=args.resume)
    print(json.dumps({k: v for k, v in report.items() if k != "config"}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
