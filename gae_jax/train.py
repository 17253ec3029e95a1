"""Text-driven editing of a head avatar: the embedded default, or your own data and avatar.

    python -m gae_jax.train [--preset fast] [--prompt "turn the lips blue"] [--out runs/edit]
                            [--data DIR [--flame-model FILE] --avatar DIR] ...

Loads the scene, takes the original avatar (`--avatar DIR` with a GaussianAvatars
`point_cloud.ply`, or reconstructs one and caches it) and runs the job (`run.job.run`): the
edit, the run folder (`run/folder.py` lists its files), the evaluation. Presets:
`edit.config.PRESETS`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from gae_jax import cli
from gae_jax.edit import config as edit_config
from gae_jax.edit import edit
from gae_jax.edit.config import EditConfig
from gae_jax.evaluation import report
from gae_jax.model import avatar_io
from gae_jax.run import folder, job
from gae_jax.scene.load import SCENE_HELP, SceneConfig, load_scene


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
    cli.prepare_process(args.compile_cache)
    inputs = {}

    def prepare():
        start = time.perf_counter()
        config = edit_config.preset(args.preset, **cli.given(args, EditConfig))
        cli.check_run_folder(args.out, args.resume, args.overwrite, edit.CHECKPOINT,
                             folder.METRICS)
        job.check_inputs(config)
        scene_config = SceneConfig(**cli.given(args, SceneConfig))
        if scene_config.data and not args.avatar and config.reconstruct_iterations:
            print("note: no --avatar given; reconstructing one from --data first",
                  file=sys.stderr)
        scene = load_scene(scene_config, progress=True)
        original, extra = None, None
        if args.avatar:
            original = avatar_io.load_bound_avatar(folder.avatar_file(args.avatar),
                                                   scene.face_regions)
            params = os.path.join(args.avatar, "flame_param.npz")
            extra = avatar_io.extra_flame_params(params) if os.path.isfile(params) else None
        inputs.update(config=config, scene=scene, original=original, scene_config=scene_config,
                      avatar_extra=extra, timings=dict(load_s=round(time.perf_counter() - start,
                                                                     1)))
        return 0

    if cli.main_guard(prepare):
        return 2
    metrics = job.run(inputs["config"], args.out, inputs["scene"], inputs["original"],
                  resume=args.resume, video=not args.no_video,
                  scene_config=inputs["scene_config"], timings=inputs["timings"],
                  keep_checkpoint=args.keep_checkpoint, avatar_extra=inputs["avatar_extra"])
    print(report.summary_table(metrics["evaluation"]))
    print(json.dumps(dict(out=args.out, timings=metrics["timings"]), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
