"""Scene helpers: posed vertices per frame, the interpolated drive of the video, the splits."""

import jax
import numpy as np
import pytest

from gae_jax.model import flame, head
from gae_jax.scene import synthetic
from gae_jax.scene.types import interpolated_vertices, posed_vertices, training_frames


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return synthetic.make_synthetic_scene(size=16, num_cameras=4, frames_per_sequence=3,
                                          supersample=1, progress=False,
                                          cache_dir=str(tmp_path_factory.mktemp("c")))


def test_interpolation_hits_the_frames_and_averages_between_them(scene):
    steps = interpolated_vertices(scene, "mix", per_frame=2)
    assert steps.shape[0] == (3 - 1) * 2 + 1
    frames = posed_vertices(scene, [("mix", t) for t in range(3)])
    np.testing.assert_allclose(steps[::2], frames, atol=1e-6)
    seq, shape = scene.sequences["mix"], scene.shapes["A"]
    a, b = seq.params(shape, 0), seq.params(shape, 1)
    mid = jax.tree_util.tree_map(lambda p, q: 0.5 * (p + q), a, b)  # written out independently
    np.testing.assert_allclose(steps[1], np.asarray(flame.lbs(scene.model, mid)), atol=1e-6)


def test_splits_partition_the_sequences(scene):
    names = [n for split in ("train", "self_reenactment", "cross_identity")
             for n in scene.sequences_of(split)]
    assert sorted(names) == sorted(scene.sequences)
    assert {n for n, _ in training_frames(scene)} == set(scene.sequences_of("train"))
    with pytest.raises(ValueError, match="unknown split"):
        scene.sequences_of("test")


def test_projected_rest_positions_put_the_stripes_where_the_ideal_edit_does(tmp_path):
    """The tracked mesh's rest positions projected into a training view decide the stripes as
    the ideal edit's per-ray stripe shader does on the same frame and camera (the truth's own
    path: `raycast_views` with `instructions.stripe_shader`), and the view's labels say where
    the mesh was hit."""
    from gae_jax import instructions
    from gae_jax.scene import raycast
    from gae_jax.scene.types import projected_labels, projected_rest_positions

    scene = synthetic.make_synthetic_scene(size=48, num_cameras=4, frames_per_sequence=2,
                                           supersample=1, progress=False,
                                           cache_dir=str(tmp_path))
    instruction = instructions.parse("add green stripes to the skin")
    pair, camera = ("jaw", 1), scene.train_cameras[1]
    rest = projected_rest_positions(scene, pair, camera)
    labels = projected_labels(scene, [pair], [camera])[0, 0]
    vertices = posed_vertices(scene, [pair])[0]
    template = np.asarray(scene.model.v_template, np.float64)
    values = np.concatenate([np.zeros((len(template), 3)), np.ones((len(template), 3)),
                             template[:, 1:2]], 1)
    truth = raycast.raycast_views(vertices, np.asarray(scene.model.faces), values,
                                  scene.face_regions, [scene.camera(camera)],
                                  background=(0.0, 0.0, 0.0),
                                  shader=instructions.stripe_shader(instruction,
                                                                    scene.face_regions))[0]
    skin = labels == head.REGION_ID["skin"]
    assert skin.sum() > 100
    on = instructions.stripe_on(rest[..., 1])
    assert 0.2 < on[skin].mean() < 0.8
    np.testing.assert_array_equal(on[skin], truth.image[skin, 0] > 0.5)
    hit = labels >= 0
    assert np.abs(rest[hit]).max(-1).min() > 0 and not rest[~hit].any()
    ys = template[:, 1]
    assert ys.min() - 1e-6 <= rest[hit, 1].min() and rest[hit, 1].max() <= ys.max() + 1e-6
