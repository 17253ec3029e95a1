"""Reconstruction: the fit learns, densify/prune keeps optimiser state with its Gaussian,
checkpoints resume to the same result, SH bands grow on schedule."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax import reconstruct
from gae_jax.fit import densify, step
from gae_jax.fit.config import FitStepConfig, ReconstructConfig
from gae_jax.fit.fit import fit, initial_avatar
from gae_jax.model import avatar as av
from gae_jax.render import splat
from gae_jax.scene import rig as rigs
from gae_jax.scene import synthetic
from gae_jax.model import head
from gae_jax.scene.types import posed_vertices, training_frames


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return synthetic.make_synthetic_scene(size=32, num_cameras=9, frames_per_sequence=2,
                                     cache_dir=str(tmp_path_factory.mktemp("c")), progress=False)


def test_fit_lowers_the_photometric_loss(scene):
    config = ReconstructConfig(iterations=120, seed=1)
    fitted, history = fit(scene, config)
    photo = np.array([h["photometric"] for h in history])
    assert len(history) == 120 and np.all(np.isfinite(photo))
    assert photo[-30:].mean() < 0.7 * photo[:10].mean(), (photo[:10].mean(), photo[-30:].mean())
    assert max(h["overflow_tiles"] for h in history) == 0
    assert fitted.num == int(np.asarray(fitted.binding).shape[0]) > 0


def test_a_fit_from_the_default_initial_avatar_is_the_default_fit(scene):
    config = ReconstructConfig(iterations=3, seed=4)
    given = initial_avatar(scene, config, jax.random.split(jax.random.PRNGKey(4))[1])
    default, _ = fit(scene, config)
    started, _ = fit(scene, config, initial=given)
    for a, b in zip(jax.tree_util.tree_leaves(default), jax.tree_util.tree_leaves(started)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_fit_continues_from_a_denser_avatar_and_keeps_its_binding(scene):
    config = ReconstructConfig(iterations=2)
    base = initial_avatar(scene, config, jax.random.PRNGKey(0))
    first = np.arange(base.num) < 50
    denser = av.densify(base, first, np.zeros(base.num, bool), jax.random.PRNGKey(1))
    fitted, history = fit(scene, config, initial=denser)
    assert fitted.num == base.num + 50 == history[-1]["num_gaussians"]
    np.testing.assert_array_equal(np.asarray(fitted.binding), np.asarray(denser.binding))
    with pytest.raises(ValueError, match="sh_degree"):
        fit(scene, ReconstructConfig(iterations=1, sh_degree=1), initial=denser)


class Interrupt(Exception):
    pass


def test_resume_after_a_crash_equals_the_uninterrupted_run(scene, tmp_path):
    config = ReconstructConfig(iterations=20, checkpoint_every=10, densify_every=10,
                                           densify_from=10, densify_until=0.9,
                                           grad_threshold=1e-6, seed=2)
    full, full_history = fit(scene, config, checkpoint_dir=str(tmp_path / "a"))

    def crash(i, metrics):
        if i == 15:
            raise Interrupt

    with pytest.raises(Interrupt):
        fit(scene, config, progress_fn=crash, checkpoint_dir=str(tmp_path / "b"))
    resumed, history = fit(scene, config, checkpoint_dir=str(tmp_path / "b"),
                                       resume=True)
    assert resumed.num == full.num
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(history) == len(full_history) == 20
    np.testing.assert_allclose([h["loss"] for h in history], [h["loss"] for h in full_history])
    counts = {h["num_gaussians"] for h in full_history}
    assert len(counts) > 1, "densify / prune changed the Gaussian count during the fit"
    other = ReconstructConfig(iterations=21, checkpoint_every=10)
    with pytest.raises(ValueError, match="different ReconstructConfig"):
        fit(scene, other, checkpoint_dir=str(tmp_path / "b"), resume=True)


def test_densify_and_prune_carry_adam_moments_with_each_gaussian(scene):
    config = ReconstructConfig(grad_threshold=0.5)  # prune_unseen: faces may empty
    fixed = initial_avatar(scene, config, jax.random.PRNGKey(0))
    params = fixed.trainable()
    opt = step.optimizer(FitStepConfig.of(config))
    n = fixed.num
    # Moments that identify each Gaussian: mu = index.
    state = opt.init(params)
    state = jax.tree_util.tree_map(
        lambda x: jnp.broadcast_to(jnp.arange(n, dtype=x.dtype).reshape((n,) + (1,) * (x.ndim - 1)),
                                   x.shape) if x.ndim and x.shape[0] == n else x, state)
    grad_sum = jnp.zeros(n).at[:5].set(1.0)  # the first five are densified
    seen = jnp.ones(n, jnp.int32)
    logits = params["opacity_logits"].at[10:13].set(-20.0)  # three nearly transparent
    params = dict(params, opacity_logits=logits)
    fit_state = step.FitState(params, state, jax.random.PRNGKey(1), jnp.int32(0),
                                     grad_sum, seen)
    new, new_fixed = densify.densify_and_prune(fit_state, fixed, config,
                                               scene.model.faces.shape[0])
    assert new_fixed.num == n + 5 - 3
    means_moment = [x for x in jax.tree_util.tree_leaves(new.opt_state)
                    if x.ndim == 2 and x.shape == (new_fixed.num, 3)][0]
    origin = np.asarray(means_moment[:, 0]).astype(int)
    np.testing.assert_array_equal(np.asarray(new_fixed.binding),
                                  np.asarray(fixed.binding)[origin])
    assert not set(range(10, 13)) & set(origin.tolist())
    assert np.asarray(new.grad_sum).sum() == 0 and new.grad_sum.shape == (new_fixed.num,)


def test_sh_mask_keeps_bands_up_to_the_degree():
    np.testing.assert_array_equal(np.asarray(step.sh_mask((5, 16, 3), 1))[:, 0],
                                  [1, 1, 1, 1] + [0] * 12)
    np.testing.assert_array_equal(np.asarray(step.sh_mask((5, 9, 3), 2))[:, 0], [1] * 9)
    np.testing.assert_array_equal(np.asarray(step.sh_mask((5, 16, 3), 0))[:, 0],
                                  [1] + [0] * 15)


def test_capacity_from_tile_load_leaves_no_tile_overflowing(scene):
    from gae_jax.model import avatar as av

    model = scene.model
    config = ReconstructConfig()
    a = initial_avatar(scene, config, jax.random.PRNGKey(0))
    g = av.deform(a, model.v_template, model.faces)
    camera = scene.camera(0)
    load = int(splat.tile_load(g, camera))
    full = splat.render(g, camera, tile_capacity=load)
    short = splat.render(g, camera, tile_capacity=load - 1)
    assert int(full.stats.overflow_tiles) == 0 and int(short.stats.overflow_tiles) >= 1
    rig = rigs.put_rig(scene, a, model.v_template[None], tile_capacity=1)
    assert rigs.required_capacity(a.trainable(), rig, [0]) >= load


def test_a_fit_step_keeps_plain_colours_in_the_unit_range(scene):
    # A white target and a colour rate of 0.5 push seen colours from 0.95 far past 1 in one
    # Adam step; the step clips them, and leaves unseen ones where they were.
    config = ReconstructConfig(lr_colors=0.5, region_weight=0.0)
    fixed = initial_avatar(scene, config, jax.random.PRNGKey(0))
    params = dict(fixed.trainable(), colors=jnp.full((fixed.num, 3), 0.95, jnp.float32))
    vertices = np.asarray(scene.model.v_template)[None]
    rig = rigs.put_rig(scene, fixed, vertices)
    white = jnp.full((scene.num_cameras, 1, scene.height, scene.width, 3), 255, jnp.uint8)
    fit_step = step.make_fit_step(FitStepConfig.of(config))
    state = step.initial_state(params, FitStepConfig.of(config), jax.random.PRNGKey(2))
    no_labels = jnp.zeros((1, 1, 1, 1, 1), jnp.int8)
    state, _ = fit_step(state, rig, white, no_labels,
                        jnp.arange(scene.num_cameras, dtype=jnp.int32))
    colors = np.asarray(state.params["colors"])
    assert colors.max() == 1.0 and colors.min() >= 0.0
    assert (colors == 1.0).any(axis=1).sum() > 10 and (colors == np.float32(0.95)).any()


def test_the_region_loss_teaches_each_pixel_its_region(scene):
    """The same fit with and without the region loss: with it, the rendered regions match the
    training views' projected labels far better, for a small photometric cost."""
    import jax.numpy as jnp

    from gae_jax.render import losses
    from gae_jax.scene.types import training_label_samples

    results = {}
    for weight in (0.0, 0.3):
        fitted, history = fit(scene, ReconstructConfig(iterations=150, seed=2,
                                                        region_weight=weight, unseen_weight=0.0))
        rig = rigs.put_rig(scene, fitted, posed_vertices(scene, training_frames(scene)))
        labels = jnp.asarray(training_label_samples(scene))
        codes = losses.region_codes(len(head.REGIONS))
        onehot = jnp.asarray(codes)[rig.regions + 1]
        region, photo = [], []
        for cam in scene.train_cameras[:4]:
            for frame in range(0, rig.vertices.shape[0], 3):
                out = rigs.render_bound(fitted.trainable(), rig, frame, cam,
                                        extra_channels=onehot)
                region.append(float(losses.region_loss(out.image[..., 3:],
                                                       labels[cam, frame], codes)))
        photo = np.mean([h["photometric"] for h in history[-30:]])
        results[weight] = (np.mean(region), photo)
    (r0, p0), (r1, p1) = results[0.0], results[0.3]
    assert r1 < 0.75 * r0, results
    assert p1 < 1.25 * p0, results
