"""NeRSemble / GaussianAvatars layout: our scene written and read back gives the same data."""

import json
import os

import numpy as np
import pytest

from gae_jax.scene import nersemble, synthetic


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    scene = synthetic.make_synthetic_scene(size=24, num_cameras=9, frames_per_sequence=3,
                                      cache_dir=str(tmp_path_factory.mktemp("cache")),
                                      progress=False)
    folder = str(tmp_path_factory.mktemp("subject"))
    counts = nersemble.export_scene(scene, folder)
    return scene, folder, counts


def test_splits_have_the_expected_sizes(exported):
    scene, folder, counts = exported
    train_frames = 3 * len(synthetic.TRAIN_SEQUENCES)
    assert counts == dict(train=train_frames * 8, val=train_frames, test=3 * 8)
    for split in ("train", "val", "test"):
        assert os.path.isfile(os.path.join(folder, f"transforms_{split}.json"))
    assert os.path.isfile(os.path.join(folder, "canonical_flame_param.npz"))


def test_round_trip_gives_the_same_cameras_params_and_images(exported):
    scene, folder, _ = exported
    names = [n for n, s in scene.sequences.items() if s.identity == "A"]
    timesteps = [(n, t) for n in names for t in range(scene.sequences[n].num_frames)]
    for split in ("train", "val", "test"):
        for fr in nersemble.load_split(folder, split)[::5]:
            np.testing.assert_allclose(fr.w2c, scene.w2c[fr.camera], atol=1e-5)
            np.testing.assert_allclose(fr.intrinsics, scene.intrinsics[fr.camera], atol=1e-4)
            name, t = timesteps[fr.timestep]
            seq = scene.sequences[name]
            p = nersemble.load_flame_param(fr.flame_param_path)
            np.testing.assert_allclose(p["jaw_pose"][0], seq.jaw[t], atol=1e-6)
            np.testing.assert_allclose(p["expr"][0], seq.expr[t], atol=1e-6)
            np.testing.assert_allclose(p["rotation"][0], seq.rotation[t], atol=1e-6)
            np.testing.assert_array_equal(nersemble.read_image(fr.image_path),
                                          scene.images[name][fr.camera, t])
            mask = nersemble.read_image(fr.mask_path)
            np.testing.assert_array_equal(mask > 0, scene.regions[name][fr.camera, t] >= 0)
    val_cams = {fr.camera for fr in nersemble.load_split(folder, "val")}
    assert val_cams == set(scene.held_out_cameras)


def test_malformed_files_are_named(exported, tmp_path):
    _, folder, _ = exported
    with open(os.path.join(folder, "transforms_train.json"), encoding="utf-8") as f:
        meta = json.load(f)
    del meta["frames"][0]["transform_matrix"]
    bad = tmp_path / "transforms_train.json"
    bad.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="transform_matrix"):
        nersemble.load_split(str(tmp_path), "train")
    np.savez(tmp_path / "p.npz", translation=np.zeros((1, 3)), rotation=np.zeros((1, 3)),
             neck_pose=np.zeros((1, 3)), jaw_pose=np.full((1, 3), np.nan),
             eyes_pose=np.zeros((1, 6)), shape=np.zeros(3), expr=np.zeros((1, 6)))
    with pytest.raises(ValueError, match="jaw_pose.*NaN"):
        nersemble.load_flame_param(str(tmp_path / "p.npz"))
    with pytest.raises(ValueError, match="unreadable image"):
        nersemble.read_image(str(tmp_path / "missing.png"))


def test_a_captures_labels_are_its_tracked_mesh_projected_into_each_view(exported):
    """Read back as a capture (no region labels of its own, only foreground masks), the scene's
    training labels are ray-cast from its posed mesh: the synthetic scene's own labels, which
    are that projection, at every pixel but the few whose centre ray grazes an edge; a
    subsampled grid is every stride-th pixel of it."""
    from gae_jax.model import head
    from gae_jax.scene import types

    scene, folder, _ = exported
    model, assets = head.make_head("procedural")
    capture = nersemble.load_scene(folder, model, assets.face_regions)
    assert capture.kind == "capture"
    projected = types.training_labels(capture)
    expected = types.training_labels(scene)[np.asarray(capture.train_cameras)]
    mine = projected[np.asarray(capture.train_cameras)]
    assert mine.shape == expected.shape
    assert np.mean(mine == expected) > 0.995
    assert set(np.unique(mine)) <= set(range(-1, len(head.REGIONS)))
    coarse = types.training_labels(capture, stride=2)
    np.testing.assert_array_equal(coarse, projected[..., ::2, ::2])


def test_a_captures_label_samples_are_its_tracked_mesh_projected_along_each_ray(exported):
    """The capture's label samples (4 rays per pixel, ray-cast from its posed mesh) are the
    synthetic scene's stored samples (its 2 x 2 colour rays' regions) at every ray but those
    that miss the mesh inside a foreground pixel, which a capture cannot tell from hair the
    mesh does not model (unknown); the fit reads a capture's centre labels (one per pixel),
    and a scene without stored samples falls back to its centre labels too."""
    import dataclasses

    from gae_jax.model import head
    from gae_jax.scene import types

    scene, folder, _ = exported
    model, assets = head.make_head("procedural")
    capture = nersemble.load_scene(folder, model, assets.face_regions)
    cams = np.asarray(capture.train_cameras)
    mine = types.projected_label_samples(capture, types.training_frames(capture), cams)
    expected = types.projected_label_samples(scene, types.training_frames(scene), cams)
    assert mine.shape == expected.shape and mine.shape[-1] == types.LABEL_SUPERSAMPLE ** 2
    known = mine != types.UNKNOWN_REGION
    np.testing.assert_array_equal(mine[known], expected[known])
    assert np.all(expected[~known] == -1) and np.mean(~known) < 0.02
    edge = (expected != expected[..., :1]).any(-1)
    assert edge.any()  # some pixels are shared by regions, and the samples say so
    # the fit's labels of a capture's many views: one per pixel
    np.testing.assert_array_equal(types.training_label_samples(capture),
                                  types.training_labels(capture)[..., None])
    bare = dataclasses.replace(scene, region_samples={})
    np.testing.assert_array_equal(types.training_label_samples(bare),
                                  types.training_labels(scene)[..., None])
