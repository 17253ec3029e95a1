"""Text-driven editing of a head avatar: the embedded default, or your own data and avatar.

    python -m gae_jax.train [--preset fast] [--prompt "turn the lips blue"] [--out runs/edit]
                            [--data DIR [--flame-model FILE] --avatar DIR] ...

Loads the scene, takes the original avatar (`--avatar DIR` with a GaussianAvatars
`point_cloud.ply`, or reconstructs one and caches it), edits it (`edit.edit.edit_avatar`), and
writes the run folder: `metrics.json`, `evaluation_set.npz` (what `python -m gae_jax.evaluate`
re-scores), `original_avatar/` and `edited_avatar/` (GaussianAvatars files), `edited_posed.ply`,
`motion.npz` (the scene's sequences, which `python -m gae_jax.view` plays), `grid.png` and
`reenactment.mp4`. Presets: `edit.config.PRESETS`.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import sys
import time
from typing import Callable, Optional

import jax
from tqdm import tqdm

from gae_jax import cli, instructions
from gae_jax.edit import config as edit_config
from gae_jax.edit import edit, outputs
from gae_jax.edit.config import EditConfig
from gae_jax.edit.editors import make_editor
from gae_jax.evaluation import clip_score, report, score, truth
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import RECONSTRUCTION_VERSION, fit
from gae_jax.model import avatar_io
from gae_jax.render import projection
from gae_jax.scene.load import SCENE_HELP, SceneConfig, load_scene
from gae_jax.scene.synthetic import scene_fingerprint
from gae_jax.util.fileio import PlyError, atomic_write_bytes, cache_root


def original_avatar(scene, iterations: int, progress: bool, **settings):
    """The reconstruction of the scene's identity A with `iterations` steps and any other
    `ReconstructConfig` settings, from the cache or fitted now (then cached). The cache key
    covers the scene's ground truth, every reconstruction setting and the renderer's screen
    filter."""
    config = ReconstructConfig(iterations=iterations, **settings)
    key = dict(dataclasses.asdict(config), cov2d_dilation=projection.COV2D_DILATION,
               version=RECONSTRUCTION_VERSION)
    settings = hashlib.sha256(json.dumps(key, sort_keys=True).encode())
    path = os.path.join(cache_root(), f"avatar-{scene_fingerprint(scene)}-"
                                     f"{settings.hexdigest()[:12]}.ply")
    if os.path.isfile(path):
        try:
            return avatar_io.load_bound_avatar(path, scene.face_regions)
        except (PlyError, OSError) as e:
            print(f"warning: the cached avatar is unreadable ({e}); reconstructing it",
                  file=sys.stderr)
    fitted, _ = fit(scene, config, progress=progress)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    avatar_io.save_avatar_ply(fitted, path)
    return avatar_io.load_bound_avatar(path, scene.face_regions)


def check_inputs(config: EditConfig) -> None:
    """Fails early (ValueError / FileNotFoundError) on a prompt the editor cannot read or a
    missing model folder."""
    if config.editor == "semantic":
        instructions.parse(config.prompt)
    elif config.editor == "style":
        instructions.parse_style(config.prompt)
    else:
        make_editor("ip2p", folder=config.ip2p_folder)
    if config.clip_folder:
        clip_score.check_folder(config.clip_folder)


def run(config: EditConfig, workdir: str, scene=None, original=None, resume: bool = False,
        progress: bool = True, video: bool = True,
        progress_fn: Optional[Callable[[int, dict], None]] = None,
        scene_config: SceneConfig = SceneConfig(), timings: Optional[dict] = None,
        keep_checkpoint: bool = False, avatar_extra: Optional[dict] = None) -> dict:
    """The whole job into `workdir`; returns the metrics written to `metrics.json`. `scene` and
    `original` default to `load_scene(scene_config)` and its cached reconstruction; `timings`
    holds what the caller already spent (the CLI's loading); `avatar_extra`: flame_param keys
    of an input avatar the written avatars carry on. A finished run removes its checkpoint
    unless `keep_checkpoint`."""
    os.makedirs(workdir, exist_ok=True)
    timings = dict(timings or {})
    t0 = time.perf_counter()
    scene = scene if scene is not None else load_scene(scene_config, progress=progress)
    if scene.head and not scene_config.data and scene.head != scene_config.head:
        # A scene passed in: the run folder records the head that posed it (the viewer reads it).
        scene_config = dataclasses.replace(scene_config, head=scene.head)
    if original is None:
        original = original_avatar(scene, config.reconstruct_iterations, progress)
    session = edit.setup(config, scene, original)
    timings["setup_s"] = round(time.perf_counter() - t0, 1)
    t1 = time.perf_counter()
    edited, history = edit.edit_avatar(session, workdir, resume=resume, progress=progress,
                                       progress_fn=progress_fn, keep_checkpoint=keep_checkpoint)
    timings["edit_s"] = round(time.perf_counter() - t1, 1)
    t2 = time.perf_counter()
    bar = tqdm(total=4, desc="outputs: avatar files", disable=not progress, leave=False)
    outputs.write_avatar_files(session, edited, workdir, avatar_extra)
    bar.update(1)
    bar.set_description("outputs: grid")
    outputs.write_grid(session, edited, os.path.join(workdir, "grid.png"),
                       jax.random.PRNGKey(99))
    bar.update(1)
    if video:
        bar.set_description("outputs: video")
        outputs.write_video(session, edited, os.path.join(workdir, "reenactment.mp4"))
    bar.update(1)
    bar.set_description("evaluation")
    evalset = truth.build(scene, config.prompt)
    truth.save(evalset, os.path.join(workdir, truth.FILE_NAME))
    scores = score.evaluate_avatars(evalset, edited, original, session.rig.tile_capacity,
                                    session.step_config.blend, config.clip_folder)
    bar.update(1)
    bar.close()
    timings["outputs_and_evaluation_s"] = round(time.perf_counter() - t2, 1)
    timings["total_s"] = round(time.perf_counter() - t0 + timings.get("load_s", 0.0), 1)
    metrics = dict(config=dataclasses.asdict(config), scene=dataclasses.asdict(scene_config),
                   timings=timings, evaluation=scores,
                   final_losses=history[-1] if history else {}, gaussians=edited.num,
                   tile_capacity=session.rig.tile_capacity)
    atomic_write_bytes(os.path.join(workdir, "metrics.json"),
                       json.dumps(metrics, indent=1).encode())
    return metrics


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gae_jax.train",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="fast", choices=list(edit_config.PRESETS),
                   help="starting settings; flags override them")
    p.add_argument("--out", default="runs/edit", help="run folder (default: runs/edit)")
    p.add_argument("--avatar", default="", help="folder with the original avatar's "
                   "point_cloud.ply (GaussianAvatars); empty: reconstruct it (cached)")
    p.add_argument("--resume", action="store_true", help="continue from the run folder's "
                   "checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace a run already in --out")
    p.add_argument("--keep-checkpoint", action="store_true", help="keep the edit checkpoint of "
                   "a finished run (~13 MB), so that --resume --iterations N can extend it")
    p.add_argument("--no-video", action="store_true", help="skip the MP4")
    cli.add_compile_cache_flag(p)
    cli.add_config_flags(p, SceneConfig, SCENE_HELP, "scene")
    cli.add_config_flags(p, EditConfig, edit_config.HELP, "edit", edit_config.CHOICES)
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    cli.use_compile_cache(args.compile_cache)
    inputs = {}

    def prepare():
        start = time.perf_counter()
        config = edit_config.preset(args.preset, **cli.given(args, EditConfig))
        cli.check_run_folder(args.out, args.resume, args.overwrite, edit.CHECKPOINT)
        check_inputs(config)
        scene_config = SceneConfig(**cli.given(args, SceneConfig))
        if scene_config.data and not args.avatar and config.reconstruct_iterations:
            print("note: no --avatar given; reconstructing one from --data first",
                  file=sys.stderr)
        scene = load_scene(scene_config, progress=True)
        original, extra = None, None
        if args.avatar:
            original = avatar_io.load_bound_avatar(
                os.path.join(args.avatar, "point_cloud.ply"), scene.face_regions)
            params = os.path.join(args.avatar, "flame_param.npz")
            extra = avatar_io.extra_flame_params(params) if os.path.isfile(params) else None
        inputs.update(config=config, scene=scene, original=original, scene_config=scene_config,
                      avatar_extra=extra, timings=dict(load_s=round(time.perf_counter() - start,
                                                                     1)))
        return 0

    if cli.main_guard(prepare):
        return 2
    metrics = run(inputs["config"], args.out, inputs["scene"], inputs["original"],
                  resume=args.resume, video=not args.no_video,
                  scene_config=inputs["scene_config"], timings=inputs["timings"],
                  keep_checkpoint=args.keep_checkpoint, avatar_extra=inputs["avatar_extra"])
    print(report.summary_table(metrics["evaluation"]))
    print(json.dumps(dict(out=args.out, timings=metrics["timings"]), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
