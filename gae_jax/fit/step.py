"""The jitted fit step: sample a training (camera, frame), render through the rig, take
GaussianAvatars' losses, one per-attribute Adam update, accumulate screen-space gradients.

Losses: (1 - dssim_weight) L1 + dssim_weight D-SSIM, position regulariser (beyond 1 triangle
scale) and scale regulariser (beyond 0.6), on the Gaussians visible in the view, the region
loss (`region_weight`): the rendered regions against the view's projected labels, and
(`unseen_weight`) the same in a view between the training ones that only the mesh labels. The
position rate decays exponentially to `lr_means_final` (as in 3DGS).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gae_jax.fit.config import FitStepConfig
from gae_jax.model import head
from gae_jax.model.avatar import TRAINABLE
from gae_jax.render import losses
from gae_jax.scene.rig import Rig, render_bound
from gae_jax.util.compile import fast_jit


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


def optimizer(config: FitStepConfig) -> optax.GradientTransformation:
    """Per-attribute Adam; the position rate decays exponentially to `lr_means_final`."""
    means = optax.exponential_decay(config.lr_means, config.iterations,
                                    config.lr_means_final / config.lr_means)
    rates = dict(means=means, quats=config.lr_quats, log_scales=config.lr_scales,
                 opacity_logits=config.lr_opacity, colors=config.lr_colors)
    return optax.partition({k: optax.adam(v, eps=1e-15) for k, v in rates.items()},
                           {k: k for k in TRAINABLE})


def initial_state(params: dict, config: FitStepConfig, key) -> FitState:
    """A fresh state for `params` (copied: the step donates its state)."""
    params = jax.tree_util.tree_map(jnp.array, params)
    n = params["means"].shape[0]
    return FitState(params, jax.jit(optimizer(config).init)(params), key, jnp.int32(0),
                    jnp.zeros((n,), jnp.float32), jnp.zeros((n,), jnp.int32))


def sh_mask(colors_shape, degree) -> jax.Array:
    """(K, 1) mask keeping the SH coefficients of bands <= degree (traced degree allowed)."""
    bands = np.floor(np.sqrt(np.arange(colors_shape[1]))).astype(np.int32)
    return (jnp.asarray(bands)[:, None] <= degree).astype(jnp.float32)


def make_fit_step(config: FitStepConfig):
    """A jitted `step(state, rig, images, labels, cameras, unseen=None) -> (state, metrics)`,
    state donated.

    rig: the avatar's `Rig` at the training frames; images: (C, T, H, W, 3) uint8 ground truth
    of those frames; labels: (C, T, H, W, S) int8 region labels of S rays in each pixel of the
    same views (the tracked mesh's face regions projected along them,
    `types.training_label_samples`; -1 background), read when `region_weight` > 0; cameras:
    (K,) int32 cameras to sample from.

    With `region_weight` > 0 the avatar also renders each Gaussian's region as extra channels
    (a binary code, `losses.region_codes`), matched to the labels' (`losses.region_loss`; an
    edge pixel to the mix of the regions its rays hit): the reconstruction learns where
    regions end (Gaussian Grouping's 2D-mask supervision with the regions fixed by the
    binding), so that recolouring one region's Gaussians reproduces a crisp border. `unseen`:
    None, or (Rig, (K, H, W, S) int8 labels) of K views no camera took (`scene.unseen`, view k
    = rig frame k from rig camera k); with `unseen_weight` > 0 one of them, drawn each step, is
    rendered too and its regions matched to its labels (no image: only the mesh knows it).

    Plain RGB colours are clipped to [0, 1] after each update: a Gaussian half hidden behind
    another otherwise overshoots (cyan sclera, green spots in the mouth seen from a novel view).
    """
    opt = optimizer(config)
    codes = jnp.asarray(losses.region_codes(len(head.REGIONS)))

    def loss_fn(params, offset, rig, images, labels, cam, frame, degree, unseen, view):
        colors = params["colors"]
        if colors.ndim == 3:
            params = dict(params, colors=colors * sh_mask(colors.shape, degree))
        extra = (codes[rig.regions + 1] if config.region_weight or config.unseen_weight
                 else None)
        out = render_bound(params, rig, frame, cam, screen_offset=offset, extra_channels=extra,
                           tiles_per_chunk=config.tiles_per_chunk)
        image = out.image[..., :3]
        target = images[cam, frame].astype(jnp.float32) / 255.0
        photo = losses.photometric(image, target, config.dssim_weight)
        visible = out.stats.radii > 0
        reg = (config.position_weight * losses.position_regulariser(params["means"], visible)
               + config.scale_weight * losses.scale_regulariser(params["log_scales"], visible))
        region = jnp.float32(0.0)
        if config.region_weight:
            region = losses.region_loss(out.image[..., 3:], labels[cam, frame], codes,
                                         config.region_outline_weight)
        unseen_region = jnp.float32(0.0)
        if unseen is not None:
            unseen_rig, unseen_labels = unseen
            seen = render_bound(params, unseen_rig, view, view, extra_channels=extra,
                                tiles_per_chunk=config.tiles_per_chunk)
            unseen_region = losses.region_loss(seen.image[..., 3:], unseen_labels[view], codes,
                                                config.unseen_outline_weight)
        return (photo + reg + config.region_weight * region
                + config.unseen_weight * unseen_region), (out.stats.contributed, dict(
            photometric=photo, region=region, unseen_region=unseen_region,
            psnr=losses.psnr(image, target), overflow_tiles=out.stats.overflow_tiles))

    def step(state: FitState, rig: Rig, images, labels, cameras, unseen=None):
        key, k_cam, k_frame = jax.random.split(state.key, 3)
        if not config.unseen_weight:
            unseen = None
        view = jnp.int32(0) if unseen is None else jax.random.randint(
            jax.random.fold_in(state.key, 1), (), 0, unseen[1].shape[0])
        cam = cameras[jax.random.randint(k_cam, (), 0, cameras.shape[0])]
        frame = jax.random.randint(k_frame, (), 0, rig.vertices.shape[0])
        degree = jnp.minimum(state.step // max(config.sh_every, 1), config.sh_degree or 0)
        offset = jnp.zeros((rig.binding.shape[0], 2), jnp.float32)
        (loss, (visible, aux)), (grads, offset_grad) = jax.value_and_grad(
            loss_fn, argnums=(0, 1), has_aux=True)(state.params, offset, rig, images, labels,
                                                   cam, frame, degree, unseen, view)
        # optax mixes int32 step counts with floats; keep working under strict promotion.
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = opt.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        if params["colors"].ndim == 2:
            params = dict(params, colors=jnp.clip(params["colors"], 0.0, 1.0))
        # 3DGS measures the mean gradient in NDC: d/d(ndc) = d/d(pixel) * size / 2.
        screen_grad = jnp.linalg.norm(offset_grad, axis=-1) * (rig.width / 2)
        new = FitState(params, opt_state, key, state.step + 1,
                       state.grad_sum + jnp.where(visible, screen_grad, 0.0),
                       state.seen + visible.astype(jnp.int32))
        return new, dict(loss=loss, num_gaussians=jnp.int32(rig.binding.shape[0]), **aux)

    return fast_jit(step, donate_argnums=0)
