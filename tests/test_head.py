"""The procedural head: FLAME layout, skinning, and occlusions checked by trimesh ray casting."""

import jax
import numpy as np
import pytest
import trimesh

from gae_jax.model import flame, head

FRONTAL_EYES = [np.array(e) for e in ([0, 0, 0.5], [0.17, 0.0, 0.47], [-0.17, 0.0, 0.47],
                                      [0.0, 0.09, 0.49], [0.0, -0.08, 0.49])]


@pytest.fixture(scope="module")
def model_assets():
    return head.make_head()


def first_hits(vertices, faces, eye, size=96, fov=30.0):
    """Face index hit first by each pixel's ray from `eye` towards the head (-1: miss)."""
    mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), np.asarray(faces), process=False)
    fwd = np.array([0.0, -0.01, 0.0]) - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = np.tan(np.deg2rad(fov / 2))
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    d = (fwd[None] + ((xs / size * 2 - 1) * t).reshape(-1, 1) * right[None]
         - ((ys / size * 2 - 1) * t).reshape(-1, 1) * up[None])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mesh.ray.intersects_first(np.tile(eye, (len(d), 1)), d)


def region_hits(model, assets, params, region):
    verts = jax.jit(flame.lbs)(model, params)
    total = 0
    for eye in FRONTAL_EYES:
        hit = first_hits(verts, model.faces, eye)
        total += int(np.sum(assets.face_regions[hit[hit >= 0]] == head.REGION_ID[region]))
    return total


def test_head_is_in_flame_layout_and_deterministic(model_assets):
    model, assets = model_assets
    v = model.num_vertices
    assert 2000 < v < 10000
    assert model.parents == flame.FLAME_PARENTS
    assert model.posedirs.shape == (v, 3, 36) and model.j_regressor.shape == (5, v)
    assert model.num_shape == len(head.SHAPE_NAMES) and model.num_expr == len(head.EXPR_NAMES)
    np.testing.assert_allclose(np.asarray(model.lbs_weights).sum(1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(model.j_regressor).sum(1), 1.0, atol=1e-5)
    # Every region but the tongue (the MakeHuman head's).
    assert set(np.unique(assets.face_regions)) == set(range(len(head.REGIONS))) - {
        head.REGION_ID["tongue"]}
    assert assets.vertex_colors.shape == (v, 3)
    again, _ = head.make_head()
    np.testing.assert_array_equal(again.v_template, model.v_template)
    np.testing.assert_allclose(flame.lbs(model, head.params(model)), model.v_template,
                               atol=1e-6)


def test_teeth_hidden_with_jaw_closed_and_visible_with_jaw_open(model_assets):
    model, assets = model_assets
    assert region_hits(model, assets, head.params(model), "teeth") == 0
    assert region_hits(model, assets, head.params(model, jaw_open=0.3), "teeth") > 50


def test_blink_hides_the_irises(model_assets):
    model, assets = model_assets
    assert region_hits(model, assets, head.params(model), "iris") > 50
    blink = head.expression(model, blink_left=1.0, blink_right=1.0)
    assert region_hits(model, assets, head.params(model, expr=blink), "iris") == 0
    one = head.expression(model, blink_left=1.0)
    verts = flame.lbs(model, head.params(model, expr=one))
    hit = first_hits(verts, model.faces, FRONTAL_EYES[0])
    xs = np.asarray(verts)[np.asarray(model.faces)[hit[hit >= 0]]].mean(1)[:, 0]
    iris = assets.face_regions[hit[hit >= 0]] == head.REGION_ID["iris"]
    assert iris.any() and np.all(xs[iris] < 0), "only the right eye (x < 0) stays open"


def test_jaw_moves_the_lower_lip_but_not_the_upper(model_assets):
    model, assets = model_assets
    faces = np.asarray(model.faces)
    lips = faces[assets.face_regions == head.REGION_ID["lips"]].ravel()
    rest = np.asarray(model.v_template)
    opened = np.asarray(flame.lbs(model, head.params(model, jaw_open=0.3)))
    moved = np.linalg.norm(opened - rest, axis=1)
    lower = lips[rest[lips, 1] < head.MOUTH_CENTRE[1] - 0.006]
    upper = lips[rest[lips, 1] > head.MOUTH_CENTRE[1] + 0.006]
    assert moved[lower].min() > 0.005 and moved[upper].max() < 1e-6
    eyes = np.flatnonzero(np.asarray(model.lbs_weights)[:, 3] > 0.5)
    turned = np.asarray(flame.lbs(model, head.params(model, eyes=(0, 0.3, 0, 0, 0, 0))))
    assert np.linalg.norm(turned[eyes] - rest[eyes], axis=1).max() > 0.002


def test_identities_and_expressions_change_the_shape(model_assets):
    model, _ = model_assets
    base = np.asarray(model.v_template)
    for name in head.SHAPE_NAMES:
        p = head.params(model, shape=head.identity(**{name: 1.0}))
        assert np.abs(np.asarray(flame.lbs(model, p)) - base).max() > 1e-3, name
    for name in head.EXPR_NAMES:
        p = head.params(model, expr=head.expression(model, **{name: 1.0}))
        assert np.abs(np.asarray(flame.lbs(model, p)) - base).max() > 1e-3, name
    with pytest.raises(ValueError, match="known"):
        head.expression(model, frown=1.0)
