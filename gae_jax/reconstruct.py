"""Fitting an avatar to multi-view video (GaussianAvatars-style), first version.

`fit(scene, config)` binds Gaussians to the head's triangles and optimises their local parameters
with GaussianAvatars' losses -- 0.8 L1 + 0.2 D-SSIM, position regulariser (0.01, beyond 1
triangle scale) and scale regulariser (1.0, beyond 0.6) -- and per-attribute Adam learning rates
through `optax.partition`. One jitted step samples a training (camera, frame) pair from the state's
PRNG key, poses the avatar with FLAME and renders it.

Not yet here (next session): densify / prune during the fit, SH degree growth, checkpoints and
resume, and the benchmark against the PSNR / time targets.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gae_jax import avatar as av
from gae_jax import flame, head, losses, splat
from gae_jax.camera import Camera
from gae_jax.compile import fast_jit

TRAINABLE = ("means", "quats", "log_scales", "opacity_logits", "colors")


@dataclasses.dataclass(frozen=True)
class ReconstructConfig:
    """Settings of `fit` (learning rates in GaussianAvatars' triangle-local units)."""

    iterations: int = 1500
    per_face: int = 1
    init_opacity: float = 0.9
    normal_scale: float = 0.3
    lr_means: float = 2e-3
    lr_quats: float = 1e-3
    lr_scales: float = 1.7e-2
    lr_opacity: float = 5e-2
    lr_colors: float = 5e-3
    dssim_weight: float = 0.2
    position_weight: float = 0.01
    scale_weight: float = 1.0
    tile_capacity: int = 512
    seed: int = 0

    def __post_init__(self):
        if self.iterations < 1 or self.per_face < 1 or self.tile_capacity < 1:
            raise ValueError("iterations, per_face and tile_capacity must be >= 1")
        if not 0 < self.init_opacity < 1:
            raise ValueError(f"init_opacity must be in (0, 1), got {self.init_opacity}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FitState:
    """What changes during the fit: trainable params, optimiser state, PRNG key, step."""

    params: dict
    opt_state: optax.OptState
    key: jax.Array
    step: jax.Array


def _optimizer(config: ReconstructConfig) -> optax.GradientTransformation:
    rates = dict(means=config.lr_means, quats=config.lr_quats, log_scales=config.lr_scales,
                 opacity_logits=config.lr_opacity, colors=config.lr_colors)
    return optax.partition({k: optax.adam(v, eps=1e-15) for k, v in rates.items()},
                           {k: k for k in TRAINABLE})


def training_frames(scene):
    """(sequence name, frame) pairs of identity A's training sequences."""
    return [(n, t) for n, s in scene.sequences.items() if s.identity == "A" and s.split == "train"
            for t in range(s.num_frames)]


def posed_vertices(model, scene, frames) -> np.ndarray:
    """(T, V, 3) mesh vertices of identity A for the given (sequence, frame) pairs."""
    lbs = jax.jit(flame.lbs)
    return np.stack([np.asarray(lbs(model, scene.sequences[n].params(scene.shapes["A"], t)))
                     for n, t in frames])


def make_step(config, model, binding, regions, vertices, images, intrinsics, w2c, size,
              background, cameras):
    """A jitted `step(state) -> (state, metrics)` over the given device-resident data.

    vertices: (T, V, 3); images: (C, T, H, W, 3) uint8; cameras: (K,) usable camera indices.
    """
    faces = model.faces
    optimizer = _optimizer(config)

    def loss_fn(params, cam, frame):
        a = av.Avatar(binding=binding, regions=regions, **params)
        g = av.deform(a, vertices[frame], faces)
        camera = Camera(intrinsics=intrinsics[cam], w2c=w2c[cam], width=size, height=size)
        out = splat.render(g, camera, background=background, tile_capacity=config.tile_capacity)
        target = images[cam, frame].astype(jnp.float32) / 255.0
        photo = losses.photometric(out.image, target, config.dssim_weight)
        visible = out.stats.radii > 0
        reg = (config.position_weight * losses.position_regulariser(params["means"], visible)
               + config.scale_weight * losses.scale_regulariser(params["log_scales"], visible))
        return photo + reg, dict(photometric=photo, psnr=losses.psnr(out.image, target),
                                 overflow_tiles=out.stats.overflow_tiles)

    @fast_jit
    def step(state: FitState):
        key, k_cam, k_frame = jax.random.split(state.key, 3)
        cam = cameras[jax.random.randint(k_cam, (), 0, cameras.shape[0])]
        frame = jax.random.randint(k_frame, (), 0, vertices.shape[0])
        (loss, aux), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params, cam, frame)
        # optax mixes int32 step counts with floats; keep working under strict promotion.
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return FitState(params, opt_state, key, state.step + 1), dict(loss=loss, **aux)

    return step


def fit(scene, config: ReconstructConfig = ReconstructConfig(),
        progress_fn: Optional[Callable[[int, dict], None]] = None):
    """Fits identity A's avatar on the training split; returns (Avatar, list of metrics)."""
    model, assets = head.make_head()
    key = jax.random.PRNGKey(config.seed)
    key, init_key = jax.random.split(key)
    init = av.init_from_mesh(model.v_template, model.faces, scene.vertex_colors["A"],
                             assets.face_regions, per_face=config.per_face, sh_degree=None,
                             key=init_key, opacity=config.init_opacity,
                             normal_scale=config.normal_scale)
    frames = training_frames(scene)
    vertices = jnp.asarray(posed_vertices(model, scene, frames))
    names = sorted({n for n, _ in frames}, key=list(scene.sequences).index)
    images = jnp.asarray(np.concatenate([scene.images[n] for n in names], axis=1))
    step = make_step(config, model, init.binding, init.regions, vertices, images,
                     jnp.asarray(scene.intrinsics), jnp.asarray(scene.w2c), scene.width,
                     jnp.asarray(scene.background), jnp.asarray(scene.train_cameras, jnp.int32))
    params = {k: getattr(init, k) for k in TRAINABLE}
    state = FitState(params, _optimizer(config).init(params), key, jnp.int32(0))
    history, previous = [], None
    for i in range(config.iterations):
        state, metrics = step(state)
        # Report the previous step's metrics so the host never waits on the current one.
        if previous is not None:
            host = {k: float(v) for k, v in previous.items()}
            history.append(host)
            if progress_fn is not None:
                progress_fn(i, host)
        previous = metrics
    history.append({k: float(v) for k, v in previous.items()})
    fitted = av.Avatar(binding=init.binding, regions=init.regions, **state.params)
    return fitted, history
