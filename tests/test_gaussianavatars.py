"""Conformance with GaussianAvatars and VHAP, against files their own code wrote
(`shared/fixtures/gaussianavatars/`, made by running GaussianAvatars @ 30cc4bd and VHAP @ 4b64ab7
unmodified; its README says how, and the tolerances below are the ones it gives for a float32
implementation): their teeth, their avatar posed, files they accept, their data folders'
meshes and cameras."""

import json
import os

import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.model import avatar as av
from gae_jax.model import avatar_io, flame, flame_io, head, teeth
from gae_jax.scene import load, nersemble
from gae_jax.scene.types import posed_vertices
from gae_jax.util.fileio import read_ply

FIXTURES = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "fixtures",
                        "gaussianavatars")
# The fixtures' README: what a correct float32 implementation should expect.
VERTEX_ATOL = 1e-6  # m
XYZ_ATOL = 2e-6  # m
SCALING_RTOL = 1e-3
ROTATION_ATOL = 1e-3  # wxyz components, after aligning the sign
OPACITY_ATOL = 1e-6
CAMERA_ATOL = 1e-6


def fixture(*parts):
    path = os.path.join(FIXTURES, *parts)
    if not os.path.exists(path):
        pytest.fail(f"{path} is missing: the conformance fixtures live in ../shared (CI has them)")
    return path


@pytest.fixture(scope="module")
def flame_model():
    return flame_io.load_flame(fixture("teeth", "flame_model.npz"), n_shape=300, n_expr=100)


@pytest.fixture(scope="module")
def with_teeth(flame_model):
    return teeth.with_teeth(flame_model)


def test_teeth_are_gaussianavatars_teeth_exactly(flame_model, with_teeth):
    """Vertex order, the 168 faces in order with their corner order, skinning, blendshapes."""
    ga = np.load(fixture("teeth", "teeth_ga.npz"))
    np.testing.assert_array_equal(ga["lip_ring_upper"], teeth.FLAME_UPPER_LIP)
    np.testing.assert_array_equal(ga["lip_ring_lower"], teeth.FLAME_LOWER_LIP)
    np.testing.assert_allclose(np.asarray(with_teeth.v_template), ga["v_template"],
                               atol=VERTEX_ATOL)
    np.testing.assert_array_equal(np.asarray(with_teeth.faces), ga["faces"])
    np.testing.assert_array_equal(np.asarray(with_teeth.lbs_weights), ga["lbs_weights"])
    np.testing.assert_array_equal(np.asarray(with_teeth.j_regressor), ga["J_regressor"])
    base = int(ga["num_verts_orig"])
    dirs = np.concatenate([np.asarray(with_teeth.shapedirs), np.asarray(with_teeth.exprdirs)],
                          -1)[base:]
    np.testing.assert_array_equal(dirs, ga["shapedirs_teeth"])
    np.testing.assert_array_equal(np.asarray(with_teeth.posedirs)[base:], ga["posedirs_teeth"])
    upper_rows = np.concatenate([base + 15 * r + np.arange(15) for r in teeth.UPPER_ROWS])
    np.testing.assert_array_equal(np.sort(upper_rows), np.sort(ga["teeth_upper"]))
    assert int(ga["num_faces_orig"]) == flame_model.faces.shape[0]


def _quat_close(ours, theirs):
    """wxyz quaternions equal up to sign (q and -q are one rotation)."""
    sign = np.where(np.sum(ours * theirs, -1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(ours * sign, theirs, atol=ROTATION_ATOL)


def test_their_avatar_with_teeth_bindings_poses_as_in_their_code(with_teeth):
    """point_cloud.ply (SH 3, bindings on every face including the teeth) and flame_param.npz
    (static offsets), posed at their three timesteps: their vertices and their Gaussians."""
    folder = fixture("avatar_teeth")
    posed = np.load(os.path.join(folder, "posed.npz"))
    regions = teeth.teeth_regions(np.zeros(with_teeth.faces.shape[0] - 168, np.int32),
                                  head.REGION_ID["teeth"])
    avatar = avatar_io.load_bound_avatar(os.path.join(folder, "point_cloud.ply"), regions)
    np.testing.assert_array_equal(np.asarray(avatar.binding), posed["binding"])
    assert avatar.colors.shape == (avatar.num, 16, 3)
    # the file's channel-major f_rest read back in GaussianAvatars' coefficient-major order
    np.testing.assert_array_equal(np.asarray(avatar.colors)[:64], posed["features_first64"])
    shape, frames = avatar_io.load_flame_params(os.path.join(folder, "flame_param.npz"))
    offset = flame.fit_static_offset(np.asarray(frames.static_offset)[0],
                                     with_teeth.num_vertices)
    for t in range(len(posed["timesteps"])):
        params = flame.FlameParams(
            shape=jnp.asarray(shape), expr=frames.expr[t], rotation=frames.rotation[t],
            neck=frames.neck[t], jaw=frames.jaw[t], eyes=frames.eyes[t],
            translation=frames.translation[t], static_offset=jnp.asarray(offset))
        verts = flame.lbs(with_teeth, params)
        np.testing.assert_allclose(np.asarray(verts), posed["verts"][t], atol=VERTEX_ATOL)
        g = av.deform(avatar, verts, with_teeth.faces)
        np.testing.assert_allclose(np.asarray(g.means), posed["xyz"][t], atol=XYZ_ATOL)
        np.testing.assert_allclose(np.asarray(g.scales), posed["scaling"][t], rtol=SCALING_RTOL)
        _quat_close(np.asarray(g.quats), posed["rotation"][t])
        np.testing.assert_allclose(np.asarray(g.opacities), posed["opacity"][:, 0],
                                   atol=OPACITY_ATOL)


def test_our_files_have_their_layout(tmp_path, with_teeth):
    """Our avatar folder as theirs: the ply's property names, order and dtypes (45 f_rest_* for
    their default SH degree 3, float32 binding) and the nine flame_param keys in their order,
    float32, `shape` one-dimensional; keys of an input file carried through."""
    folder = fixture("avatar_teeth")
    regions = np.zeros(with_teeth.faces.shape[0], np.int32)
    plain = avatar_io.load_bound_avatar(os.path.join(folder, "point_cloud.ply"), regions)
    plain = plain.with_params(dict(plain.trainable(), colors=jnp.full((plain.num, 3), 0.5)))
    shape, frames = avatar_io.load_flame_params(os.path.join(folder, "flame_param.npz"))
    avatar_io.save_avatar_folder(str(tmp_path), plain, shape, frames,
                                 np.asarray(frames.static_offset)[0],
                                 extra={"their_key": np.arange(3)})
    theirs = read_ply(os.path.join(folder, "point_cloud.ply"))
    ours = read_ply(str(tmp_path / "point_cloud.ply"))
    assert list(ours) == list(theirs)
    assert all(ours[k].dtype == np.float32 for k in ours)
    assert sum(k.startswith("f_rest_") for k in ours) == 45
    np.testing.assert_array_equal(ours["f_rest_7"], 0.0)
    with np.load(os.path.join(folder, "flame_param.npz")) as t, \
            np.load(str(tmp_path / "flame_param.npz")) as o:
        assert list(o.files)[:9] == list(t.files) and o.files[9:] == ["their_key"]
        for k in t.files:
            assert o[k].dtype == np.float32 and o[k].shape == t[k].shape, k
        np.testing.assert_array_equal(o["static_offset"], t["static_offset"])
        np.testing.assert_array_equal(o["their_key"], np.arange(3))


@pytest.mark.parametrize("folder", ["vhap_subject", "vhap_union"])
def test_their_data_folders_pose_their_meshes(folder, with_teeth):
    """A VHAP export (and a UNION of two): the mesh of every timestep as GaussianAvatars poses
    it (static offset of timestep 0's file, teeth, paths relative to the folder), with the
    model sized from the data even when the folder holds no flame_param of its own."""
    path = fixture(folder)
    first = nersemble.first_flame_param(path)
    assert first["shape"].size == 300 and first["expr"].shape[-1] == 100
    scene = nersemble.load_scene(path, with_teeth, np.zeros(with_teeth.faces.shape[0], np.int32))
    expected = np.load(os.path.join(path, "expected_vertices.npz"))
    assert "A" in scene.static_offsets
    order = {}
    train = sorted({fr.timestep for fr in nersemble.load_split(path, "train")})
    order.update({t: ("train", i) for i, t in enumerate(train)})
    if "test" in scene.sequences:
        test = sorted({fr.timestep for fr in nersemble.load_split(path, "test")} - set(train))
        order.update({t: ("test", i) for i, t in enumerate(test)})
    pairs = [order[int(t)] for t in expected["timestep_index"]]
    verts = posed_vertices(scene, pairs)
    np.testing.assert_allclose(verts, expected["vertices"], atol=VERTEX_ATOL)


@pytest.mark.parametrize("folder", ["vhap_subject", "vhap_union"])
def test_their_cameras_are_read_as_their_code_and_the_calibration_say(folder):
    """Poses as GaussianAvatars builds them (world-to-view), and the principal point of the
    OpenCV calibration VHAP started from: cy = h - cy of the JSON."""
    path = fixture(folder)
    cameras = np.load(os.path.join(path, "ga_cameras.npz"))
    with open(fixture("vhap_input", "camera_params.json")) as f:
        calibration = json.load(f)
    serials = sorted(calibration["world_2_cam"])
    k = np.asarray(calibration["intrinsics"], np.float64)
    for split in ("train", "val", "test"):
        frames = nersemble.load_split(path, split)
        for j, image_path in enumerate(cameras[f"{split}_image_path"]):
            fr = next(f for f in frames
                      if os.path.normpath(f.image_path) == os.path.normpath(
                          os.path.join(path, str(image_path))))
            w2v = cameras[f"{split}_world_view_transform"][j].T  # their row-vector convention
            np.testing.assert_allclose(fr.w2c, w2v, atol=CAMERA_ATOL)
            assert (fr.width, fr.height) == tuple(cameras[f"{split}_width_height"][j])
            np.testing.assert_allclose(fr.intrinsics, [k[0, 0], k[1, 1], k[0, 2], k[1, 2]],
                                       atol=1e-4)
    assert len(serials) == 3


def test_a_flame_file_loads_with_their_teeth_unless_asked(tmp_path, flame_model):
    path = str(tmp_path / "flame.npz")
    flame_io.save_flame(flame_model, path)
    model, regions = load.load_model(path)
    assert model.num_vertices == 5143 and model.faces.shape[0] == 10144
    assert np.all(regions[9976:] == head.REGION_ID["teeth"]) and np.all(regions[:9976] == 0)
    plain, plain_regions = load.load_model(path, teeth=False)
    assert plain.num_vertices == 5023 and len(plain_regions) == 9976


def test_their_avatar_edits_on_their_data_and_comes_back_in_their_layout(tmp_path, flame_model,
                                                                        capsys):
    """`train --avatar` with their avatar, their VHAP folder and a FLAME file (teeth added as
    they add them): the edited folder is theirs again, their extra keys carried."""
    from gae_jax import train

    model_path = str(tmp_path / "flame.npz")
    flame_io.save_flame(flame_model, model_path)
    avatar = tmp_path / "their_avatar"
    avatar.mkdir()
    source = fixture("avatar_teeth")
    (avatar / "point_cloud.ply").write_bytes(open(os.path.join(source, "point_cloud.ply"),
                                                  "rb").read())
    with np.load(os.path.join(source, "flame_param.npz")) as f:
        np.savez(avatar / "flame_param.npz", **{k: f[k] for k in f.files},
                 their_key=np.arange(4, dtype=np.int64))
    out = tmp_path / "run"
    code = train.main(["--data", fixture("vhap_subject"), "--flame-model", model_path,
                       "--avatar", str(avatar), "--out", str(out), "--iterations", "2",
                       "--prompt", "make the skin light blue", "--no-video",
                       "--compile-cache", "off"])
    assert code == 0, capsys.readouterr().err
    edited = out / "edited_avatar"
    ours, theirs = read_ply(str(edited / "point_cloud.ply")), read_ply(str(avatar /
                                                                           "point_cloud.ply"))
    assert list(ours) == list(theirs) and all(v.dtype == np.float32 for v in ours.values())
    np.testing.assert_array_equal(ours["binding_0"], theirs["binding_0"])
    with np.load(str(edited / "flame_param.npz")) as f:
        assert f.files[:9] == ["shape", "expr", "rotation", "neck_pose", "jaw_pose",
                               "eyes_pose", "translation", "static_offset", "dynamic_offset"]
        assert all(f[k].dtype == np.float32 for k in f.files[:9]) and f["shape"].ndim == 1
        assert f["static_offset"].shape == (1, 5143, 3) and np.any(f["static_offset"])
        np.testing.assert_array_equal(f["their_key"], np.arange(4))
    posed = read_ply(str(out / "edited_posed.ply"))
    assert sum(k.startswith("f_rest_") for k in posed) == 45  # 3DGS load_ply's default


def test_the_viewer_poses_their_avatar_with_its_static_offset(tmp_path, flame_model):
    """`view --avatar` on their folder with a FLAME file: the sliders of their frame t pose
    their Gaussians (their static offset applied)."""
    from gae_jax.viewer import pose, source

    model_path = str(tmp_path / "flame.npz")
    flame_io.save_flame(flame_model, model_path)
    folder = fixture("avatar_teeth")
    viewable = source.from_avatar(folder, flame_model=model_path)
    posed = np.load(os.path.join(folder, "posed.npz"))
    assert viewable.model.num_vertices == 5143
    sequence = viewable.sequences[source.AVATAR_MOTION]
    for t in range(sequence.num_frames):
        params = pose.params_of_values(pose.values_of_frame(sequence, t), viewable.shapes["A"],
                                       viewable.model.num_expr, viewable.static_offsets["A"])
        g = av.deform(viewable.avatars["avatar"], flame.lbs(viewable.model, params),
                      viewable.model.faces)
        np.testing.assert_allclose(np.asarray(g.means), posed["xyz"][t], atol=XYZ_ATOL)


@pytest.mark.parametrize("folder", ["vhap_subject", "vhap_union"])
def test_their_data_folders_reconstruct(folder, tmp_path, flame_model, capsys):
    from gae_jax import reconstruct

    model_path = str(tmp_path / "flame.npz")
    flame_io.save_flame(flame_model, model_path)
    out = tmp_path / "avatar"
    code = reconstruct.main(["--data", fixture(folder), "--flame-model", model_path,
                             "--out", str(out), "--iterations", "30",
                             "--compile-cache", "off"])
    assert code == 0, capsys.readouterr().err
    report = json.loads((out / "reconstruct.json").read_text())
    assert np.isfinite(report["final"]["loss"]) and report["final"]["region"] >= 0
    ply = read_ply(str(out / "point_cloud.ply"))
    assert ply["binding_0"].max() >= 9976  # Gaussians on their teeth too
    with np.load(str(out / "flame_param.npz")) as f:
        expected = np.load(fixture("vhap_subject", "flame_param", "00000.npz"))["static_offset"]
        np.testing.assert_allclose(f["static_offset"], expected)
