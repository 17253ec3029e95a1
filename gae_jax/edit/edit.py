"""The render-edit-aggregate loop over views and time.

`setup(config, scene, original)` puts the scene and the original avatar on the device (one
`Rig`), and builds the jitted step and the preview; `edit_avatar(session, ...)` runs the loop:
each iteration samples `batch` (training camera, training frame) pairs, renders the current
avatar there (with the region labels the semantic editor reads), edits each render outside jit,
takes the edit of an adjacent frame of the same view (from the edit cache, or made fresh), and
runs one jitted step. Checkpoints are atomic; `resume=True` reproduces an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax import loop
from gae_jax.edit import region
from gae_jax.edit.config import EditConfig, StepConfig
from gae_jax.edit.sampler import EditSampler, data_mesh, put_batch, replicate
from gae_jax.edit.step import EditState, initial_state, make_edit_step, make_preview
from gae_jax.model import avatar as av
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import Scene, posed_vertices, training_frames

CHECKPOINT = "edit_checkpoint.npz"
# Fields a resumed run may change: they do not change what the finished iterations computed.
RESUME_FREE = ("checkpoint_every", "clip_folder")
RESUME_GROWABLE = ("iterations",)  # more iterations extend a run


@dataclasses.dataclass(frozen=True)
class EditSetup:
    """What `setup` builds, fixed for the edit: scene, original avatar, device rig, the training
    (sequence, frame) pairs, `canonical` (N, 6): each Gaussian's head-space position and normal
    (the rest pose), and the jitted step and preview."""

    config: EditConfig
    step_config: StepConfig
    scene: Scene
    original: av.Avatar
    rig: rigs.Rig
    pairs: tuple
    canonical: jax.Array
    step: Callable
    preview: Callable


def setup(config: EditConfig, scene: Scene, original: av.Avatar,
          programs: Optional[dict] = None) -> EditSetup:
    """Device data and jitted functions of an edit. `programs` ({StepConfig: (step, preview)})
    keeps the compiled functions between edits in one process: they are taken from it when
    there and added to it when new."""
    pairs = tuple(training_frames(scene))
    rig = rigs.put_rig(scene, original, posed_vertices(scene, pairs))
    step_config = StepConfig.of(config)
    rest = scene.model.v_template
    canonical = jnp.concatenate([
        av.deform(original, rest, scene.model.faces).means,
        jnp.asarray(av.gaussian_normals(original.binding, rest, scene.model.faces))], -1)
    programs = {} if programs is None else programs
    if step_config not in programs:
        programs[step_config] = (make_edit_step(step_config), make_preview(step_config.blend))
    return EditSetup(config, step_config, scene, original, rig, pairs, canonical,
                     *programs[step_config])


def make_sampler(session: EditSetup, editor=None) -> EditSampler:
    s = session
    return EditSampler(s.config, s.scene, s.pairs, s.preview, s.rig, s.canonical,
                       (region.make_tracer(), region.make_coverage()), editor)


def fresh_state(session: EditSetup) -> EditState:
    size = (session.rig.height, session.rig.width)
    return initial_state(session.step_config, session.original.trainable(), size,
                         jax.random.PRNGKey(session.config.seed + 1))


def _save(path, state, sampler: EditSampler, history, config):
    arrays = {}
    for store, name in ((sampler.cache, "cache"), (sampler.dataset, "dataset")):
        keys = sorted(store)
        arrays[f"{name}/keys"] = np.asarray(keys, np.int64).reshape(-1, 2)
        if keys:
            arrays[f"{name}/images"] = np.stack([store[k] for k in keys])
    arrays["region/votes"] = sampler.votes
    arrays["region/shares"] = np.asarray(sampler.shares, np.float64)
    arrays["region/colours"] = np.asarray(sampler.colours, np.float32).reshape(-1, 3)
    loop.save_checkpoint(path, dict(state=state), arrays, config, history=history)


def _load(path, template, sampler: EditSampler, config):
    trees, arrays, meta = loop.load_checkpoint(path, dict(state=template), config,
                                               free=RESUME_FREE, growable=RESUME_GROWABLE)
    for store, name in ((sampler.cache, "cache"), (sampler.dataset, "dataset")):
        keys = arrays[f"{name}/keys"]
        if len(keys):
            images = arrays[f"{name}/images"]
            store.update({(int(a), int(b)): images[j] for j, (a, b) in enumerate(keys)})
    sampler.votes = np.asarray(arrays["region/votes"], np.float64)
    sampler.shares = [float(v) for v in arrays["region/shares"]]
    sampler.colours = [np.asarray(v, np.float32) for v in arrays.get("region/colours", ())]
    return trees["state"], meta["history"]


def edit_avatar(session: EditSetup, out_dir: Optional[str] = None, resume: bool = False,
                progress: bool = False, stop_after: Optional[int] = None,
                progress_fn=None, keep_checkpoint: bool = True, editor=None):
    """Runs the loop; returns (edited Avatar, history). Checkpoints into `out_dir` every
    `checkpoint_every` iterations; a run that completes removes them unless `keep_checkpoint`
    (a kept checkpoint lets `resume` extend the run with more iterations).

    `stop_after` ends the run early (as an interruption would) after that many iterations.
    `editor` replaces the config's 2D editor by an object with the editors' `edit` protocol
    (the benchmarks' oracle).
    With `batch` > 1 and several devices, the batch is split over a ("data",) mesh and the
    state and rig are replicated.
    """
    config = session.config
    state = fresh_state(session)
    sampler = make_sampler(session, editor)
    history: list = []
    path = os.path.join(out_dir, CHECKPOINT) if out_dir else None
    if resume and path and os.path.isfile(path):
        state, history = _load(path, state, sampler, config)
    mesh = data_mesh(config.batch)
    state, rig = replicate(state, mesh), replicate(session.rig, mesh)
    sampler.rig, sampler.canonical = rig, replicate(session.canonical, mesh)
    key = jax.random.PRNGKey(config.seed)
    start = int(state.step)
    recorder = loop.Recorder("edit", config.iterations, start, history, progress, progress_fn,
                             postfix=lambda h: dict(recon=f"{h['recon']:.3f}",
                                                    d=f"{h['d_loss']:.3f}",
                                                    psnr=f"{h['psnr_to_edit']:.1f}"))
    for i in range(start, config.iterations):
        batch = put_batch(sampler.batch(state.params, i, key), mesh)
        editable = replicate(jnp.asarray(sampler.editable()), mesh)
        state, metrics = session.step(state, rig, batch, editable)
        recorder.push(i + 1, metrics)
        done = i + 1
        if path and config.checkpoint_every and done % config.checkpoint_every == 0:
            recorder.flush()
            _save(path, state, sampler, recorder.history, config)
        if stop_after is not None and done >= stop_after:
            break
    finished = int(state.step) == config.iterations
    if path and finished and keep_checkpoint and config.checkpoint_every and \
            config.iterations % config.checkpoint_every:
        recorder.flush()
        _save(path, state, sampler, recorder.history, config)  # so that it can be extended
    history = recorder.close()
    if path and finished and not keep_checkpoint:
        loop.remove_checkpoint(path)
    params = jax.tree_util.tree_map(jnp.asarray, jax.device_get(state.average))
    return session.original.with_params(params), history
