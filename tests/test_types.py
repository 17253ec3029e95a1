"""Scene helpers: posed vertices per frame, the interpolated drive of the video, the splits."""

import jax
import numpy as np
import pytest

from gae_jax.model import flame
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
