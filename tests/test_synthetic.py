"""The synthetic scene: splits, identities, determinism, caching, and ground truth that sees teeth."""

import os

import numpy as np
import pytest

from gae_jax.scene import synthetic
from gae_jax.model import head
from tests.helpers import near

SMALL = dict(size=40, num_cameras=9, frames_per_sequence=6, progress=False)



@pytest.fixture(scope="module")
def scene_and_dir(tmp_path_factory):
    cache = str(tmp_path_factory.mktemp("cache"))
    return synthetic.make_synthetic_scene(cache_dir=cache, **SMALL), cache


def test_splits_cameras_and_identities(scene_and_dir):
    scene, _ = scene_and_dir
    assert scene.held_out_cameras == (synthetic.HELD_OUT_CAMERA,)
    assert set(scene.train_cameras) == set(range(9)) - {synthetic.HELD_OUT_CAMERA}
    splits = {s.name: (s.identity, s.split) for s in scene.sequences.values()}
    assert all(splits[n] == ("A", "train") for n in synthetic.TRAIN_SEQUENCES)
    assert splits[synthetic.HELD_OUT_SEQUENCE] == ("A", "self_reenactment")
    assert splits[synthetic.CROSS_SEQUENCE] == ("B", "cross_identity")
    assert not np.allclose(scene.shapes["A"], scene.shapes["B"])
    assert np.abs(scene.vertex_colors["A"] - scene.vertex_colors["B"]).max() > 0.1
    for name, img in scene.images.items():
        assert img.shape == (9, 6, 40, 40, 3) and img.dtype == np.uint8
        assert scene.regions[name].shape == (9, 6, 40, 40)
    cams = np.asarray(scene.w2c)
    centres = np.einsum("cji,cj->ci", cams[:, :3, :3], -cams[:, :3, 3])
    assert np.all(centres[:, 2] > 0), "all cameras on the frontal hemisphere"


def test_background_pixels_are_background_and_regions_cover_the_head(scene_and_dir):
    scene, _ = scene_and_dir
    img, reg = scene.images["talk"], scene.regions["talk"]
    # Anti-aliased edges blend into the background only next to the head.
    np.testing.assert_array_equal(img[~near(reg >= 0)], 255)
    assert (img[(reg < 0) & near(reg >= 0)] < 255).any()
    assert (reg >= 0).mean() > 0.2
    present = set(np.unique(reg)) - {-1}
    assert {head.REGION_ID[r] for r in ("skin", "hair", "lips", "iris")} <= present


def test_open_jaw_shows_teeth_closed_does_not(scene_and_dir):
    scene, _ = scene_and_dir
    teeth = head.REGION_ID["teeth"]
    jaw = scene.sequences["jaw"]
    front = synthetic.HELD_OUT_CAMERA
    counts = [(scene.regions["jaw"][front, t] == teeth).sum() for t in range(jaw.num_frames)]
    assert counts[0] == 0 and max(counts) > 0
    widest = int(np.argmax(jaw.jaw[:, 0]))
    assert counts[widest] == max(counts)


def test_second_build_comes_from_the_cache_and_is_identical(scene_and_dir):
    scene, cache = scene_and_dir
    files = os.listdir(cache)
    assert len(files) == 1 and files[0].startswith("scene-") and files[0].endswith(".npz")
    again = synthetic.make_synthetic_scene(cache_dir=cache, **SMALL)
    for name in scene.images:
        np.testing.assert_array_equal(again.images[name], scene.images[name])
    other = dict(SMALL, background="black")
    assert synthetic._cache_key(dict(size=40)) != synthetic._cache_key(dict(size=41))
    with pytest.raises(ValueError, match="background"):
        synthetic.make_synthetic_scene(cache_dir=cache, **dict(other, background="grey"))


def test_render_frame_with_edited_colours_changes_only_that_region(scene_and_dir):
    scene, _ = scene_and_dir
    model, assets = head.make_head()
    seq = scene.sequences["talk"]
    colours = scene.vertex_colors["A"].copy()
    faces = np.asarray(model.faces)
    lip_vertices = np.unique(faces[assets.face_regions == head.REGION_ID["lips"]])
    colours[lip_vertices] = (0.1, 0.2, 0.9)
    img, reg = synthetic.render_frame(model, assets.face_regions, colours, scene.shapes["A"], seq, 2,
                                 scene.intrinsics, scene.w2c, 40, scene.background,
                                 supersample=2)  # the scene default
    original = scene.images["talk"][:, 2]
    changed = np.abs(img.astype(int) - original.astype(int)).max(-1) > 2
    np.testing.assert_array_equal(reg, scene.regions["talk"][:, 2])
    lips = reg == head.REGION_ID["lips"]
    assert changed[lips].mean() > 0.9 and not changed[~near(lips)].any()
    unedited, _ = synthetic.render_frame(model, assets.face_regions, scene.vertex_colors["A"],
                                    scene.shapes["A"], seq, 2, scene.intrinsics, scene.w2c, 40,
                                    scene.background, supersample=2)  # the scene default
    np.testing.assert_array_equal(unedited, original)


def test_the_makehuman_scene_drives_face_units_and_shows_the_tongue_only_when_held_out(
        tmp_path):
    scene = synthetic.make_synthetic_scene(cache_dir=str(tmp_path), head_kind="makehuman",
                                           size=32, num_cameras=9, frames_per_sequence=8,
                                           progress=False)
    _, assets = head.make_head("makehuman")
    tongue = assets.expr_names.index("tongueOut")
    for name, seq in scene.sequences.items():
        assert seq.expr.shape == (8, len(assets.expr_names))
        assert (np.abs(seq.expr[:, tongue]).max() > 0) == (name == synthetic.HELD_OUT_SEQUENCE)
    assert not np.allclose(scene.shapes["A"], scene.shapes["B"])
    skin = np.unique(np.asarray(scene.model.faces)[assets.face_regions == head.REGION_ID["skin"]])
    ratio = scene.albedo["B"][skin] / np.maximum(scene.albedo["A"][skin], 1e-6)
    # B's skin is A's rescaled by one colour (the blush kept).
    np.testing.assert_allclose(ratio, np.broadcast_to(ratio[:1], ratio.shape), rtol=1e-5)
    assert ratio[0].max() < 0.8
    seen = {name: set(np.unique(r)) for name, r in scene.regions.items()}
    assert head.REGION_ID["tongue"] in seen[synthetic.HELD_OUT_SEQUENCE]
    with pytest.raises(ValueError, match="unknown head"):
        synthetic.make_synthetic_scene(cache_dir=str(tmp_path), head_kind="robot", size=16)


def test_the_scene_config_names_the_heads_and_the_head_poses_user_data_without_flame():
    from gae_jax.scene.load import SceneConfig, load_model

    with pytest.raises(ValueError, match="--head takes procedural or makehuman"):
        SceneConfig(head="robot")
    assert SceneConfig().head == head.DEFAULT_KIND == "makehuman"
    for kind in head.HEAD_KINDS:
        model, regions = load_model(head_kind=kind)
        own, assets = head.make_head(kind)
        np.testing.assert_array_equal(np.asarray(model.faces), np.asarray(own.faces))
        np.testing.assert_array_equal(regions, assets.face_regions)
