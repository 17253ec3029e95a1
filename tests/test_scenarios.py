"""The claims study's closed-mouth training split (gae_jax/run/scenarios.py)."""

import dataclasses

import numpy as np
import pytest

from gae_jax.run import scenarios
from gae_jax.edit.sampler import frame_table
from gae_jax.model import head
from gae_jax.scene import synthetic
from gae_jax.scene.types import training_frames

TEETH, IRIS = head.REGION_ID["teeth"], head.REGION_ID["iris"]


def test_closed_split_keeps_closed_open_eyed_runs_as_their_own_sequences(tmp_path):
    scene = synthetic.make_synthetic_scene(size=16, num_cameras=4, frames_per_sequence=8,
                                           supersample=1, progress=False,
                                           cache_dir=str(tmp_path))
    train = scene.sequences_of("train")
    # Hand-made labels: irises everywhere except where a frame closes the eyes, teeth where it
    # opens the mouth (6 px > the 5 px allowed), on one training camera only.
    regions = dict(scene.regions)
    open_mouth = {n: set() for n in train}
    closed_eyes = {n: set() for n in train}
    open_mouth[train[0]] = {2, 3}
    closed_eyes[train[1]] = {0, 7}
    open_mouth[train[2]] = {5}
    cam = scene.train_cameras[0]
    for n in train:
        lab = np.full_like(scene.regions[n], head.REGION_ID["skin"])
        lab[..., 0, :4] = IRIS
        for t in closed_eyes[n]:
            lab[:, t, 0, :4] = head.REGION_ID["skin"]
        for t in open_mouth[n]:
            lab[cam, t, 5, :6] = TEETH
        regions[n] = lab
    scene = dataclasses.replace(scene, regions=regions)
    closed = scenarios.closed_split(scene)
    expected = []
    for n in train:
        keep = [t not in open_mouth[n] and t not in closed_eyes[n] for t in range(8)]
        expected += [(n, t) for t in range(8) if keep[t]
                     and ((t > 0 and keep[t - 1]) or (t < 7 and keep[t + 1]))]
    got = []
    for n, t in training_frames(closed):
        base, first = n.split("~")
        start = int(first)
        got.append((base, start + t))
        np.testing.assert_array_equal(closed.images[n][:, t], scene.images[base][:, start + t])
        np.testing.assert_array_equal(closed.sequences[n].jaw[t],
                                      scene.sequences[base].jaw[start + t])
    assert sorted(got) == sorted(expected)
    others = {n for n, s in scene.sequences.items() if s.split != "train"}
    assert {n for n in closed.sequences if "~" not in n} == others
    for n in others:
        assert closed.sequences[n] is scene.sequences[n] and closed.images[n] is scene.images[n]
    # Temporal neighbours never join two runs: a neighbour is always the adjacent original frame.
    pairs = training_frames(closed)
    for (n, t), neighbours in zip(pairs, frame_table(closed, pairs)):
        for k in neighbours:
            assert pairs[k][0] == n and abs(pairs[k][1] - t) == 1
    with pytest.raises(ValueError, match="no training frame"):
        scenarios.closed_split(scene, eyes_open=2.0)
