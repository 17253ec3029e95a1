"""The viewer's update path: slider values pose exactly the Gaussians `deform` gives for the same
FLAME parameters, the browser's camera becomes the same pinhole camera viser describes, a frame
renders as the training path renders it (capacity grown on overflow), and a run or avatar
folder loads with clear errors when it is not one."""

import socket

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax import view
from gae_jax.edit.config import EditConfig
from gae_jax.evaluation import truth
from gae_jax.model import avatar as av
from gae_jax.model import flame, head
from gae_jax.render import wabe
from gae_jax.render.projection import quat_to_rotmat
from gae_jax.run import folder
from gae_jax.scene import motion_io, synthetic
from gae_jax.scene import rig as rigs
from gae_jax.scene.load import SceneConfig
from gae_jax.scene.types import stacked_params
from gae_jax.viewer import app, frames, pose, source
from tests.helpers import tree_allclose

POSE_TOL = 1e-5  # float32 skinning of the same parameters along two code paths
RIG_SIZE = 64


def tiny_run_folder(path, num_expr_frames: int = 4):
    """A run folder as `run.job.run` writes it (the same writers), with untrained splats on the
    procedural head: avatars, metrics.json, evaluation_set.npz (cameras only) and motion.npz."""
    model, assets = head.make_head("procedural")
    avatar = av.init_from_mesh(model.v_template, model.faces, assets.vertex_colors,
                               assets.face_regions, per_face=1, sh_degree=None,
                               key=jax.random.PRNGKey(0), opacity=0.95, normal_scale=0.1)
    sequences = synthetic.make_sequences(num_expr_frames, model.num_expr)
    shapes = {"A": np.zeros(model.num_shape),
              "B": np.asarray(head.identity(**synthetic.IDENTITY_B_SHAPE["procedural"]))}
    frames_a = jax.tree_util.tree_map(
        lambda *x: jnp.stack(x), *[sequences["mix"].params(shapes["A"], t)
                                  for t in range(num_expr_frames)])
    edited = av.Avatar(**{**{k: getattr(avatar, k) for k in ("binding", "means", "quats",
                                                              "log_scales", "opacity_logits",
                                                              "regions")},
                          "colors": avatar.colors * 0.5})
    for which, a in (("edited", edited), ("original", avatar)):
        folder.write_avatar(str(path), which, a, shapes["A"], frames_a, None, model.num_vertices)
    intrinsics, w2c = synthetic.camera_rig(9, RIG_SIZE)
    evalset = truth.EvalSet("turn the lips blue", "lips", "ideal edit", np.asarray(model.faces),
                            assets.face_regions, intrinsics, w2c, np.ones(3), RIG_SIZE, RIG_SIZE,
                            {})
    truth.save(evalset, folder.path(str(path), "evaluation_set"))
    motion_io.save(folder.path(str(path), "motion"), sequences, shapes)
    folder.write_metrics(str(path), dict(config=dict(EditConfig().__dict__),
                                         scene=dict(SceneConfig(head="procedural").__dict__),
                                         tile_capacity=256))
    return path


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return tiny_run_folder(tmp_path_factory.mktemp("run"))


@pytest.fixture(scope="module")
def viewable(run_dir):
    return source.from_run(str(run_dir))


def test_run_folder_loads_both_avatars_the_scene_motions_and_the_training_blend(viewable):
    v = viewable
    assert list(v.avatars) == ["edited", "original"]
    assert set(v.shapes) == {"A", "B"} and v.sequences["b_mix"].identity == "B"
    assert set(v.sequences) == set(synthetic.make_sequences(4, v.model.num_expr))
    assert v.expr_names == head.EXPR_NAMES
    assert v.blend == wabe.named(EditConfig().blend, EditConfig().beta)
    assert v.w2c.shape == (9, 4, 4) and v.height == RIG_SIZE


def test_slider_values_of_a_frame_pose_the_gaussians_deform_gives(viewable):
    v = viewable
    for name in ("mix", "b_mix", "turn"):
        seq = v.sequences[name]
        shape = v.shapes[seq.identity]
        for t in range(seq.num_frames):
            values = pose.values_of_frame(seq, t)
            ours = frames.posed(v.model, v.avatars["edited"],
                                pose.params_of_values(values, shape, v.model.num_expr))
            reference = av.deform(v.avatars["edited"], flame.lbs(v.model, seq.params(shape, t)),
                                  v.model.faces)
            tree_allclose(ours, reference, rtol=POSE_TOL, atol=POSE_TOL)


def test_single_sliders_move_the_parameters_they_name(viewable):
    v = viewable
    values = dict(pose.neutral(v.model.num_expr), **{"jaw/0": 0.3, "expr/2": 0.7,
                                                      "eyes/4": -0.2, "rotation/1": 0.5})
    ours = pose.params_of_values(values, v.shapes["A"], v.model.num_expr)
    eyes = np.zeros(6)
    eyes[4] = -0.2
    reference = head.params(v.model, jaw_open=0.3, rotation=(0.0, 0.5, 0.0), eyes=eyes,
                            expr=head.expression(v.model, smile=0.7))
    tree_allclose(ours, reference)
    tree_allclose(frames.posed(v.model, v.avatars["original"], ours),
                  av.deform(v.avatars["original"], flame.lbs(v.model, reference), v.model.faces),
                  rtol=POSE_TOL, atol=POSE_TOL)


def test_every_parameter_has_one_slider_whose_range_holds_the_sequences(viewable):
    v = viewable
    specs = pose.sliders(v.expr_names, v.sequences, 1.0)
    assert [s.key for s in specs] == list(pose.neutral(v.model.num_expr))
    assert [s.label for s in specs[:len(v.expr_names)]] == list(v.expr_names)
    for seq in v.sequences.values():
        for t in range(seq.num_frames):
            values = pose.values_of_frame(seq, t)
            for s in specs:
                assert s.low <= values[s.key] <= s.high, (seq.name, s.key)


def test_the_browser_camera_is_the_pinhole_viser_describes():
    import viser.transforms as vtf

    rng = np.random.default_rng(0)
    wxyz = rng.normal(size=4)
    wxyz /= np.linalg.norm(wxyz)
    position = rng.normal(size=3)
    fov, aspect, height = 0.7, 1.6, 96
    camera = frames.camera_of_view(position, wxyz, fov, aspect, height)
    # viser: P_world = R p_camera + position, OpenCV axes; a viewport of aspect `aspect` with a
    # vertical field of view `fov`, onto which the image is stretched.
    r = vtf.SO3(wxyz).as_matrix()
    points = position + (rng.normal(size=(20, 3)) * 0.3 + [0, 0, 2.0]) @ r.T
    p_cam = (points - position) @ r
    tan_half = np.tan(fov / 2)
    ndc = np.stack([p_cam[:, 0] / p_cam[:, 2] / (tan_half * aspect),
                    p_cam[:, 1] / p_cam[:, 2] / tan_half], -1)  # -1..1 across the viewport
    ours = np.asarray(camera.world_to_camera(jnp.asarray(points, jnp.float32)), np.float64)
    fx, fy, cx, cy = np.asarray(camera.intrinsics, np.float64)
    pixels = np.stack([fx * ours[:, 0] / ours[:, 2] + cx, fy * ours[:, 1] / ours[:, 2] + cy], -1)
    stretched = pixels / [camera.width, camera.height] * 2 - 1
    np.testing.assert_allclose(stretched, ndc, atol=1e-4)


def test_a_rig_camera_round_trips_through_the_browser_view(viewable):
    v = viewable
    for i in range(len(v.w2c)):
        position, wxyz, fov = frames.view_of_camera(v.intrinsics[i], v.w2c[i], v.height)
        camera = frames.camera_of_view(position, wxyz, fov, 1.0, v.height)
        np.testing.assert_allclose(np.asarray(camera.w2c), v.w2c[i], atol=1e-5)
        np.testing.assert_allclose(np.asarray(camera.intrinsics), v.intrinsics[i], rtol=1e-5)


def test_a_frame_renders_as_the_training_path_and_grows_an_overflowing_capacity(viewable):
    v = viewable
    seq = v.sequences["mix"]
    params = seq.params(v.shapes["A"], 1)
    avatar = v.avatars["edited"]
    verts = np.asarray(flame.lbs(v.model, params))[None]
    rig = rigs.make_rig(v.model.faces, avatar, verts, v.intrinsics[3:4], v.w2c[3:4],
                        v.background, v.width, v.height, 4096)
    camera = rig.camera(0)
    reference = np.clip(np.asarray(rigs.render_bound(avatar.trainable(), rig, 0, 0,
                                                     blend=v.blend).image), 0, 1)
    image, capacity = frames.render(v.model, avatar, params, camera, v.background, v.blend,
                                    capacity=8)
    assert capacity > 8
    np.testing.assert_allclose(image, reference, atol=1e-5)
    again, same = frames.render(v.model, avatar, params, camera, v.background, v.blend,
                                capacity)
    assert same == capacity
    np.testing.assert_allclose(again, reference, atol=1e-5)


def test_side_by_side_halves_keep_the_views_scale_over_half_the_viewport(viewable):
    v = viewable
    position, wxyz, fov = frames.view_of_camera(v.intrinsics[0], v.w2c[0], v.height)
    camera = frames.camera_of_view(position, wxyz, fov, 2.0, 64)
    half = frames.side_by_side(camera)
    assert (half.width, half.height) == (64, 64)
    points = jnp.asarray(v.model.v_template[::50])

    def screen(cam, share):
        """Positions as fractions of the viewport, for an image stretched over `share` of its
        width."""
        p = cam.world_to_camera(points)
        u = cam.intrinsics[0] * p[:, 0] / p[:, 2] + cam.intrinsics[2]
        w = cam.intrinsics[1] * p[:, 1] / p[:, 2] + cam.intrinsics[3]
        return np.stack([np.asarray(u) / cam.width * share, np.asarray(w) / cam.height], -1)

    full, halved = screen(camera, 1.0), screen(half, 0.5)
    # the same picture, smaller by nothing: every offset between two points is the same on
    # screen, and the head sits at the half's centre instead of the viewport's
    np.testing.assert_allclose(halved - halved.mean(0), full - full.mean(0), atol=1e-5)
    np.testing.assert_allclose(halved.mean(0) - full.mean(0), [-0.25, 0.0], atol=1e-5)


def test_splat_arrays_are_the_posed_gaussians_covariances(viewable):
    v = viewable
    params = v.sequences["talk"].params(v.shapes["A"], 2)
    arrays = frames.splat_arrays(v.model, v.avatars["original"], params)
    g = frames.posed(v.model, v.avatars["original"], params)
    rot = np.asarray(quat_to_rotmat(g.quats), np.float64)
    s = np.asarray(g.scales, np.float64)
    reference = np.stack([r @ np.diag(x ** 2) @ r.T for r, x in zip(rot[:50], s[:50])])
    # float32 products cancel in the small off-diagonal terms: tolerance relative to the largest
    np.testing.assert_allclose(arrays.covariances[:50], reference, rtol=1e-4,
                               atol=1e-5 * np.abs(reference).max())
    np.testing.assert_allclose(arrays.centers, np.asarray(g.means))
    assert arrays.opacities.shape == (g.num, 1) and arrays.rgbs.max() <= 1.0


def test_motion_file_round_trips_and_refuses_what_does_not_fit(tmp_path):
    model, _ = head.make_head()
    sequences = synthetic.make_sequences(3, model.num_expr)
    shapes = {"A": np.zeros(model.num_shape), "B": np.ones(model.num_shape)}
    path = str(tmp_path / "motion.npz")
    motion_io.save(path, sequences, shapes)
    loaded, loaded_shapes, offsets = motion_io.load(path, model.num_expr, model.num_shape)
    assert offsets == {}
    assert list(loaded) == list(sequences)
    for name, seq in sequences.items():
        tree_allclose(stacked_params_of(loaded[name], shapes), stacked_params_of(seq, shapes))
        assert (loaded[name].split, loaded[name].identity) == (seq.split, seq.identity)
    with pytest.raises(ValueError, match="expected"):
        motion_io.load(path, model.num_expr + 1, model.num_shape)
    with pytest.raises(ValueError, match="shape has"):
        motion_io.load(path, model.num_expr, model.num_shape + 2)
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match="not a readable motion file"):
        motion_io.load(str(tmp_path / "bad.npz"), model.num_expr, model.num_shape)


def stacked_params_of(seq, shapes):
    return [np.asarray(getattr(seq, f), np.float32) for f in motion_io.FIELDS]


def test_an_avatar_folder_views_on_the_embedded_rig(run_dir):
    v = source.from_avatar(folder.path(str(run_dir), "original"), "procedural")
    assert list(v.avatars) == ["avatar"] and source.AVATAR_MOTION in v.sequences
    assert "mix" in v.sequences and v.w2c.shape[0] == source.RIG_CAMERAS


def test_an_avatar_folder_bound_to_a_flame_file_poses_as_the_embedded_head(run_dir, tmp_path):
    from gae_jax.model import flame_io

    embedded = source.from_avatar(folder.path(str(run_dir), "original"), "procedural")
    path = str(tmp_path / "generic_model.pkl")
    flame_io.save_flame(embedded.model, path)  # FLAME's own pickle layout
    v = source.from_avatar(folder.path(str(run_dir), "original"), flame_model=path)
    assert v.expr_names == tuple(f"expression {i}" for i in range(embedded.model.num_expr))
    assert list(v.sequences) == [source.AVATAR_MOTION]
    seq = v.sequences[source.AVATAR_MOTION]
    params = pose.params_of_values(pose.values_of_frame(seq, 2), v.shapes["A"],
                                   v.model.num_expr)
    tree_allclose(frames.posed(v.model, v.avatars["avatar"], params),
                  frames.posed(embedded.model, embedded.avatars["avatar"], params),
                  rtol=POSE_TOL, atol=POSE_TOL)


def test_the_cli_refuses_bad_folders_and_a_busy_port_in_one_line(tmp_path, run_dir, capsys):
    (tmp_path / "empty").mkdir()
    cases = [([str(tmp_path / "empty")], "metrics.json not found; is"),
             ([str(tmp_path / "missing")], "no such folder"),
             (["--avatar", str(tmp_path / "empty")], "no point_cloud.ply"),
             ([], "give a run folder or --avatar"),
             ([str(run_dir), "--size", "4", "--port", "0"], "--size 4"),
             (["--avatar", folder.path(str(run_dir), "original"), "--head", "makehuman",
               "--port", "0"], "another model")]
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        cases.append(([str(run_dir), "--port", str(port)], f"--port {port}: cannot listen"))
        for argv, message in cases:
            assert view.main(argv) == 2, argv
            err = capsys.readouterr().err
            assert message in err and err.count("\n") == 1, (argv, err)


def test_the_player_loads_each_frame_into_the_sliders_with_the_sequences_identity(viewable):
    import time

    viewer = app.Viewer(viewable, port=0, size=32)
    try:
        viewer.sequence.value = "b_mix"
        assert viewer.identity.value == "B"
        viewer.fps.value = 30
        viewer.playing.value = True
        start = time.monotonic()
        while int(viewer.frame.value) == 0 and time.monotonic() - start < 10:
            time.sleep(0.05)
        viewer.playing.value = False
        time.sleep(0.1)
        frame = int(viewer.frame.value)
        assert frame > 0
        seq = viewable.sequences["b_mix"]
        assert viewer.values == pose.values_of_frame(seq, frame)
        tree_allclose(viewer.current_params(), seq.params(viewable.shapes["B"], frame))
        for key, handle in viewer.sliders.items():
            assert handle.value == pytest.approx(viewer.values[key], abs=1e-6), key
    finally:
        viewer.stop()
