"""The edit region: tracing votes equal a brute-force per-pixel weighting, coverage equals the
brute-force alpha of the selected Gaussians, the masks and the composite have their closed
forms, and the flag's spellings resolve (or fail) clearly."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.edit import region
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import initial_avatar
from gae_jax.model import avatar as av
from gae_jax.model import head
from gae_jax.render import splat
from gae_jax.scene import rig as rigs
from gae_jax.scene import synthetic
from gae_jax.scene.types import posed_vertices, training_frames
from tests import bruteforce

# float32 compositor vs the float64 brute force, summed over ~1000 pixels.
VOTE_TOLERANCE = 2e-3


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 64 px scene and 40 Gaussians of the lips and the skin around them."""
    scene = synthetic.make_synthetic_scene(size=64, num_cameras=3, frames_per_sequence=2,
                                           cache_dir=str(tmp_path_factory.mktemp("c")),
                                           progress=False)
    full = initial_avatar(scene, ReconstructConfig(), jax.random.PRNGKey(0))
    labels = np.asarray(full.regions)
    pick = np.concatenate([np.flatnonzero(labels == head.REGION_ID["lips"])[:25],
                           np.flatnonzero(labels == head.REGION_ID["skin"])[:15]])
    avatar = jax.tree_util.tree_map(lambda x: x[pick], full)
    avatar = dataclasses.replace(avatar, opacity_logits=jnp.full((avatar.num,), 1.0))
    rig = rigs.put_rig(scene, avatar, posed_vertices(scene, training_frames(scene)[:1]),
                       tile_capacity=64)
    return scene, avatar, rig


def _weights(avatar, rig, cam):
    """(H, W, N) standard blending weight of every Gaussian at every pixel, brute force: the
    render of one-hot colours."""
    g = rigs.gaussians_at(avatar.trainable(), rig, 0)
    g = dataclasses.replace(g, colors=jnp.eye(avatar.num))
    image, _, _ = bruteforce.render(g, rig.camera(cam))
    return image


def test_tracing_votes_are_the_masked_sums_of_blending_weights(small):
    scene, avatar, rig = small
    cam = 1
    weights = _weights(avatar, rig, cam)
    assert weights.sum() > 10  # the Gaussians are in view
    change = (np.random.default_rng(0).random((rig.height, rig.width)) > 0.5).astype(np.float32)
    votes = np.asarray(region.make_tracer()(avatar.trainable(), rig, jnp.int32(cam),
                                            jnp.int32(0), jnp.asarray(change)))
    np.testing.assert_allclose(votes[:, 0], np.einsum("hwn,hw->n", weights, change),
                               atol=VOTE_TOLERANCE, rtol=1e-3)
    np.testing.assert_allclose(votes[:, 1], weights.sum((0, 1)), atol=VOTE_TOLERANCE,
                               rtol=1e-3)


def test_coverage_is_the_bruteforce_alpha_of_the_selected_gaussians(small):
    scene, avatar, rig = small
    selected = np.asarray(avatar.regions) == head.REGION_ID["lips"]
    cover = np.asarray(region.make_coverage()(avatar.trainable(), rig, jnp.int32(1),
                                              jnp.int32(0), jnp.asarray(selected)))
    expected = _weights(avatar, rig, 1)[..., selected].sum(-1)
    assert expected.max() > 0.5
    np.testing.assert_allclose(cover, expected, atol=1e-4)


@pytest.mark.parametrize("blend", ["standard", "wabe_grad"])
def test_preview_channels_are_the_bruteforce_composites(small, blend):
    """The preview's one pass: the plain image, the head-space position (alpha-normalised),
    the normal (normalised) and the region of the largest weight, each the brute-force
    weighted sum of the Gaussians' values."""
    from gae_jax.edit.step import make_preview
    from gae_jax.render import wabe

    scene, avatar, rig = small
    rng = np.random.default_rng(0)
    positions = rng.normal(size=(avatar.num, 3)).astype(np.float32)
    normals = rng.normal(size=(avatar.num, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    view = make_preview(wabe.named(blend))(avatar.trainable(), rig, jnp.int32(1), jnp.int32(0),
                                           jnp.asarray(np.concatenate([positions, normals], 1)))
    w = _weights(avatar, rig, 1)
    alpha = w.sum(-1)
    covered = alpha > 0.5
    assert covered.sum() > 10
    np.testing.assert_allclose(np.asarray(view.alpha), alpha, atol=1e-4)
    np.testing.assert_allclose(np.asarray(view.coords)[covered],
                               (w @ positions / alpha[..., None])[covered], atol=2e-3)
    n = w @ normals
    np.testing.assert_allclose(np.asarray(view.normals)[covered],
                               (n / np.linalg.norm(n, axis=-1, keepdims=True))[covered],
                               atol=2e-3)
    onehot = np.eye(len(head.REGIONS))[np.asarray(avatar.regions)]
    expected = np.where(covered, np.argmax(w @ onehot, -1), -1)
    np.testing.assert_array_equal(np.asarray(view.regions), expected)
    plain = rigs.render_bound(avatar.trainable(), rig, 0, 1, blend=wabe.standard()).image
    np.testing.assert_allclose(np.asarray(view.image), np.asarray(plain), atol=1e-5)


def test_a_rig_renders_with_the_screen_filter_it_carries(small):
    """The rig carries the avatar's screen filter (static): every render through it uses it."""
    scene, avatar, rig = small
    wide = rigs.put_rig(scene, avatar, posed_vertices(scene, training_frames(scene)[:1]),
                        tile_capacity=64, screen_filter=0.3)
    assert rig.screen_filter == 0.1 and wide.screen_filter == 0.3
    g = rigs.gaussians_at(avatar.trainable(), rig, 0)
    for r in (rig, wide):
        through_rig = rigs.render_bound(avatar.trainable(), r, 0, 1).image
        direct = splat.render(g, r.camera(1), background=r.background, tile_capacity=64,
                              tiles_per_chunk=rigs.TILES_PER_CHUNK,
                              screen_filter=r.screen_filter).image
        np.testing.assert_array_equal(np.asarray(through_rig), np.asarray(direct))
    assert not np.allclose(np.asarray(rigs.render_bound(avatar.trainable(), rig, 0, 1).image),
                           np.asarray(rigs.render_bound(avatar.trainable(), wide, 0, 1).image))


def test_selection_is_a_mean_vote_above_one_half():
    votes = np.array([[0.6, 1.0], [0.5, 1.0], [0.0, 0.0], [3.0, 4.0], [1e-9, 1e-9]])
    np.testing.assert_array_equal(region.select(votes), [True, False, False, True, True])


def test_parse_region_resolves_names_the_prompt_and_refuses_unknowns():
    assert region.parse_region("none") == ("none",)
    assert region.parse_region("Auto") == ("auto",)
    assert region.parse_region("hair, brows") == ("hair", "brows")
    assert region.parse_region("prompt", "turn the lips blue") == ("lips",)
    assert region.parse_region("prompt", "make it an oil painting") == ("auto",)
    with pytest.raises(ValueError, match="unknown region nose; --region takes none, auto, prompt"):
        region.parse_region("lips,nose")
    labels = np.array([head.REGION_ID[n] for n in ("skin", "lips", "hair", "lips")])
    np.testing.assert_array_equal(region.named_selection(labels, ("lips",)),
                                  [False, True, False, True])


def test_change_mask_sees_a_changed_patch_and_ignores_a_lone_pixel():
    before = np.full((20, 20, 3), 0.5, np.float32)
    after = before.copy()
    after[5:10, 5:10, 2] = 1.0  # a 5x5 patch changes by 0.5
    after[15, 15] = 0.8  # one pixel by 0.3: its 3x3 mean is 0.033
    mask = region.change_mask(after, before, 0.1)
    assert mask[6:9, 6:9].all() and not mask[15, 15] and not mask[0:3].any()


def test_soft_mask_grows_by_the_dilation_and_composite_is_the_convex_mix():
    cover = np.zeros((21, 21), np.float32)
    cover[10, 10] = 1.0
    sharp = region.soft_mask(cover, dilate=2, blur=0)
    np.testing.assert_array_equal(np.argwhere(sharp > 0).min(0), [8, 8])
    np.testing.assert_array_equal(np.argwhere(sharp > 0).max(0), [12, 12])
    soft = region.soft_mask(cover, dilate=2, blur=1.0)
    assert soft[10, 10] == pytest.approx(1.0, abs=0.02) and 0 < soft[10, 13] < 0.5
    edit, unedited = np.ones((21, 21, 3)), np.zeros((21, 21, 3))
    np.testing.assert_allclose(region.composite(edit, unedited, soft)[..., 0], soft, atol=1e-6)


def test_named_region_protects_every_gaussian_outside_it(small):
    """Masking in the step: after edits of the lips, every non-lips parameter is bit-identical
    and the lips' colours moved."""
    from gae_jax.edit import config as edit_config
    from gae_jax.edit import edit

    scene, _, _ = small
    original = initial_avatar(scene, ReconstructConfig(), jax.random.PRNGKey(0))
    config = edit_config.preset("fast", iterations=4, checkpoint_every=0, editor_noise=0.3,
                                region="lips")
    edited, _ = edit.edit_avatar(edit.setup(config, scene, original))
    lips = np.asarray(original.regions) == head.REGION_ID["lips"]
    for name in av.TRAINABLE:
        before, after = np.asarray(getattr(original, name)), np.asarray(getattr(edited, name))
        np.testing.assert_array_equal(after[~lips], before[~lips], err_msg=name)
    moved = np.abs(np.asarray(edited.colors) - np.asarray(original.colors))[lips]
    assert moved.max() > 0.05
