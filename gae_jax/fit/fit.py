"""`fit(scene, config)`: the reconstruction loop over the jitted step, with densification,
SH growth, atomic checkpoints and exact resume.

Departures from GaussianAvatars, chosen for a 2-core CPU budget of minutes (documented knobs):
initial opacity 0.9 and in-plane scale 0.3 k with a thin normal axis (surfels that already cover
the surface) instead of opacity 0.1 and spheres of size k; a position rate of 1e-2 decaying to
1e-4 over the (short) fit instead of 5e-3 decaying over 600k steps (at 2e-3 the fit stalls at
~26 dB after 400 steps, at 1e-2 it reaches ~36 dB: see benchmarks/reconstruct.py); no
densification by default (the scene does not need it, measured there too); tile capacity sized
from the initial avatar's busiest tile instead of unbounded lists.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax import loop
from gae_jax.fit.config import FitStepConfig, ReconstructConfig
from gae_jax.fit.densify import densify_and_prune
from gae_jax.fit.step import FitState, initial_state, make_fit_step, optimizer, sh_mask
from gae_jax.model import avatar as av
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import (Scene, posed_vertices, training_frames, training_images,
                                 training_label_samples, training_labels)
from gae_jax.scene.unseen import unseen_views

CHECKPOINT_NAME = "reconstruct_checkpoint.npz"
# Changes when the same settings fit a different avatar (cached reconstructions are keyed by it):
# 2: the region loss on binary region codes. 3: against each pixel's label samples (an edge
# pixel asks for the regions' mix).
RECONSTRUCTION_VERSION = 3


def initial_avatar(scene: Scene, config: ReconstructConfig, key) -> av.Avatar:
    """GaussianAvatars' binding on the rest mesh with our surfel-like initial shape."""
    model = scene.model
    init = av.init_from_mesh(model.v_template, model.faces, scene.vertex_colors["A"],
                             scene.face_regions, per_face=config.per_face,
                             sh_degree=config.sh_degree, key=key, opacity=config.init_opacity,
                             normal_scale=config.normal_scale)
    return dataclasses.replace(init, log_scales=init.log_scales + math.log(config.init_scale))


def _checkpoint_template(config: ReconstructConfig):
    def template(arrays):
        n = arrays["binding"].shape[0]
        params = {k: jnp.zeros(arrays[f"shape/{k}"]) for k in av.TRAINABLE}
        return FitState(params, optimizer(FitStepConfig.of(config)).init(params),
                        jax.random.PRNGKey(0), jnp.int32(0), jnp.zeros((n,), jnp.float32),
                        jnp.zeros((n,), jnp.int32))

    return template


def _save(path, state: FitState, fixed: av.Avatar, config, history, capacity,
          unseen_capacity):
    shapes = {f"shape/{k}": jnp.asarray(v.shape) for k, v in state.params.items()}
    loop.save_checkpoint(path, dict(state=state), dict(binding=fixed.binding,
                                                       regions=fixed.regions, **shapes),
                         config, history=history, tile_capacity=capacity,
                         unseen_capacity=unseen_capacity)


def _unseen(scene: Scene, avatar: av.Avatar, config: ReconstructConfig, capacity: int,
            kept: int):
    """(Rig, (K, H, W, S) labels) of the fit's `unseen_views` views (`scene.unseen`). Cameras
    between the training ones can see the head larger than any training camera: the rig's tile
    capacity is the larger of the training `capacity` and those views' busiest tile, sized once
    and then `kept` through resumes (0: not sized yet)."""
    views = unseen_views(scene, config.unseen_views, config.seed)
    rig = rigs.make_rig(scene.model.faces, avatar, views.vertices, views.intrinsics, views.w2c,
                        scene.background, scene.width, scene.height, kept or capacity,
                        config.screen_filter)
    if not kept:
        rig = dataclasses.replace(rig, tile_capacity=max(capacity, rigs.required_capacity(
            avatar.trainable(), rig, range(config.unseen_views))))
    return rig, jnp.asarray(views.labels)


def fit(scene: Scene, config: ReconstructConfig = ReconstructConfig(),
        progress_fn: Optional[Callable[[int, dict], None]] = None,
        checkpoint_dir: Optional[str] = None, resume: bool = False, progress: bool = False,
        initial: Optional[av.Avatar] = None):
    """Fits identity A's avatar on the scene's training split, from GaussianAvatars'
    initialisation or from `initial` (an avatar bound to the scene's mesh: a fit continued, or
    started from a denser or edited avatar; the schedule restarts).

    Returns (Avatar, history): history is one dict of metrics per step (loss, photometric, psnr,
    overflow_tiles, num_gaussians). `progress` shows a tqdm bar with loss and PSNR;
    `progress_fn(steps_done, metrics)` is called for every step, one step behind the device.
    """
    key, init_key = jax.random.split(jax.random.PRNGKey(config.seed))
    step_config = FitStepConfig.of(config)
    vertices = posed_vertices(scene, training_frames(scene))
    images = jnp.asarray(training_images(scene))
    if not config.region_weight:
        labels = np.zeros((1, 1, 1, 1, 1), np.int8)
    else:
        labels = (training_label_samples(scene) if config.label_samples else
                  training_labels(scene)[..., None])
    labels = jnp.asarray(labels)
    cameras = jnp.asarray(scene.train_cameras, jnp.int32)
    path = os.path.join(checkpoint_dir, CHECKPOINT_NAME) if checkpoint_dir else None
    history, capacity, unseen_capacity = [], config.tile_capacity, 0
    if resume and path and os.path.isfile(path):
        trees, arrays, meta = loop.load_checkpoint(
            path, dict(state=_checkpoint_template(config)), config, free=("checkpoint_every",))
        state, history, capacity = trees["state"], meta["history"], meta["tile_capacity"]
        unseen_capacity = meta.get("unseen_capacity", 0)
        fixed = av.Avatar(binding=jnp.asarray(arrays["binding"]),
                          regions=jnp.asarray(arrays["regions"]), **state.params)
    else:
        fixed = initial_avatar(scene, config, init_key) if initial is None else initial
        if initial is not None and (initial.colors.ndim == 2) != (config.sh_degree is None):
            raise ValueError("initial avatar's colours do not match config.sh_degree (plain RGB "
                             "needs sh_degree None, SH coefficients an integer degree)")
        state = initial_state(fixed.trainable(), step_config, key)
    # Sized once from the initial avatar and kept through resumes (same shapes, same numerics).
    rig = rigs.put_rig(scene, fixed, vertices, tile_capacity=capacity,
                       screen_filter=config.screen_filter)
    capacity = rig.tile_capacity
    unseen = None
    if config.unseen_weight:
        unseen = _unseen(scene, fixed, config, capacity, unseen_capacity)
        unseen_capacity = unseen[0].tile_capacity
    step = make_fit_step(step_config)
    recorder = loop.Recorder("reconstruct", config.iterations, int(state.step), history,
                             progress, progress_fn, postfix_every=10, postfix=lambda h: dict(
                                 loss=f"{h['loss']:.4f}", psnr=f"{h['psnr']:.2f}",
                                 n=int(h["num_gaussians"])))
    densify_stop = int(config.densify_until * config.iterations)
    unseen_start = int(config.unseen_from * config.iterations)
    for i in range(int(state.step), config.iterations):
        state, metrics = step(state, rig, images, labels, cameras,
                              unseen if i >= unseen_start else None)
        recorder.push(i + 1, metrics)
        done = i + 1
        if (config.densify_every and config.densify_from <= done < densify_stop
                and done % config.densify_every == 0):
            recorder.flush()
            state, fixed = densify_and_prune(state, fixed, config, scene.model.faces.shape[0])
            rig = dataclasses.replace(rig, binding=jnp.asarray(fixed.binding),
                                      regions=jnp.asarray(fixed.regions))
            if unseen is not None:
                unseen = (dataclasses.replace(unseen[0], binding=rig.binding,
                                              regions=rig.regions), unseen[1])
        if path and config.checkpoint_every and done % config.checkpoint_every == 0:
            recorder.flush()
            _save(path, state, fixed, config, recorder.history, capacity, unseen_capacity)
    history = recorder.close()
    fitted = fixed.with_params(state.params)
    if fitted.colors.ndim == 3:
        fitted = dataclasses.replace(
            fitted, colors=fitted.colors * sh_mask(fitted.colors.shape, min(
                config.iterations // max(config.sh_every, 1), config.sh_degree or 0)))
    return fitted, history
