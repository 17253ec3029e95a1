"""The studies' records: a record is read back only for the settings, scenes and original
avatar it was made with."""

import dataclasses

import jax
import jax.numpy as jnp

from gae_jax.edit.config import EditConfig
from gae_jax.model import avatar as av
from gae_jax.model import head
from gae_jax.run.bench import _jsonable, avatar_fingerprint, renderer_settings, same_settings


def small_avatar() -> av.Avatar:
    model, assets = head.make_head("procedural")
    return av.init_from_mesh(model.v_template, model.faces, assets.vertex_colors,
                             assets.face_regions, key=jax.random.PRNGKey(0))


def test_an_avatar_fingerprint_follows_every_array_and_nothing_else():
    a = small_avatar()
    same = av.Avatar(**{f.name: jnp.array(getattr(a, f.name)) for f in dataclasses.fields(a)})
    assert avatar_fingerprint(a) == avatar_fingerprint(same)
    for name in ("binding", "regions") + tuple(av.TRAINABLE):
        value = getattr(a, name)
        changed = value.at[(0,) * value.ndim].add(1)
        assert avatar_fingerprint(dataclasses.replace(a, **{name: changed})) != \
            avatar_fingerprint(a), name


def test_a_record_is_read_back_only_for_its_original_avatar():
    config = EditConfig(prompt="turn the lips blue")
    scenes = dict(edited_on="s", scored_on="s", original="a" * 16)
    record = dict(config=_jsonable(dataclasses.asdict(config)), renderer=renderer_settings(),
                  scenes=scenes)
    assert same_settings(record, config, scenes)
    assert not same_settings(record, config, dict(scenes, original="b" * 16))
    older = dict(record, scenes=dict(edited_on="s", scored_on="s"))  # before the avatar's key
    assert not same_settings(older, config, scenes)
    assert not same_settings(record, dataclasses.replace(config, iterations=7), scenes)
