"""Fitting an avatar to multi-view video (GaussianAvatars-style).

`fit(scene, config)` binds Gaussians to the head's triangles and optimises their local parameters
with GaussianAvatars' losses -- 0.8 L1 + 0.2 D-SSIM, position regulariser (0.01, beyond 1
triangle scale) and scale regulariser (1.0, beyond 0.6) -- and per-attribute Adam learning rates
through `optax.partition` (the position rate decays exponentially, as in 3DGS). One jitted step
samples a training (camera, frame) pair from the state's PRNG key, poses the avatar with FLAME,
renders it and accumulates each Gaussian's screen-space gradient.

Outside jit, every `densify_every` steps: Gaussians whose mean screen gradient exceeds the
threshold are cloned (small) or split (large), Gaussians that are nearly transparent are pruned
and, with `prune_unseen`, so are those that contributed to no pixel of any sampled view since the
last round (the back of the head, the closed mouth's inside: a frontal rig never sees them); the
optimiser state follows each Gaussian. `max_gaussians` caps
growth. SH colours (when `sh_degree` is set) grow one degree every `sh_every` steps. Checkpoints
are written atomically every `checkpoint_every` steps and `fit(..., resume=True)` continues from
the last one with the same result as an uninterrupted run.

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
import io as _io
import json
import math
import os
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gae_jax.model import avatar as av
from gae_jax.model import flame, head
from gae_jax.render import losses, splat
from gae_jax.render.camera import Camera
from gae_jax.util.compile import fast_jit
from gae_jax.util.fileio import atomic_write_bytes

TRAINABLE = ("means", "quats", "log_scales", "opacity_logits", "colors")
CHECKPOINT_NAME = "reconstruct_checkpoint.npz"


@dataclasses.dataclass(frozen=True)
class ReconstructConfig:
    """Settings of `fit` (learning rates in GaussianAvatars' triangle-local units).

    The Gaussian budget: `per_face` at the start, `max_gaussians` at most (0: no cap). Resolution
    is the scene's. `tile_capacity` 0 sizes the per-tile lists from the initial avatar.
    """

    iterations: int = 400
    per_face: int = 1
    init_opacity: float = 0.9
    init_scale: float = 0.3
    normal_scale: float = 0.3
    lr_means: float = 1e-2
    lr_means_final: float = 1e-4
    lr_quats: float = 1e-3
    lr_scales: float = 1.7e-2
    lr_opacity: float = 5e-2
    lr_colors: float = 5e-3
    dssim_weight: float = 0.2
    position_weight: float = 0.01
    scale_weight: float = 1.0
    sh_degree: Optional[int] = None
    sh_every: int = 500
    densify_every: int = 0
    densify_from: int = 200
    densify_until: float = 0.6
    grad_threshold: float = 2e-4
    split_scale: float = 0.5
    prune_opacity: float = 0.005
    prune_unseen: bool = True
    max_gaussians: int = 0
    tile_capacity: int = 0
    tiles_per_chunk: int = 8
    checkpoint_every: int = 0
    seed: int = 0

    def __post_init__(self):
        if self.iterations < 1 or self.per_face < 1 or self.tile_capacity < 0:
            raise ValueError("iterations and per_face must be >= 1, tile_capacity >= 0")
        if not 0 < self.init_opacity < 1:
            raise ValueError(f"init_opacity must be in (0, 1), got {self.init_opacity}")
        if self.sh_degree is not None and not 0 <= self.sh_degree <= 3:
            raise ValueError(f"sh_degree must be None or 0..3, got {self.sh_degree}")
        if min(self.densify_every, self.checkpoint_every, self.max_gaussians) < 0:
            raise ValueError("densify_every, checkpoint_every and max_gaussians must be >= 0")
        if not 0 <= self.densify_until <= 1:
            raise ValueError(f"densify_until is a fraction of the iterations, got "
                             f"{self.densify_until}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FitState:
    """What changes during the fit.

    params: trainable arrays (N, ...); opt_state: optax state; key: PRNG key; step: () int32;
    grad_sum: (N,) accumulated screen-space mean-gradient norms (NDC units); seen: (N,) in how
    many steps each Gaussian contributed to a pixel since the last densification.
    """

    params: dict
    opt_state: optax.OptState
    key: jax.Array
    step: jax.Array
    grad_sum: jax.Array
    seen: jax.Array


def optimizer(config: ReconstructConfig) -> optax.GradientTransformation:
    """Per-attribute Adam; the position rate decays exponentially to `lr_means_final`."""
    means = optax.exponential_decay(config.lr_means, config.iterations,
                                    config.lr_means_final / config.lr_means)
    rates = dict(means=means, quats=config.lr_quats, log_scales=config.lr_scales,
                 opacity_logits=config.lr_opacity, colors=config.lr_colors)
    return optax.partition({k: optax.adam(v, eps=1e-15) for k, v in rates.items()},
                           {k: k for k in TRAINABLE})


def training_frames(scene):
    """(sequence name, frame) pairs of identity A's training sequences."""
    return [(n, t) for n, s in scene.sequences.items() if s.identity == "A" and s.split == "train"
            for t in range(s.num_frames)]


def posed_vertices(model, scene, frames, identity: str = "A") -> np.ndarray:
    """(T, V, 3) mesh vertices of an identity for the given (sequence, frame) pairs."""
    lbs = jax.jit(flame.lbs)
    return np.stack([np.asarray(lbs(model, scene.sequences[n].params(scene.shapes[identity], t)))
                     for n, t in frames])


def sh_mask(colors_shape, degree) -> jax.Array:
    """(K, 1) mask keeping the SH coefficients of bands <= degree (traced degree allowed)."""
    bands = np.floor(np.sqrt(np.arange(colors_shape[1]))).astype(np.int32)
    return (jnp.asarray(bands)[:, None] <= degree).astype(jnp.float32)


def initial_avatar(model, scene, assets, config: ReconstructConfig, key) -> av.Avatar:
    """GaussianAvatars' binding on the rest mesh with our surfel-like initial shape."""
    init = av.init_from_mesh(model.v_template, model.faces, scene.vertex_colors["A"],
                             assets.face_regions, per_face=config.per_face,
                             sh_degree=config.sh_degree, key=key, opacity=config.init_opacity,
                             normal_scale=config.normal_scale)
    return dataclasses.replace(init, log_scales=init.log_scales + math.log(config.init_scale))


def required_capacity(avatar, model, vertices, cameras) -> int:
    """1.25x the busiest tile of `avatar` over the given views, rounded up to 128."""
    load = jax.jit(lambda g, cam: splat.tile_load(g, cam))
    g = av.deform(avatar, vertices, model.faces)
    worst = max(int(load(g, cam)) for cam in cameras)
    return int(128 * math.ceil(1.25 * worst / 128))


def make_step(config, model, binding, regions, vertices, images, intrinsics, w2c, size,
              background, cameras, tile_capacity):
    """A jitted `step(state) -> (state, metrics)` over the given device-resident data.

    vertices: (T, V, 3); images: (C, T, H, W, 3) uint8; cameras: (K,) usable camera indices.
    `binding` and `regions` are fixed for the life of one step function (rebuild after densify).
    """
    faces = model.faces
    opt = optimizer(config)

    def loss_fn(params, offset, cam, frame, degree):
        colors = params["colors"]
        if colors.ndim == 3:
            colors = colors * sh_mask(colors.shape, degree)
        a = av.Avatar(binding=binding, regions=regions, **dict(params, colors=colors))
        g = av.deform(a, vertices[frame], faces)
        camera = Camera(intrinsics=intrinsics[cam], w2c=w2c[cam], width=size, height=size)
        out = splat.render(g, camera, background=background, tile_capacity=tile_capacity,
                           screen_offset=offset, tiles_per_chunk=config.tiles_per_chunk)
        target = images[cam, frame].astype(jnp.float32) / 255.0
        photo = losses.photometric(out.image, target, config.dssim_weight)
        visible = out.stats.radii > 0
        reg = (config.position_weight * losses.position_regulariser(params["means"], visible)
               + config.scale_weight * losses.scale_regulariser(params["log_scales"], visible))
        return photo + reg, (out.stats.contributed, dict(photometric=photo, psnr=losses.psnr(out.image, target),
                                           overflow_tiles=out.stats.overflow_tiles))

    @fast_jit
    def step(state: FitState):
        key, k_cam, k_frame = jax.random.split(state.key, 3)
        cam = cameras[jax.random.randint(k_cam, (), 0, cameras.shape[0])]
        frame = jax.random.randint(k_frame, (), 0, vertices.shape[0])
        degree = jnp.minimum(state.step // max(config.sh_every, 1), config.sh_degree or 0)
        offset = jnp.zeros((binding.shape[0], 2), jnp.float32)
        (loss, (visible, aux)), (grads, offset_grad) = jax.value_and_grad(
            loss_fn, argnums=(0, 1), has_aux=True)(state.params, offset, cam, frame, degree)
        # optax mixes int32 step counts with floats; keep working under strict promotion.
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = opt.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        # 3DGS measures the mean gradient in NDC: d/d(ndc) = d/d(pixel) * size / 2.
        screen_grad = jnp.linalg.norm(offset_grad, axis=-1) * (size / 2)
        new = FitState(params, opt_state, key, state.step + 1,
                       state.grad_sum + jnp.where(visible, screen_grad, 0.0),
                       state.seen + visible.astype(jnp.int32))
        return new, dict(loss=loss, num_gaussians=jnp.int32(binding.shape[0]), **aux)

    return step


def _gather_state(state: FitState, source: np.ndarray, opt: optax.GradientTransformation,
                  params: dict) -> FitState:
    """State for re-indexed Gaussians: optimiser moments follow `source` (old indices)."""
    old_n = state.grad_sum.shape[0]
    index = jnp.asarray(source)

    def follow(x):
        return x[index] if getattr(x, "ndim", 0) >= 1 and x.shape[0] == old_n else x

    opt_state = jax.tree_util.tree_map(follow, state.opt_state)
    n = source.shape[0]
    return FitState(params, opt_state, state.key, state.step, jnp.zeros((n,), jnp.float32),
                    jnp.zeros((n,), jnp.int32))


def densify_and_prune(state: FitState, avatar_fixed: av.Avatar, config: ReconstructConfig,
                      num_faces: int, opt) -> tuple[FitState, av.Avatar]:
    """One densify/prune round on the host; returns the new state and the new fixed arrays."""
    a = av.Avatar(binding=avatar_fixed.binding, regions=avatar_fixed.regions, **state.params)
    mean_grad = np.asarray(state.grad_sum) / np.maximum(np.asarray(state.seen), 1)
    big = np.asarray(jnp.max(a.log_scales, axis=-1)) > math.log(config.split_scale)
    grow = mean_grad >= config.grad_threshold
    room = (config.max_gaussians - a.num) if config.max_gaussians else a.num
    if grow.sum() > max(room, 0):  # keep the strongest gradients within the budget
        keep = np.argsort(-mean_grad)[:max(room, 0)]
        grow = np.zeros_like(grow)
        grow[keep] = True
    key, sub = jax.random.split(state.key)
    a, source = av.densify(a, grow & ~big, grow & big, sub, return_source=True)
    opacity = 1 / (1 + np.exp(-np.asarray(a.opacity_logits)))
    remove = opacity < config.prune_opacity
    if config.prune_unseen:
        seen = np.asarray(state.seen)[source]
        remove |= seen == 0
    a, kept = av.prune(a, remove, num_faces, return_source=True,
                       keep_every_face=not config.prune_unseen)
    source = source[kept]
    params = {k: getattr(a, k) for k in TRAINABLE}
    new = _gather_state(dataclasses.replace(state, key=key), source, opt, params)
    return new, a


def save_checkpoint(path: str, state: FitState, avatar_fixed: av.Avatar, config, history,
                    tile_capacity: int):
    """Writes the fit state atomically (one .npz)."""
    leaves = jax.tree_util.tree_leaves(state.opt_state)
    arrays = {f"param/{k}": np.asarray(v) for k, v in state.params.items()}
    arrays.update({f"opt/{i}": np.asarray(x) for i, x in enumerate(leaves)})
    arrays.update(
        key=np.asarray(state.key), step=np.asarray(state.step), grad_sum=np.asarray(state.grad_sum),
        seen=np.asarray(state.seen), binding=np.asarray(avatar_fixed.binding),
        regions=np.asarray(avatar_fixed.regions),
        meta=np.frombuffer(json.dumps(dict(config=dataclasses.asdict(config), history=history,
                                           tile_capacity=tile_capacity)).encode(), np.uint8))
    buffer = _io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def load_checkpoint(path: str, config, opt):
    """(state, fixed avatar arrays, history, tile capacity) from `save_checkpoint`; checks the
    config."""
    try:
        f = np.load(path)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not a readable checkpoint ({e})") from e
    with f:
        meta = json.loads(bytes(f["meta"]).decode())
        if meta["config"] != json.loads(json.dumps(dataclasses.asdict(config))):
            raise ValueError(f"{path}: written with a different ReconstructConfig; "
                             "start a fresh fit or pass the same config")
        params = {k: jnp.asarray(f[f"param/{k}"]) for k in TRAINABLE}
        template = opt.init(params)
        leaves, treedef = jax.tree_util.tree_flatten(template)
        opt_state = jax.tree_util.tree_unflatten(
            treedef, [jnp.asarray(f[f"opt/{i}"]) for i in range(len(leaves))])
        state = FitState(params, opt_state, jnp.asarray(f["key"]), jnp.asarray(f["step"]),
                         jnp.asarray(f["grad_sum"]), jnp.asarray(f["seen"]))
        fixed = av.Avatar(binding=jnp.asarray(f["binding"]), regions=jnp.asarray(f["regions"]),
                          **params)
    return state, fixed, meta["history"], meta["tile_capacity"]


def fit(scene, config: ReconstructConfig = ReconstructConfig(),
        progress_fn: Optional[Callable[[int, dict], None]] = None,
        checkpoint_dir: Optional[str] = None, resume: bool = False, progress: bool = False):
    """Fits identity A's avatar on the training split.

    Returns (Avatar, history): history is one dict of metrics per step (loss, photometric, psnr,
    overflow_tiles, num_gaussians). `progress` shows a tqdm bar with loss and PSNR;
    `progress_fn(i, metrics)` is called per step with the previous step's metrics.
    """
    model, assets = head.make_head()
    key = jax.random.PRNGKey(config.seed)
    key, init_key = jax.random.split(key)
    frames = training_frames(scene)
    vertices = jnp.asarray(posed_vertices(model, scene, frames))
    names = sorted({n for n, _ in frames}, key=list(scene.sequences).index)
    images = jnp.asarray(np.concatenate([scene.images[n] for n in names], axis=1))
    opt = optimizer(config)
    path = os.path.join(checkpoint_dir, CHECKPOINT_NAME) if checkpoint_dir else None
    if resume and path and os.path.isfile(path):
        state, fixed, history, capacity = load_checkpoint(path, config, opt)
    else:
        capacity = config.tile_capacity
        fixed = initial_avatar(model, scene, assets, config, init_key)
        params = {k: getattr(fixed, k) for k in TRAINABLE}
        n = fixed.num
        state = FitState(params, opt.init(params), key, jnp.int32(0),
                         jnp.zeros((n,), jnp.float32), jnp.zeros((n,), jnp.int32))
        history = []
    # Sized once from the initial avatar and kept through resumes (same shapes, same numerics).
    capacity = capacity or required_capacity(
        fixed, model, vertices[0], [scene.camera(int(c)) for c in scene.train_cameras])
    data = dict(model=model, vertices=vertices, images=images,
                intrinsics=jnp.asarray(scene.intrinsics), w2c=jnp.asarray(scene.w2c),
                size=scene.width, background=jnp.asarray(scene.background),
                cameras=jnp.asarray(scene.train_cameras, jnp.int32), tile_capacity=capacity)

    def build(fixed):
        return make_step(config, binding=fixed.binding, regions=fixed.regions, **data)

    step = build(fixed)
    bar = _progress_bar(config.iterations, int(state.step), progress)
    densify_stop = int(config.densify_until * config.iterations)
    previous = None
    for i in range(int(state.step), config.iterations):
        state, metrics = step(state)
        # Report the previous step's metrics so the host never waits on the current one.
        if previous is not None:
            _record(history, previous, i, progress_fn, bar)
        previous = metrics
        done = i + 1
        if (config.densify_every and config.densify_from <= done < densify_stop
                and done % config.densify_every == 0):
            _record(history, previous, done, progress_fn, bar)
            previous = None
            state, fixed = densify_and_prune(state, fixed, config, model.faces.shape[0], opt)
            step = build(fixed)
        if path and config.checkpoint_every and done % config.checkpoint_every == 0:
            if previous is not None:
                _record(history, previous, done, progress_fn, bar)
                previous = None
            save_checkpoint(path, state, fixed, config, history, capacity)
    if previous is not None:
        _record(history, previous, config.iterations, progress_fn, bar)
    bar.close()
    fitted = av.Avatar(binding=fixed.binding, regions=fixed.regions, **state.params)
    if fitted.colors.ndim == 3:
        fitted = dataclasses.replace(
            fitted, colors=fitted.colors * sh_mask(fitted.colors.shape, min(
                config.iterations // max(config.sh_every, 1), config.sh_degree or 0)))
    return fitted, history


def _record(history, metrics, i, progress_fn, bar):
    host = {k: float(v) for k, v in metrics.items()}
    history.append(host)
    if progress_fn is not None:
        progress_fn(i, host)
    bar.update(1)
    if i % 10 == 0:
        bar.set_postfix(loss=f"{host['loss']:.4f}", psnr=f"{host['psnr']:.2f}",
                        n=int(host["num_gaussians"]))


def _progress_bar(total, initial, enabled):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="reconstruct", disable=not enabled,
                leave=False)


def evaluate_psnr(avatar: av.Avatar, scene, pairs, cameras, identity: str = "A",
                  tile_capacity: int = 0) -> float:
    """Mean PSNR of `avatar` against the scene's ground truth over cameras x (sequence, frame).

    The avatar's colours are kept (identity B's motion drives identity A's appearance only
    through the mesh, as in cross-identity reenactment: compare against B only with care).
    """
    model, _ = head.make_head()
    vertices = posed_vertices(model, scene, pairs, identity)
    capacity = tile_capacity or required_capacity(avatar, model, jnp.asarray(vertices[0]),
                                                  [scene.camera(int(c)) for c in cameras])

    @fast_jit
    def score(verts, cam_index, target):
        g = av.deform(avatar, verts, model.faces)
        camera = Camera(intrinsics=jnp.asarray(scene.intrinsics)[cam_index],
                        w2c=jnp.asarray(scene.w2c)[cam_index], width=scene.width,
                        height=scene.height)
        out = splat.render(g, camera, background=jnp.asarray(scene.background),
                           tile_capacity=capacity)
        return losses.psnr(out.image, target.astype(jnp.float32) / 255.0)

    values = [float(score(jnp.asarray(vertices[j]), jnp.int32(c),
                          jnp.asarray(scene.images[n][c, t])))
              for j, (n, t) in enumerate(pairs) for c in cameras]
    return float(np.mean(values))

