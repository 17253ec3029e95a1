"""The jitted edit step and the preview render the 2D editor sees.

One step: render the batch of (camera, frame) samples through the rig (traced once: its VJP
serves the avatar update after the discriminator has moved), update the discriminator on
(real, fake) pairs, then the avatar on lambda_1 (L1 + w (1 - SSIM)) + lambda_3 L_G
+ lambda_4 L_const, and the running average of the avatar's iterates that the edit releases.
The batch axis is `vmap`ped; shard it over devices (`sampler.put_batch`) to run data-parallel.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from gae_jax.edit import gan
from gae_jax.edit.config import StepConfig
from gae_jax.model import head
from gae_jax.model.avatar import TRAINABLE
from gae_jax.render import losses, sh, wabe
from gae_jax.scene.rig import Rig, one_frame, render_bound
from gae_jax.util.compile import fast_jit

MOUTH_REGIONS = ("teeth", "mouth")  # excluded from the released code's gradient mask
CODE_MASK_CONTRIBUTORS = 10
SGD_MOMENTUM = 0.9


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class EditState:
    """Avatar params and optimiser state, discriminator params and optimiser state, step, the
    running average of the avatar's params over the steps (`average_params`: what the edit
    releases), and the colours the edit started from (what `coherence_weight` measures each
    Gaussian's change against)."""

    params: dict
    opt_state: optax.OptState
    d_params: dict
    d_opt_state: optax.OptState
    step: jax.Array
    average: dict
    origin: jax.Array  # (N, 3) base RGB before the edit (`base_colour`)


def avatar_optimizer(config: StepConfig) -> optax.GradientTransformation:
    """Adam (or SGD with momentum 0.9, `optimizer="sgd"`) at `lr` for colours, `lr_geometry` for
    opacities, scales and rotations, `lr_means` for local positions (the paper: Adam at 1e-2 for
    everything), each decaying exponentially to `lr_final` of itself over `lr_decay_steps` and
    constant after (a schedule that does not depend on the run's length, so an extended run
    equals a longer one)."""
    rates = {k: config.lr_geometry for k in TRAINABLE}
    rates.update(colors=config.lr, means=config.lr_means)

    def rate(value):
        if config.lr_final == 1.0:
            return value
        return optax.exponential_decay(value, config.lr_decay_steps, config.lr_final,
                                       end_value=value * config.lr_final)

    def one(value):
        if config.optimizer == "sgd":
            return optax.sgd(rate(value), momentum=SGD_MOMENTUM)
        return optax.adam(rate(value), eps=config.adam_eps)

    return optax.partition({k: one(v) for k, v in rates.items()}, {k: k for k in TRAINABLE})


def discriminator_optimizer(config: StepConfig) -> optax.GradientTransformation:
    return optax.adam(config.d_lr, b1=0.5)


def initial_state(config: StepConfig, params: dict, image_size: tuple, key) -> EditState:
    """A fresh state: `params` copied (the step donates its state), a new discriminator for
    (H, W) images from `key`."""
    params = jax.tree_util.tree_map(jnp.array, params)
    d_params = gan.init_params(key, image_size)
    # the optimisers' states made in one program each (eagerly, a program per array shape)
    return EditState(params, jax.jit(avatar_optimizer(config).init)(params), d_params,
                     jax.jit(discriminator_optimizer(config).init)(d_params), jnp.int32(0),
                     jax.tree_util.tree_map(jnp.array, params),
                     jnp.array(base_colour(jnp.asarray(params["colors"]))))  # a copy: donated


def average_params(average: dict, params: dict, step: jax.Array, decay: float) -> dict:
    """The running average after `step` (1, 2, ...) iterates: an exponential average of decay
    `decay`, debiased as Adam's moments are, so that it weighs the iterates 1 .. step alone
    (iterate k by (1 - decay) decay^(step - k), normalised; the params before the first step
    have no weight). `decay` 0: the last iterate. A noisy 2D editor's per-call errors (colour
    jitter, outline moves) enter the iterates one at a time; their average cancels them, as
    Polyak-Ruppert averaging does a noisy gradient's."""
    if decay == 0:
        return params
    decay = jnp.float32(decay)
    weight = (1.0 - decay) / (1.0 - decay ** step.astype(jnp.float32))
    # a + w (p - a): a param that did not move keeps its value bit for bit
    return jax.tree_util.tree_map(
        lambda a, p: jnp.where(step == 1, p, a + weight * (p - a)), average, params)


def coherence_weight(config: StepConfig, step: jax.Array) -> jax.Array:
    """The weight of the change-coherence prior (`losses.change_coherence`) at `step` (0, 1,
    ...): `coherence_weight` x min(1, step / lr_decay_steps), rising as the rates decay. Early,
    each Gaussian follows its own evidence, so the region's mean change is the data's; by the
    end, a region Gaussian that the views barely showed has been pulled to that change rather
    than left half-way (a back tooth), and one whose pixels mix with a neighbour's (a mouth
    corner's skin over the dark inside of the mouth) keeps its darkness in ratio. Held at full
    weight from the start it pulled the first movers back towards the unmoved (an earlier form
    of the prior, at 1e-4: black teeth 22.3 -> 19.2 dB, against 22.8 with the ramp)."""
    ramp = jnp.minimum(1.0, step.astype(jnp.float32) / config.lr_decay_steps)
    return jnp.float32(config.coherence_weight) * ramp


def base_colour(colors: jax.Array) -> jax.Array:
    """(N, 3) RGB of (N, 3) plain RGB colours, or of (N, K, 3) SH's degree-0 band."""
    return colors if colors.ndim == 2 else jnp.maximum(sh.dc_to_rgb(colors[:, 0]), 0.0)


def make_edit_step(config: StepConfig):
    """A jitted `step(state, rig, batch, editable) -> (state, metrics)`, state donated.

    batch: cams (B,) int32, frames (B,) int32 (rows of rig.vertices), target (B, H, W, 3) float
    (E_t), neighbour (B, H, W, 3) (E_k). editable: (N,) bool, the edit region's Gaussians: the
    others receive no gradient and no update, so no parameter outside the region moves.
    """
    disc = gan.Discriminator()
    opt, d_opt = avatar_optimizer(config), discriminator_optimizer(config)
    mouth_ids = jnp.asarray([head.REGION_ID[r] for r in MOUTH_REGIONS])
    front = CODE_MASK_CONTRIBUTORS if config.gradient_mask == "code" else 0

    def render_one(params, rig, cam, frame):
        out = render_bound(params, rig, frame, cam, blend=config.blend,
                           visibility_contributors=front)
        return out.image, (out.stats.radii > 0, out.stats.visibility)

    def step(state: EditState, rig: Rig, batch: dict, editable: jax.Array):
        def render_batch(params):
            return jax.vmap(render_one, in_axes=(None, None, 0, 0))(params, rig, batch["cams"],
                                                                      batch["frames"])

        images, pullback, (visible, visibility) = jax.vjp(render_batch, state.params,
                                                          has_aux=True)
        target, neighbour = batch["target"], batch["neighbour"]
        d_params, d_opt_state = state.d_params, state.d_opt_state
        d_value = jnp.float32(0.0)
        if config.adversarial:
            real, fake = (gan.downscale(x, config.gan_max_side) for x in gan.make_pairs(
                config.pair_mode, target, neighbour, jax.lax.stop_gradient(images)))

            def d_objective(p):
                return config.d_weight * gan.d_loss(disc.apply(p, real), disc.apply(p, fake))

            d_value, d_grads = jax.value_and_grad(d_objective)(d_params)
            with jax.numpy_dtype_promotion("standard"):
                d_updates, d_opt_state = d_opt.update(d_grads, d_opt_state, d_params)
            d_params = optax.apply_updates(d_params, d_updates)

        def image_objective(imgs):
            recon = jnp.mean(jax.vmap(lambda c, e: _reconstruction(config, c, e))(imgs, target))
            adv = jnp.float32(0.0)
            if config.adversarial:
                _, fake = gan.make_pairs(config.pair_mode, target, neighbour, imgs)
                adv = gan.g_loss(disc.apply(d_params, gan.downscale(fake, config.gan_max_side)))
            return config.recon_weight * recon + config.g_weight * adv, (recon, adv)

        (_, (recon, adv)), d_images = jax.value_and_grad(image_objective, has_aux=True)(images)
        (grads,) = pullback(d_images)
        seen = jnp.any(visible, axis=0)

        def const_objective(p):
            value = config.const_weight * (losses.position_regulariser(p["means"], seen)
                                           + losses.scale_regulariser(p["log_scales"], seen))
            if config.coherence_weight > 0:
                value = value + coherence_weight(config, state.step) * losses.change_coherence(
                    base_colour(p["colors"]), state.origin, editable, rig.regions,
                    len(head.REGIONS))
            return value

        const, const_grads = jax.value_and_grad(const_objective)(state.params)
        grads = jax.tree_util.tree_map(jnp.add, grads, const_grads)
        if config.gradient_mask == "code":
            # The released code updates only Gaussians among a pixel's front contributors and
            # never the mouth's; every attribute of the others is frozen alike.
            keep = (jnp.max(visibility, axis=0) > 0) & ~jnp.isin(rig.regions, mouth_ids)
            grads = _masked(grads, keep)
        grads = _masked(grads, editable)
        with jax.numpy_dtype_promotion("standard"):
            updates, opt_state = opt.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        if params["colors"].ndim == 2:  # plain RGB: keep it a colour (no compensating overshoot)
            params = dict(params, colors=jnp.clip(params["colors"], 0.0, 1.0))
        # Adam's momentum would carry a Gaussian that left an `auto` region on moving.
        params = {k: jnp.where(_column(editable, v), v, state.params[k])
                  for k, v in params.items()}
        psnr = jnp.mean(jax.vmap(losses.psnr)(images, target))
        metrics = dict(recon=recon, g_adv=adv, d_loss=d_value, const=const, psnr_to_edit=psnr)
        step = state.step + 1
        average = average_params(state.average, params, step, config.average_decay)
        return EditState(params, opt_state, d_params, d_opt_state, step, average,
                         state.origin), metrics

    return fast_jit(step, donate_argnums=0)


def _reconstruction(config: StepConfig, image: jax.Array, target: jax.Array) -> jax.Array:
    """L1 + ssim_weight (1 - SSIM) of one (H, W, 3) image. At weight 0 the SSIM is not traced:
    XLA keeps `0 * x` (it is NaN where x is), and the SSIM's gradient is ~0.1 s of an
    iteration at 512 px."""
    value = losses.l1(image, target)
    if config.ssim_weight:
        value = value + config.ssim_weight * (1 - losses.ssim(image, target))
    return value


def _column(mask, like):
    return mask.reshape((-1,) + (1,) * (like.ndim - 1))


def _masked(tree: dict, mask) -> dict:
    """Per-Gaussian arrays zeroed where the (N,) bool mask is False."""
    return {k: v * _column(mask, v).astype(v.dtype) for k, v in tree.items()}


class Preview(NamedTuple):
    """What the 2D editor and the composite read of one view, from one composite pass.

    image: (H, W, 3); regions: (H, W) int region label (the region of the largest composited
    weight, -1 where alpha <= 1/2); coords, normals: (H, W, 3) head-space position and unit
    normal (alpha-normalised); alpha: (H, W) the avatar's coverage.
    """

    image: jax.Array
    regions: jax.Array
    coords: jax.Array
    normals: jax.Array
    alpha: jax.Array


def make_preview(blend: wabe.Blend):
    """Jitted `preview(params, rig, cam, frame, canonical) -> Preview` in one composite pass.

    canonical: (N, 6) each Gaussian's head-space position and normal (the rest pose)."""
    num_regions = len(head.REGIONS)

    @fast_jit
    def preview_frame(params, rig: Rig, cam, canonical):
        onehot = jax.nn.one_hot(rig.regions, num_regions, dtype=canonical.dtype)
        out = render_bound(params, rig, 0, cam, blend=blend,
                           extra_channels=jnp.concatenate([onehot, canonical], -1))
        votes = out.image[..., 3:3 + num_regions]
        regions = jnp.where(out.alpha > 0.5, jnp.argmax(votes, -1), -1)
        coords = out.image[..., 3 + num_regions:6 + num_regions] / jnp.maximum(
            out.alpha, 1e-6)[..., None]
        normals = out.image[..., 6 + num_regions:9 + num_regions]
        normals = normals / jnp.maximum(jnp.linalg.norm(normals, axis=-1, keepdims=True), 1e-6)
        return Preview(out.image[..., :3], regions, coords, normals, out.alpha)

    def preview(params, rig: Rig, cam, frame, canonical):
        return preview_frame(params, one_frame(rig, frame), cam, canonical)

    preview.jitted = preview_frame  # compiled once for rigs of any length (`rig.one_frame`)
    return preview
