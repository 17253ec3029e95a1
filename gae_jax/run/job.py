"""The main job: edit an avatar and write its run folder (`run/folder.py`).

`check_inputs` fails early on what the job cannot use; `run` loads what is not given (the scene,
the cached original avatar), edits, writes the avatars, grid and video (`run/outputs.py`),
evaluates, and writes the metrics.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Callable, Optional

import jax
from tqdm import tqdm

from gae_jax import instructions
from gae_jax.edit import edit
from gae_jax.edit.config import EditConfig
from gae_jax.edit.editors import make_editor
from gae_jax.evaluation import clip_score, score, truth
from gae_jax.run import folder, outputs
from gae_jax.run.original import original_avatar
from gae_jax.scene.load import SceneConfig, load_scene
from gae_jax.scene.synthetic import scene_fingerprint

GRID_KEY = 99  # the PRNG seed of the grid's 2D edits


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
        keep_checkpoint: bool = False, avatar_extra: Optional[dict] = None,
        shared: Optional[dict] = None) -> dict:
    """The whole job into the run folder `workdir`; returns the metrics written there.

    `scene` and `original` default to `load_scene(scene_config)` and its cached
    reconstruction; `timings` holds what the caller already spent (the CLI's loading);
    `avatar_extra`: flame_param keys of an input avatar the written avatars carry on. A
    finished run removes its checkpoint unless `keep_checkpoint`. `shared` is what a caller
    running many jobs in one process keeps between them (filled here): the compiled step and
    preview of each StepConfig and the evaluation set of each (scene, prompt)."""
    os.makedirs(workdir, exist_ok=True)
    timings = dict(timings or {})
    t0 = time.perf_counter()
    scene = scene if scene is not None else load_scene(scene_config, progress=progress)
    if scene.head and not scene_config.data and scene.head != scene_config.head:
        # A scene passed in: the run folder records the head that posed it (the viewer reads it).
        scene_config = dataclasses.replace(scene_config, head=scene.head)
    if original is None:
        original = original_avatar(scene, config.reconstruct_iterations, progress)
    setup = edit.setup(config, scene, original,
                       None if shared is None else shared.setdefault("programs", {}))
    timings["setup_s"] = round(time.perf_counter() - t0, 1)
    t1 = time.perf_counter()
    edited, history = edit.edit_avatar(setup, workdir, resume=resume, progress=progress,
                                       progress_fn=progress_fn, keep_checkpoint=keep_checkpoint)
    timings["edit_s"] = round(time.perf_counter() - t1, 1)
    t2 = time.perf_counter()
    bar = tqdm(total=4, desc="outputs: avatar files", disable=not progress, leave=False)
    outputs.write_avatar_files(scene, original, edited, workdir, avatar_extra)
    bar.update(1)
    bar.set_description("outputs: grid")
    outputs.write_grid(setup, edited, folder.path(workdir, "grid"),
                       jax.random.PRNGKey(GRID_KEY))
    bar.update(1)
    if video:
        bar.set_description("outputs: video")
        outputs.write_video(scene, setup.rig, setup.step_config.blend, original, edited,
                            folder.path(workdir, "video"))
    bar.update(1)
    bar.set_description("evaluation")
    evalset = _evaluation_set(scene, config.prompt, shared)
    truth.save(evalset, folder.path(workdir, "evaluation_set"))
    scores = score.evaluate_avatars(evalset, edited, original, setup.rig.tile_capacity,
                                    setup.step_config.blend, config.clip_folder)
    bar.update(1)
    bar.close()
    timings["outputs_and_evaluation_s"] = round(time.perf_counter() - t2, 1)
    timings["total_s"] = round(time.perf_counter() - t0 + timings.get("load_s", 0.0), 1)
    metrics = dict(config=dataclasses.asdict(config), scene=dataclasses.asdict(scene_config),
                   timings=timings, evaluation=scores,
                   final_losses=history[-1] if history else {}, gaussians=edited.num,
                   tile_capacity=setup.rig.tile_capacity)
    folder.write_metrics(workdir, metrics)
    return metrics


def _evaluation_set(scene, prompt: str, shared: Optional[dict]):
    """`truth.build(scene, prompt)`, kept in `shared` (when given) for the next job."""
    if shared is None:
        return truth.build(scene, prompt)
    key = (scene_fingerprint(scene), prompt)
    evalsets = shared.setdefault("evalsets", {})
    if key not in evalsets:
        evalsets[key] = truth.build(scene, prompt)
    return evalsets[key]
