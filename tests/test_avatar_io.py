"""GaussianAvatars files and the posed 3DGS .ply: round trips and clear errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.model import avatar as av
from gae_jax.model import avatar_io, flame, head
from gae_jax.render import splat
from gae_jax.render.camera import look_at_w2c, make_camera
from gae_jax.util.fileio import PlyError, read_ply


@pytest.fixture(scope="module")
def head_avatar():
    model, assets = head.make_head()
    a = av.init_from_mesh(model.v_template, model.faces, assets.vertex_colors,
                          assets.face_regions, sh_degree=3, opacity=0.8, normal_scale=0.2)
    rng = np.random.default_rng(0)
    a = av.Avatar(a.binding, a.means + jnp.asarray(rng.normal(scale=0.1, size=a.means.shape),
                                                  jnp.float32),
                  jnp.asarray(rng.normal(size=a.quats.shape), jnp.float32), a.log_scales,
                  a.opacity_logits, a.colors + jnp.asarray(
                      rng.normal(scale=0.1, size=a.colors.shape), jnp.float32), a.regions)
    return model, assets, a


def test_point_cloud_round_trip_renders_identically(tmp_path, head_avatar):
    model, assets, a = head_avatar
    path = str(tmp_path / "point_cloud.ply")
    avatar_io.save_avatar_ply(a, path)
    b = avatar_io.load_avatar_ply(path, assets.face_regions)
    for name in ("binding", "means", "quats", "log_scales", "opacity_logits", "colors",
                 "regions"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
    props = read_ply(path)
    # f_rest is channel-major: index = channel * 15 + coefficient.
    np.testing.assert_array_equal(props["f_rest_0"], np.asarray(a.colors)[:, 1, 0])
    np.testing.assert_array_equal(props["f_rest_15"], np.asarray(a.colors)[:, 1, 1])
    camera = make_camera(look_at_w2c([0, 0, 0.55], [0, -0.01, 0], up=(0, 1, 0)), 48, 48,
                         fov_degrees=28.0)
    verts = flame.lbs(model, head.params(model, jaw_open=0.2))

    @jax.jit
    def render(x):
        return splat.render(av.deform(x, verts, model.faces), camera, tile_capacity=512).image

    np.testing.assert_array_equal(render(a), render(b))


def test_posed_ply_holds_world_space_activated_parameters(tmp_path, head_avatar):
    model, _, a = head_avatar
    g = av.deform(a, flame.lbs(model, head.params(model)), model.faces)
    path = str(tmp_path / "posed.ply")
    avatar_io.save_posed_ply(g, path)
    p = read_ply(path)
    np.testing.assert_allclose(np.c_[p["x"], p["y"], p["z"]], g.means, atol=1e-7)
    np.testing.assert_allclose(np.exp(np.c_[p["scale_0"], p["scale_1"], p["scale_2"]]),
                               g.scales, rtol=1e-5)
    np.testing.assert_allclose(1 / (1 + np.exp(-p["opacity"])), g.opacities, atol=1e-5)
    q = np.c_[p["rot_0"], p["rot_1"], p["rot_2"], p["rot_3"]]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)
    assert sum(k.startswith("f_rest_") for k in p) == 45


def test_malformed_ply_files_name_the_file_and_property(tmp_path, head_avatar):
    _, _, a = head_avatar
    path = tmp_path / "pc.ply"
    avatar_io.save_avatar_ply(a, str(path))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(PlyError, match="pc.ply.*truncated"):
        avatar_io.load_avatar_ply(str(path))
    path.write_bytes(data.replace(b"property float binding_0", b"property float other_0"))
    with pytest.raises(PlyError, match="binding_0"):
        avatar_io.load_avatar_ply(str(path))
    path.write_bytes(b"not a ply")
    with pytest.raises(PlyError, match="not a .ply"):
        read_ply(str(path))


def test_flame_params_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(1)
    t = 5
    frames = flame.FlameParams(
        shape=jnp.zeros((t, 3)), expr=jnp.asarray(rng.normal(size=(t, 6)), jnp.float32),
        rotation=jnp.asarray(rng.normal(size=(t, 3)), jnp.float32),
        neck=jnp.asarray(rng.normal(size=(t, 3)), jnp.float32),
        jaw=jnp.asarray(rng.normal(size=(t, 3)), jnp.float32),
        eyes=jnp.asarray(rng.normal(size=(t, 6)), jnp.float32),
        translation=jnp.asarray(rng.normal(size=(t, 3)), jnp.float32))
    shape = np.arange(3, dtype=np.float32)
    path = str(tmp_path / "flame_param.npz")
    avatar_io.save_flame_params(path, shape, frames, num_vertices=7)
    with np.load(path) as f:  # GaussianAvatars' nine keys, in its order, float32
        assert f.files == ["shape", "expr", "rotation", "neck_pose", "jaw_pose", "eyes_pose",
                           "translation", "static_offset", "dynamic_offset"]
        assert all(f[k].dtype == np.float32 for k in f.files)
        assert f["static_offset"].shape == (1, 7, 3) and f["dynamic_offset"].shape == (t, 7, 3)
    loaded_shape, loaded = avatar_io.load_flame_params(path)
    np.testing.assert_array_equal(loaded_shape, shape)
    for name in ("expr", "rotation", "neck", "jaw", "eyes", "translation"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(frames, name))
    np.savez(path, shape=shape, rotation=np.zeros((t, 3)), neck_pose=np.zeros((t, 3)),
             jaw_pose=np.zeros((t, 2)), eyes_pose=np.zeros((t, 6)),
             translation=np.zeros((t, 3)), expr=np.zeros((t, 6)))
    with pytest.raises(ValueError, match="jaw_pose"):
        avatar_io.load_flame_params(path)
    np.savez(path, shape=shape)
    with pytest.raises(ValueError, match="missing keys"):
        avatar_io.load_flame_params(path)


def test_plain_rgb_avatar_round_trips_as_sh_dc_with_the_same_colours(tmp_path):
    model, assets = head.make_head()
    a = av.init_from_mesh(model.v_template, model.faces, assets.vertex_colors,
                          assets.face_regions, sh_degree=None)
    path = str(tmp_path / "point_cloud.ply")
    avatar_io.save_avatar_ply(a, path)
    rest = [v for k, v in read_ply(path).items() if k.startswith("f_rest_")]
    assert len(rest) == 45 and not np.any(rest)  # the degree-3 layout, higher bands zero
    b = avatar_io.load_avatar_ply(path, assets.face_regions)
    assert b.colors.shape == (a.num, 16, 3)
    np.testing.assert_allclose(avatar_io.load_bound_avatar(path, assets.face_regions).colors,
                               a.colors, atol=1e-6)  # read back to edit: plain colours again
    avatar_io.save_avatar_ply(a, path, sh_degree=0)
    assert not any(k.startswith("f_rest_") for k in read_ply(path))
    camera = make_camera(look_at_w2c([0, 0, 0.55], [0, -0.01, 0], up=(0, 1, 0)), 8, 8)
    g_b = av.deform(b, model.v_template, model.faces)
    np.testing.assert_allclose(splat.colors_towards(g_b, camera), np.asarray(a.colors),
                               atol=1e-6)
