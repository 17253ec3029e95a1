"""Views between the training ones, labelled by the tracked mesh: cameras and poses against closed
forms, labels against an independent ray cast, and a fit supervised by them holding region
borders in views it was never shown."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import fit
from gae_jax.model import flame, head
from gae_jax.render import losses
from gae_jax.render.camera import Camera, look_at_w2c
from gae_jax.scene import raycast, synthetic
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import LABEL_SUPERSAMPLE, UNKNOWN_REGION
from gae_jax.scene.unseen import camera_between, pose_between, unseen_views


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return synthetic.make_synthetic_scene(size=32, num_cameras=9, frames_per_sequence=2,
                                          cache_dir=str(tmp_path_factory.mktemp("c")),
                                          progress=False)


def distance_to_segment(x, p, q) -> float:
    t = np.clip(np.dot(x - p, q - p) / np.dot(q - p, q - p), 0.0, 1.0)
    return float(np.linalg.norm(x - (p + t * (q - p))))


def test_a_camera_between_two_is_each_at_the_ends_and_the_bisector_halfway():
    target = np.array([0.1, -0.2, 0.3])
    yaw = np.deg2rad(50.0)
    eye = lambda a: target + 2.0 * np.array([np.sin(a), 0.0, np.cos(a)])  # noqa: E731
    a, b = look_at_w2c(eye(-yaw), target), look_at_w2c(eye(yaw), target)
    ka, kb = np.array([100.0, 100.0, 16.0, 16.0]), np.array([120.0, 110.0, 15.0, 17.0])
    for t, want in ((0.0, a), (1.0, b)):
        k, w2c = camera_between(ka, a, kb, b, t)
        np.testing.assert_allclose(w2c, want, atol=1e-12)
    k, w2c = camera_between(ka, a, kb, b, 0.5)
    # Halfway: on the chord between the two centres, looking along the bisector at the target.
    chord = target + np.array([0.0, 0.0, 2.0 * np.cos(yaw)])
    np.testing.assert_allclose(w2c, look_at_w2c(chord, target), atol=1e-12)
    np.testing.assert_allclose(k, [110.0, 105.0, 15.5, 16.5])


def test_a_pose_between_two_mixes_them_and_stretches_the_expression():
    model, _ = head.make_head("procedural")
    zero = flame.zero_params(model)
    rng = np.random.default_rng(0)
    rand = lambda p: jax.tree_util.tree_map(  # noqa: E731
        lambda x: jnp.asarray(rng.normal(size=x.shape), jnp.float32), p)
    a, b = rand(zero), rand(zero)
    got = pose_between(a, b, 0.25, 1.2)
    for name in ("expr", "jaw", "eyes"):
        np.testing.assert_allclose(getattr(got, name), 1.2 * (0.75 * getattr(a, name)
                                                              + 0.25 * getattr(b, name)),
                                   rtol=1e-5, atol=1e-6)
    for name in ("rotation", "neck", "translation", "shape"):
        np.testing.assert_allclose(getattr(got, name), 0.75 * getattr(a, name)
                                   + 0.25 * getattr(b, name), rtol=1e-5, atol=1e-6)


def test_unseen_views_are_labelled_as_a_ray_cast_of_their_mesh_says(scene):
    views = unseen_views(scene, 3, seed=5)
    again = unseen_views(scene, 3, seed=5)
    np.testing.assert_array_equal(views.labels, again.labels)
    assert views.labels.shape == (3, scene.height, scene.width, LABEL_SUPERSAMPLE ** 2)
    for k in range(3):
        camera = Camera(intrinsics=views.intrinsics[k], w2c=views.w2c[k], width=scene.width,
                        height=scene.height)
        hit = raycast.raycast_views(views.vertices[k], np.asarray(scene.model.faces),
                                    np.zeros((views.vertices.shape[1], 3)), scene.face_regions,
                                    [camera], supersample=LABEL_SUPERSAMPLE, workers=1)[0]
        np.testing.assert_array_equal(views.labels[k],
                                      np.where(hit.samples >= 0, hit.samples, UNKNOWN_REGION))
        # The camera sits on the segment between two training cameras' centres.
        centres = [-scene.w2c[c][:3, :3].T @ scene.w2c[c][:3, 3] for c in scene.train_cameras]
        centre = -views.w2c[k][:3, :3].T @ views.w2c[k][:3, 3]
        assert min(distance_to_segment(centre, p, q) for p in centres for q in centres
                   if p is not q) < 1e-5
    assert (views.labels >= 0).any() and (views.labels == UNKNOWN_REGION).any()
    with pytest.raises(ValueError, match="count"):
        unseen_views(scene, 0, seed=0)
    with pytest.raises(ValueError, match="unseen_views"):
        ReconstructConfig(unseen_views=0)


def test_a_fit_taught_unseen_views_keeps_regions_apart_in_views_it_never_saw(scene):
    """Fitted with and without the unseen views' region loss, then scored on other unseen views
    (another seed): with it, the rendered regions match the mesh's far better there, for a small
    photometric cost in the training views."""
    held_out = unseen_views(scene, 6, seed=99)
    codes = losses.region_codes(len(head.REGIONS))
    results = {}
    for weight in (0.0, 0.5):
        fitted, history = fit(scene, ReconstructConfig(iterations=150, seed=2, region_weight=0.3,
                                                       unseen_weight=weight, unseen_views=16))
        rig = rigs.make_rig(scene.model.faces, fitted, held_out.vertices, held_out.intrinsics,
                            held_out.w2c, scene.background, scene.width, scene.height, 1)
        rig = dataclasses.replace(rig, tile_capacity=2 * max(rigs.required_capacity(
            fitted.trainable(), rigs.with_vertices(rig, held_out.vertices[k:k + 1]), [k])
            for k in range(6)))
        onehot = jnp.asarray(codes)[rig.regions + 1]
        region = []
        for k in range(held_out.labels.shape[0]):
            out = rigs.render_bound(fitted.trainable(), rig, k, k, extra_channels=onehot)
            assert int(out.stats.overflow_tiles) == 0
            region.append(float(losses.region_loss(out.image[..., 3:],
                                                   jnp.asarray(held_out.labels[k]), codes)))
        photo = np.mean([h["photometric"] for h in history[-30:]])
        results[weight] = (np.mean(region), photo)
        assert (np.array([h["unseen_region"] for h in history]) > 0).all() == (weight > 0)
    (r0, p0), (r1, p1) = results[0.0], results[0.5]
    assert r1 < 0.85 * r0, results
    assert p1 < 1.25 * p0, results


def test_unseen_views_join_the_loss_from_the_fraction_of_the_fit_asked(scene):
    _, history = fit(scene, ReconstructConfig(iterations=12, region_weight=0.3,
                                              unseen_weight=0.5, unseen_views=4,
                                              unseen_from=0.5))
    unseen = np.array([h["unseen_region"] for h in history])
    assert np.all(unseen[:6] == 0) and np.all(unseen[6:] > 0), unseen
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError, match="unseen_from"):
            ReconstructConfig(unseen_from=bad)
