"""The edit loop: it learns the edit where the edit is and leaves the occluded teeth alone, the
step compiles once, runs the same sharded over two devices (through the loop itself), resumes
exactly, and the CLI refuses bad input clearly."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax import evaluate, train
from gae_jax.edit import calibration
from gae_jax.edit import config as edit_config
from gae_jax.edit import edit, sampler
from gae_jax.edit import region as region_module
from gae_jax.edit import step as step_module
from gae_jax.evaluation import protocols, truth
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import initial_avatar
from gae_jax.model import head
from gae_jax.render import losses
from gae_jax.run import job
from gae_jax.scene import rig as rigs
from gae_jax.scene import synthetic
from gae_jax.scene.load import SCENE_HELP, SceneConfig
from gae_jax.viewer import source
from tests.helpers import near

SIZE = 96


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    scene = synthetic.make_synthetic_scene(size=SIZE, num_cameras=9, frames_per_sequence=3,
                                           cache_dir=str(tmp_path_factory.mktemp("c")),
                                           progress=False)
    original = initial_avatar(scene, ReconstructConfig(), jax.random.PRNGKey(0))
    return scene, original


def session_for(base, **overrides):
    scene, original = base
    config = edit_config.preset("fast", **{**dict(editor_noise=0.0, checkpoint_every=0),
                                           **overrides})
    return edit.setup(config, scene, original)


def test_a_short_edit_turns_the_lips_and_leaves_the_teeth(base):
    s = session_for(base, iterations=40, lr=5e-2)
    edited, history = edit.edit_avatar(s)
    assert len(history) == 40 and all(np.isfinite(h["recon"]) for h in history)
    assert np.mean([h["recon"] for h in history[-10:]]) < np.mean(
        [h["recon"] for h in history[:5]])
    teeth_id = head.REGION_ID["teeth"]
    shown = [(n, t) for n in ("talk", "jaw", "mix") for t in range(3)
             if (s.scene.regions[n][:, t] == teeth_id).sum() > 20]
    frames = truth.frames_truth(s.scene, protocols.ProtocolFrames("teeth_shown", shown,
                                                                  tuple(range(9))),
                                s.scene.albedo["A"])
    rig = rigs.with_vertices(s.rig, frames.vertices)
    render = rigs.make_view_renderer(s.step_config.blend)
    before = rigs.render_views(render, s.original.trainable(), rig, frames.cameras)
    after = rigs.render_views(render, edited.trainable(), rig, frames.cameras)
    lips = frames.regions == head.REGION_ID["lips"]
    # Teeth pixels not next to a lip pixel (a lip Gaussian's tail covers its neighbours).
    teeth = (frames.regions == head.REGION_ID["teeth"]) & ~near(lips)
    assert lips.sum() > 20 and teeth.sum() > 3
    blue_gain = (after[..., 2] - before[..., 2])[lips].mean()
    teeth_change = np.abs(after - before).max(-1)[teeth].mean()
    assert blue_gain > 0.1, blue_gain
    assert teeth_change < 0.5 * blue_gain, (teeth_change, blue_gain)


def test_auto_region_traces_the_edited_lips_and_resumes_with_its_votes(base, tmp_path):
    """`--region auto` from the 2D edits alone: the traced Gaussians are the lips' (and a
    fringe around them), never the hair; a resumed run reproduces the votes exactly."""
    s = session_for(base, iterations=6, checkpoint_every=3, region="auto", editor_noise=0.3)
    full, _ = edit.edit_avatar(s, str(tmp_path / "a"))
    edit.edit_avatar(s, str(tmp_path / "b"), stop_after=4)
    resumed, _ = edit.edit_avatar(s, str(tmp_path / "b"), resume=True)
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    sampler_ = edit.make_sampler(s)
    params = s.original.trainable()
    for i in range(6):
        sampler_.batch(params, i, jax.random.PRNGKey(0))
    chosen = sampler_.editable()
    labels = np.asarray(s.original.regions)
    lips = labels == head.REGION_ID["lips"]
    assert chosen.sum() > 20
    assert (chosen & lips).sum() / chosen.sum() > 0.7, (chosen & lips).sum() / chosen.sum()
    assert not (chosen & (labels == head.REGION_ID["hair"])).any()
    moved = np.asarray(full.colors != s.original.colors).reshape(len(labels), -1).any(1)
    assert lips[moved].mean() > 0.7


def test_step_compiles_once(base):
    """One compilation of the step, and one of the preview and of the view renderer for rigs
    of every length (the edit's, the grid's 3 frames, one frame)."""
    s = session_for(base, iterations=3)
    edit.edit_avatar(s)
    assert s.step._cache_size() == 1
    render = rigs.make_view_renderer(s.step_config.blend)
    # one renderer per blend and process (lru_cache): other tests may have compiled it already
    compiled_before = render.jitted._cache_size()
    params = s.original.trainable()
    images = []
    for rig in (s.rig, rigs.with_vertices(s.rig, np.asarray(s.rig.vertices)[[2, 0, 1]]),
                rigs.with_vertices(s.rig, np.asarray(s.rig.vertices)[1:2])):
        frame = jnp.int32(0 if rig.vertices.shape[0] == 1 else 1)
        images.append((np.asarray(s.preview(params, rig, jnp.int32(2), frame,
                                            s.canonical).image),
                       np.asarray(render(params, rig, frame, jnp.int32(2)))))
    assert s.preview.jitted._cache_size() == 1
    assert render.jitted._cache_size() - compiled_before <= 1
    # Frame 1 of the first rig, frame 1 (the original 0) of the second, 0 of the third.
    np.testing.assert_array_equal(images[0][0], images[2][0])
    np.testing.assert_array_equal(images[0][1], images[2][1])
    assert np.abs(images[0][1] - images[1][1]).max() > 1e-3


def test_resume_after_interruption_equals_the_uninterrupted_run(base, tmp_path):
    s = session_for(base, iterations=6, checkpoint_every=3, editor_noise=0.5)
    full, full_history = edit.edit_avatar(s, str(tmp_path / "a"))
    edit.edit_avatar(s, str(tmp_path / "b"), stop_after=4)  # checkpoint at 3, dies at 4
    resumed, history = edit.edit_avatar(s, str(tmp_path / "b"), resume=True)
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(history) == len(full_history) == 6
    other = session_for(base, iterations=7, checkpoint_every=3, editor_noise=0.5, lr=2e-2)
    with pytest.raises(ValueError, match=r"different EditConfig: lr \(there 0.1, here 0.02\);"):
        edit.edit_avatar(other, str(tmp_path / "b"), resume=True)


def test_sharded_run_over_two_devices_equals_one_device(base, tmp_path, monkeypatch):
    """Through `run.job.run` (the CLI's job): batch 2 is split over a ("data",) mesh of the two
    forced CPU devices, and the edited avatar equals the single-device run's."""
    from gae_jax.model import avatar_io

    assert len(jax.devices()) >= 2, "conftest forces two CPU devices"
    scene, original = base
    config = edit_config.preset("fast", batch=2, iterations=2, checkpoint_every=0,
                                editor_noise=0.0)
    assert sampler.data_mesh(2).devices.size == 2
    placed = []
    real_put = sampler.put_batch

    def spy(batch, mesh):
        out = real_put(batch, mesh)
        placed.append(len(out["target"].sharding.device_set))
        return out

    monkeypatch.setattr(edit, "put_batch", spy)
    m2 = job.run(config, str(tmp_path / "two"), scene, original, progress=False, video=False)
    assert placed == [2, 2]
    monkeypatch.setattr(edit, "data_mesh", lambda batch: None)
    m1 = job.run(config, str(tmp_path / "one"), scene, original, progress=False, video=False)
    assert placed[2:] == [1, 1]
    one, two = (avatar_io.load_avatar_ply(str(tmp_path / d / "edited_avatar" / "point_cloud.ply"))
                for d in ("one", "two"))
    # Two devices sum the batch's gradients in another order; Adam's division by sqrt(v) + eps
    # turns that last-bit difference into up to ~1e-5 (SH DC units) for Gaussians whose gradient
    # is tiny (measured: 14 of 28776 values above 2e-6 after two steps, none above 1.2e-5).
    for a, b in zip(jax.tree_util.tree_leaves(one), jax.tree_util.tree_leaves(two)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-5, atol=3e-5)
    assert m1["final_losses"]["recon"] == pytest.approx(m2["final_losses"]["recon"], rel=1e-5)


def test_in2n_dataset_update_replaces_one_image_per_iteration(base):
    s = session_for(base, iterations=4, dataset_update=True, adversarial=False,
                    blend="standard")
    edits = edit.make_sampler(s)
    params = s.original.trainable()
    for i in range(4):
        edits.batch(params, i, jax.random.PRNGKey(0))
    assert sorted(edits.dataset) == sorted(edits.spots[:4])


def test_config_and_cli_refuse_bad_input_clearly(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the default --out runs/edit must not hold a run already
    with pytest.raises(ValueError, match="blend must be one of"):
        edit_config.EditConfig(blend="additive")
    with pytest.raises(ValueError, match="checkpoint_every must be >= 0"):
        edit_config.EditConfig(checkpoint_every=-1)
    with pytest.raises(ValueError, match="unknown preset"):
        edit_config.preset("best")
    with pytest.raises(SystemExit):
        train.main(["--iterations", "many"])
    assert "invalid int value" in capsys.readouterr().err
    assert train.main(["--prompt", "make him look older"]) == 2
    assert "understands regions:" in capsys.readouterr().err
    assert train.main(["--editor", "ip2p", "--ip2p-folder", "/nonexistent"]) == 2
    assert "model_index.json" in capsys.readouterr().err
    assert train.main(["--editor", "ip2p"]) == 2
    assert "--ip2p-folder" in capsys.readouterr().err
    assert train.main(["--data", "/nonexistent/folder"]) == 2
    assert "error: /nonexistent/folder: no such folder" in capsys.readouterr().err
    text = train.parser().format_help()
    for cls in (edit_config.EditConfig, SceneConfig):
        for field in dataclasses.fields(cls):
            assert "--" + field.name.replace("_", "-") in text
    assert set(edit_config.HELP) == {f.name for f in dataclasses.fields(edit_config.EditConfig)}
    assert set(SCENE_HELP) == {f.name for f in dataclasses.fields(SceneConfig)}


def test_presets_differ_from_the_default_where_they_say():
    default = dataclasses.asdict(edit_config.preset("fast"))
    for name, knobs in edit_config.PRESETS.items():
        config = dataclasses.asdict(edit_config.preset(name))
        changed = {k for k in config if config[k] != default[k]}
        assert changed == {k for k, v in knobs.items() if default[k] != v}, name
        if name != "fast":
            assert changed, f"preset {name} is the default under another name"


def test_step_config_holds_what_the_step_reads_and_only_that(base):
    a = edit_config.StepConfig.of(edit_config.preset("fast", prompt="turn the hair white",
                                                     seed=3, iterations=7, editor_noise=0.9))
    assert a == edit_config.StepConfig.of(edit_config.preset("fast"))
    assert hash(a) == hash(edit_config.StepConfig.of(edit_config.preset("fast")))
    assert a != edit_config.StepConfig.of(edit_config.preset("no_adv"))


def test_run_writes_a_self_contained_folder_that_evaluate_rescores(base, tmp_path, capsys):
    from tests.test_clip_score import tiny_clip_folder

    scene, original = base
    config = edit_config.preset("fast", iterations=3, checkpoint_every=0)
    out = tmp_path / "run"
    metrics = job.run(config, str(out), scene, original, progress=False, video=False)
    for name in ("metrics.json", "grid.png", "edited_posed.ply", truth.FILE_NAME,
                 "edited_avatar/point_cloud.ply", "edited_avatar/flame_param.npz",
                 "original_avatar/point_cloud.ply", "motion.npz"):
        assert (out / name).is_file(), name
    # the folder records the head of the scene it was given, not the CLI's default head
    assert scene.head == metrics["scene"]["head"] == "procedural" != SceneConfig().head
    # the viewer reads the folder alone: both avatars, the scene's every sequence and identity
    viewable = source.from_run(str(out))
    assert set(viewable.sequences) == set(scene.sequences)
    assert set(viewable.shapes) == set(scene.shapes) and viewable.avatars["edited"].num == \
        original.num
    written = metrics["evaluation"]
    assert "skipped" in written["clip"] and written["truth"] == "ideal edit"
    for name in protocols.PROTOCOLS:
        for metric in ("psnr", "ssim", "lpips"):
            assert set(written[name]["ours"][metric]) >= {"whole", "edited", "teeth", "rest"}
        assert np.isfinite(written[name]["flicker"]["ours"]["whole"])

    clip_dir = tmp_path / "clip"
    clip_dir.mkdir()
    tiny_clip_folder(clip_dir)
    assert evaluate.main([str(out), "--clip-folder", str(clip_dir)]) == 0
    table = capsys.readouterr().out
    assert "| novel_view | ours |" in table
    again = json.loads((out / "evaluation.json").read_text())
    for name in protocols.PROTOCOLS:
        for who in ("ours", "original_avatar"):
            # the reloaded .ply files score as the in-memory avatars did (SH DC round trip)
            assert again[name][who]["psnr"]["whole"] == pytest.approx(
                written[name][who]["psnr"]["whole"], abs=0.01)
        assert -1 <= again[name]["clip_s"] <= 1 and -1 <= again[name]["clip_c"] <= 1
    assert (out / "evaluation.md").read_text().startswith("| protocol |")



def test_learning_rates_decay_to_their_final_fraction_and_stay():
    config = edit_config.StepConfig.of(edit_config.preset("fast", lr=0.08, lr_final=0.25,
                                                          lr_decay_steps=10))
    opt = step_module.avatar_optimizer(config)
    params = {k: np.zeros((1, 3), np.float32) for k in ("means", "quats", "log_scales",
                                                          "colors")}
    params["opacity_logits"] = np.zeros((1,), np.float32)
    state = opt.init(params)
    grads = jax.tree_util.tree_map(np.ones_like, params)
    moves = []
    for _ in range(25):
        with jax.numpy_dtype_promotion("standard"):
            updates, state = opt.update(grads, state, params)
        moves.append(float(-updates["colors"][0, 0]))
    # Adam's first step with a constant gradient moves by the rate itself.
    expected = [0.08 * max(0.25 ** (t / 10), 0.25) for t in range(25)]
    np.testing.assert_allclose(moves, expected, rtol=1e-4)


def test_sgd_moves_in_proportion_to_the_gradient_with_heavy_ball_momentum():
    config = edit_config.StepConfig.of(edit_config.preset(
        "fast", optimizer="sgd", lr=2.0, lr_geometry=0.5, lr_means=0.25, lr_final=1.0))
    opt = step_module.avatar_optimizer(config)
    params = {k: np.zeros((2, 3), np.float32) for k in ("means", "quats", "log_scales",
                                                          "colors")}
    params["opacity_logits"] = np.zeros((2,), np.float32)
    state = opt.init(params)
    # Two Gaussians, the second's gradient a tenth of the first's (a WABE weight of 0.1).
    scale = np.array([1.0, 0.1], np.float32)
    grad_at = [1e-3, -2e-3, 5e-4]
    velocity, colors_moves, means_moves = np.zeros(2), [], []
    for g in grad_at:
        grads = {k: np.ones_like(v) * g * scale.reshape((2,) + (1,) * (v.ndim - 1))
                 for k, v in params.items()}
        with jax.numpy_dtype_promotion("standard"):
            updates, state = opt.update(grads, state, params)
        colors_moves.append(np.asarray(updates["colors"][:, 0]))
        means_moves.append(np.asarray(updates["means"][:, 0]))
        velocity = step_module.SGD_MOMENTUM * velocity + g * scale
        np.testing.assert_allclose(colors_moves[-1], -2.0 * velocity, rtol=1e-5)
        np.testing.assert_allclose(means_moves[-1], -0.25 * velocity, rtol=1e-5)
    # Unlike Adam, the weighted Gaussian moves a tenth as far.
    np.testing.assert_allclose(colors_moves[-1][1] / colors_moves[-1][0], 0.1, rtol=1e-5)


def test_edit_loss_weighs_one_minus_ssim_beside_l1_as_configured(base):
    from tests.test_losses import naive_ssim

    s = session_for(base, adversarial=False)
    render = rigs.render_bound(s.original.trainable(), s.rig, 1, 2,
                               blend=s.step_config.blend).image
    image = np.asarray(render, np.float64)
    target = np.clip(image + np.random.default_rng(0).normal(0, 0.1, image.shape), 0, 1)
    batch = dict(cams=np.array([2], np.int32), frames=np.array([1], np.int32),
                 target=target[None].astype(np.float32), neighbour=target[None].astype(np.float32))
    l1 = np.abs(image - target).mean()
    one_minus_ssim = 1 - naive_ssim(image, target).mean()
    editable = np.ones(s.original.num, bool)
    for weight in (0.0, 0.2, 1.0):
        config = edit_config.StepConfig.of(dataclasses.replace(s.config, ssim_weight=weight))
        state = step_module.initial_state(config, s.original.trainable(), (SIZE, SIZE),
                                          jax.random.PRNGKey(0))
        _, metrics = step_module.make_edit_step(config)(state, s.rig, batch, editable)
        assert float(metrics["recon"]) == pytest.approx(l1 + weight * one_minus_ssim, rel=1e-4)


def _step_d_losses(base, field: str, values, seed: int):
    """The edit step's discriminator loss with `field` at each of `values`, on one noisy
    (target, neighbour) pair around the render of camera 2, frame 1, with a fresh
    discriminator (the same draw each time). Returns (session, render, target, neighbour,
    d_params, {value: loss})."""
    s = session_for(base, adversarial=True)
    render = np.asarray(rigs.render_bound(s.original.trainable(), s.rig, 1, 2,
                                          blend=s.step_config.blend).image)
    rng = np.random.default_rng(seed)
    target = np.clip(render + rng.normal(0, 0.1, render.shape), 0, 1)[None].astype(np.float32)
    neighbour = np.clip(render + rng.normal(0, 0.1, render.shape), 0, 1)[None].astype(np.float32)
    batch = dict(cams=np.array([2], np.int32), frames=np.array([1], np.int32), target=target,
                 neighbour=neighbour)
    editable = np.ones(s.original.num, bool)
    losses = {}
    for value in values:
        config = edit_config.StepConfig.of(dataclasses.replace(s.config, **{field: value}))
        state = step_module.initial_state(config, s.original.trainable(), (SIZE, SIZE),
                                          jax.random.PRNGKey(0))
        d_params = jax.tree_util.tree_map(np.asarray, state.d_params)  # the step donates
        _, metrics = step_module.make_edit_step(config)(state, s.rig, batch, editable)
        losses[value] = float(metrics["d_loss"])
    return s, render, target, neighbour, d_params, losses


def test_discriminator_sees_pairs_at_gan_max_side(base):
    """The step's discriminator loss is that of the pairs resized to `gan_max_side` (48 of 96:
    a 4x4 patch map instead of 10x10), and a cap at the image size changes nothing."""
    from gae_jax.edit import gan

    s, render, target, neighbour, d_params, losses = _step_d_losses(
        base, "gan_max_side", (0, SIZE, 48), 1)
    real, fake = gan.make_pairs("paper", target, neighbour, render[None])
    disc = gan.Discriminator()
    assert disc.apply(d_params, gan.downscale(real, 48)).shape == (1, 4, 4, 1)
    expected = s.config.d_weight * gan.d_loss(disc.apply(d_params, gan.downscale(real, 48)),
                                              disc.apply(d_params, gan.downscale(fake, 48)))
    full = s.config.d_weight * gan.d_loss(disc.apply(d_params, real), disc.apply(d_params, fake))
    assert losses[48] == pytest.approx(float(expected), rel=1e-4)
    assert losses[0] == losses[SIZE] == pytest.approx(float(full), rel=1e-4)
    assert abs(losses[48] - losses[0]) > 1e-4 * abs(losses[0])


def test_a_region_most_views_hide_is_edited_from_the_views_that_show_it(base):
    """The teeth show in a minority of views: the sampler draws only views whose projected
    labels show at least a quarter of what a well-showing view does (the definition, brute
    force); the lips show everywhere and keep the independent draw."""
    scene, _ = base
    s = session_for(base, prompt="make the teeth black", iterations=2)
    draw = edit.make_sampler(s)
    labels = np.concatenate([scene.regions[n] for n in scene.sequences_of("train")], axis=1)
    counts = (labels == head.REGION_ID["teeth"]).sum((-2, -1))
    threshold = max(1.0, sampler.SHOWING_FRACTION * np.percentile(
        counts[np.asarray(scene.train_cameras)], 90))
    expected = {(c, r) for c in scene.train_cameras for r in range(counts.shape[1])
                if counts[c, r] >= threshold}
    assert 0 < len(expected) < 0.9 * len(scene.train_cameras) * counts.shape[1]
    assert {tuple(v) for v in draw.showing.tolist()} == expected
    for i in range(6):
        b = draw.batch(s.original.trainable(), i, jax.random.PRNGKey(3))
        assert (int(b["cams"][0]), int(b["frames"][0])) in expected
    assert edit.make_sampler(session_for(base, iterations=2)).showing is None


def test_one_device_call_draws_the_indices_the_per_call_draws_would():
    """`sampler.draw` against the draws made one `jax.random` call at a time (the reference):
    the same cameras, frame rows, neighbour choices and edit keys, in both sampling modes."""
    key, batch = jax.random.PRNGKey(5), 3
    cameras = np.array([0, 2, 3, 5, 7])
    showing = np.array([[2, 4], [3, 9], [5, 1], [7, 7]])
    choices = np.array([1, 2, 2, 1, 3, 2, 2, 1, 2, 2])
    for i in (0, 1, 17):
        for uniform in (True, False):
            k_sample, k_edit = jax.random.split(jax.random.fold_in(key, i))
            if uniform:
                cams = cameras[np.asarray(jax.random.randint(k_sample, (batch,), 0,
                                                             len(cameras)))]
                rows = np.asarray(jax.random.randint(jax.random.fold_in(k_sample, 1),
                                                     (batch,), 0, len(choices)))
            else:
                cams, rows = showing[np.asarray(jax.random.randint(k_sample, (batch,), 0,
                                                                   len(showing)))].T
            edit_keys = jax.random.split(k_edit, 2 * batch + 1)
            picks = [int(jax.random.randint(edit_keys[batch + b], (), 0, choices[r]))
                     for b, r in enumerate(rows)]
            got = jax.device_get(sampler.draw(key, i, batch, uniform, jnp.asarray(cameras),
                                              len(choices), jnp.asarray(showing),
                                              jnp.asarray(choices)))
            np.testing.assert_array_equal(got[0], cams)
            np.testing.assert_array_equal(got[1], rows)
            np.testing.assert_array_equal(got[2], picks)
            np.testing.assert_array_equal(got[3], np.asarray(edit_keys))


@pytest.mark.parametrize("decay", [0.0, 0.5, 0.9])
def test_the_running_average_weighs_each_iterate_as_its_closed_form(decay):
    """After T steps the average is sum_k (1 - d) d^(T - k) x_k / sum_k (1 - d) d^(T - k) over
    the iterates x_1 .. x_T alone (the starting params weigh nothing); d = 0: x_T."""
    rng = np.random.default_rng(0)
    iterates = [{"colors": rng.normal(size=(4, 3)), "opacity_logits": rng.normal(size=(4,))}
                for _ in range(7)]
    average = {k: np.full_like(v, 1e3) for k, v in iterates[0].items()}  # weighs nothing
    for t, x in enumerate(iterates, start=1):
        average = step_module.average_params(average, x, jnp.int32(t), decay)
        weights = np.array([(1 - decay) * decay ** (t - k) if decay else float(k == t)
                            for k in range(1, t + 1)])
        for name in x:
            expected = np.tensordot(weights / weights.sum(),
                                    np.stack([it[name] for it in iterates[:t]]), 1)
            np.testing.assert_allclose(np.asarray(average[name]), expected, rtol=1e-5,
                                       atol=1e-5)


def test_the_released_edit_is_the_average_and_moves_nothing_outside_its_region(base):
    """The edit releases the running average of its iterates; a Gaussian outside the region
    keeps its original params bit for bit in it, as in the last iterate."""
    s = session_for(base, iterations=6, lr=5e-2, editor_noise=0.3, average_decay=0.8)
    edited, _ = edit.edit_avatar(s)
    sampler_ = edit.make_sampler(s)
    state = edit.fresh_state(s)
    iterates = []
    for i in range(6):
        batch = sampler.put_batch(sampler_.batch(state.params, i, jax.random.PRNGKey(0)), None)
        state, _ = s.step(state, s.rig, batch, jnp.asarray(sampler_.editable()))
        iterates.append(jax.device_get(state.params))
    outside = ~sampler_.editable()
    assert outside.sum() > 100
    for name, value in edited.trainable().items():
        weights = np.array([0.2 * 0.8 ** (6 - k) for k in range(1, 7)])
        expected = np.tensordot(weights / weights.sum(),
                                np.stack([np.asarray(a[name]) for a in iterates]), 1)
        np.testing.assert_allclose(np.asarray(value), expected, rtol=1e-4, atol=1e-5)
        np.testing.assert_array_equal(np.asarray(value)[outside],
                                      np.asarray(s.original.trainable()[name])[outside])
    # the release is not the last iterate
    assert not np.allclose(np.asarray(edited.colors), np.asarray(iterates[-1]["colors"]))


def test_changed_share_is_the_share_of_region_pixels_changed_beyond_the_threshold():
    """`region.changed_share` against a count pixel by pixel and channel by channel."""
    rng = np.random.default_rng(1)
    unedited = rng.uniform(size=(20, 24, 3)).astype(np.float32)
    edited = unedited.copy()
    edited[5:12, 6:15, 2] += rng.uniform(0.0, 0.3, size=(7, 9)).astype(np.float32)
    edited[0:4, 0:3, 0] -= 0.5  # outside the region
    inside = np.zeros((20, 24), bool)
    inside[3:16, 4:18] = True
    count = sum(any(abs(float(edited[y, x, c]) - float(unedited[y, x, c])) > 0.1
                    for c in range(3)) for y in range(20) for x in range(24) if inside[y, x])
    expected = count / inside.sum()
    assert 0.1 < expected < 0.5
    assert region_module.changed_share(edited, unedited, inside, 0.1) == pytest.approx(expected)
    assert region_module.changed_share(edited, unedited, np.zeros_like(inside), 0.1) == 0.0


class HalfEditor:
    """Paints the region the prompt names blue in every call, or only its upper half in calls
    whose key says so (`partial(key)`); records the keys it was called with."""

    def __init__(self, partial):
        self.partial, self.keys = partial, []

    def edit(self, render, original, prompt, key, context):
        self.keys.append(np.asarray(key))
        region = context["regions"] == head.REGION_ID["lips"]
        if self.partial(key):
            rows = np.nonzero(region.any(1))[0]
            region = region & (np.arange(region.shape[0])[:, None] < np.median(rows))
        out = np.array(original, np.float32)
        out[region] = (0.0, 0.0, 1.0)
        return out


def test_a_partial_2d_edit_is_made_again_and_the_whole_one_kept(base):
    """After `USUAL_AFTER` judged edits, an edit that changes half the lips is made again with
    the key folded with RETRY_SALT + 1 and the whole edit is kept; with every try partial the
    one that changed most is; with edit_retries 0 the partial edit stays."""
    s = session_for(base, iterations=2)
    params = s.original.trainable()
    cam, row = int(s.scene.train_cameras[0]), 0
    key = jax.random.PRNGKey(4)
    calls = []

    def whole_edit(editor, retries, k):
        sampler_ = edit.make_sampler(dataclasses.replace(
            s, config=dataclasses.replace(s.config, edit_retries=retries)), editor)
        view = s.preview(params, s.rig, jnp.int32(cam), jnp.int32(row), s.canonical)
        labels = sampler_.labels(cam, row)
        unedited = sampler_.original_image(cam, row) / 255.0
        context = sampler.editor_context(view, (cam, 0, 0), labels)
        for i in range(sampler.USUAL_AFTER):  # whole edits: the usual share
            sampler_.whole_edit(np.asarray(view.image), unedited, context,
                                jax.random.PRNGKey(100 + i), labels)
        calls.append(len(editor.keys))
        out = sampler_.whole_edit(np.asarray(view.image), unedited, context, k, labels)
        lips = labels == head.REGION_ID["lips"]
        assert lips.sum() >= sampler.JUDGED_PIXELS
        return out, lips, sampler_, unedited

    first_only = HalfEditor(lambda k: np.array_equal(np.asarray(k), np.asarray(key)))
    out, lips, sampler_, unedited = whole_edit(first_only, 2, key)
    assert len(first_only.keys) == calls[-1] + 2  # the partial call and one retry
    np.testing.assert_array_equal(first_only.keys[-1], jax.random.fold_in(
        key, sampler.RETRY_SALT + 1))
    assert sampler_.shares[-2] < sampler.PARTIAL * np.median(sampler_.shares[:-2])
    np.testing.assert_allclose(out[lips], np.tile([0.0, 0.0, 1.0], (lips.sum(), 1)))

    never = HalfEditor(lambda k: not any(np.array_equal(np.asarray(k), np.asarray(
        jax.random.PRNGKey(100 + i))) for i in range(sampler.USUAL_AFTER)))
    out, _, sampler_, _ = whole_edit(never, 2, key)
    assert len(never.keys) == calls[-1] + 3
    assert sampler_.shares[-1] == sampler_.shares[-2] == sampler_.shares[-3]
    assert region_module.changed_share(out, unedited, lips, 0.1) == pytest.approx(
        sampler_.shares[-1])

    kept = HalfEditor(lambda k: np.array_equal(np.asarray(k), np.asarray(key)))
    out, _, _, _ = whole_edit(kept, 0, key)
    assert len(kept.keys) == calls[-1] + 1
    assert (np.abs(out - unedited).max(-1)[lips] < 1e-6).mean() > 0.2  # half the lips kept


def test_a_resumed_run_judges_partial_edits_as_the_uninterrupted_one(base, tmp_path):
    """The shares the judged edits changed are checkpointed: with an editor that edits half
    the region in half its calls, a run interrupted after its checkpoint and resumed equals the
    uninterrupted one, and retries did happen."""
    def partial(k):
        return float(jax.random.uniform(jax.random.fold_in(k, 99))) < 0.5

    s = session_for(base, iterations=8, checkpoint_every=4)
    once = HalfEditor(partial)
    full, _ = edit.edit_avatar(s, str(tmp_path / "a"), editor=once)
    retried = [np.array_equal(b, jax.random.fold_in(a, sampler.RETRY_SALT + 1))
               for a, b in zip(once.keys, once.keys[1:])]
    assert sum(retried) >= 2
    edit.edit_avatar(s, str(tmp_path / "b"), stop_after=5, editor=HalfEditor(partial))
    resumed, _ = edit.edit_avatar(s, str(tmp_path / "b"), resume=True,
                                  editor=HalfEditor(partial))
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_coherence_pulls_an_unseen_region_gaussian_to_the_regions_change(base):
    """With no data term (recon_weight 0, no GAN), the change-coherence prior alone moves the
    colours: a region Gaussian left at its old colour while the others were halved
    is pushed darker, every member moves towards the colour its region's mean change (over the
    members of its region label) gives it,
    and nothing moves at step 0 (the prior's ramp) or without the prior."""
    s = session_for(base, adversarial=False, recon_weight=0.0)
    params = s.original.trainable()
    origin = np.asarray(params["colors"])
    members = np.zeros(len(origin), bool)
    members[: len(origin) // 2] = True
    halved = np.where(members[:, None], origin * 0.5, origin)
    halved[0] = origin[0]  # a member left as it was
    moved = dict(params, colors=jnp.asarray(halved, jnp.float32))
    render = rigs.render_bound(moved, s.rig, 1, 2, blend=s.step_config.blend).image
    batch = dict(cams=np.array([2], np.int32), frames=np.array([1], np.int32),
                 target=np.asarray(render)[None], neighbour=np.asarray(render)[None])

    def colour_step(weight, at_step):
        config = edit_config.StepConfig.of(dataclasses.replace(s.config,
                                                               coherence_weight=weight))
        state = step_module.initial_state(config, params, (SIZE, SIZE), jax.random.PRNGKey(0))
        state = dataclasses.replace(state, params=jax.tree_util.tree_map(jnp.array, moved),
                                    step=jnp.int32(at_step))
        after, _ = step_module.make_edit_step(config)(state, s.rig, batch, jnp.asarray(members))
        return np.asarray(after.params["colors"]) - halved

    decay = s.config.lr_decay_steps
    for weight, at_step in ((0.0, decay), (1e-4, 0)):
        np.testing.assert_allclose(colour_step(weight, at_step), 0.0, atol=1e-7)
    change = colour_step(1e-4, decay)
    assert (change[0] < -1e-4).all()  # the unmoved member goes the region's way
    assert not change[~members].any()
    f = losses.CHANGE_FLOOR
    d = np.log(halved + f) - np.log(origin + f)
    groups = np.asarray(s.original.regions)
    means = np.stack([d[members & (groups == g)].mean(0) if (members & (groups == g)).any()
                      else np.zeros(3) for g in range(len(head.REGIONS))])
    pull = halved - (origin + f) * np.exp(means[groups]) + f  # the gradient up to 2 w
    # Adam's first step moves each colour against its gradient's sign
    signs = np.sign(change[members & (np.abs(pull) > 1e-3).all(1)])
    np.testing.assert_array_equal(signs, -np.sign(pull[members & (np.abs(pull) > 1e-3).all(1)]))


def test_base_colour_is_plain_rgb_or_the_sh_degree_zero_band():
    """Plain RGB passes through; SH colours give 0.5 + C0 x DC (3DGS's SH2RGB), floored at 0."""
    rgb = jnp.asarray(np.random.default_rng(0).uniform(0, 1, (5, 3)), jnp.float32)
    np.testing.assert_array_equal(step_module.base_colour(rgb), rgb)
    coeffs = np.zeros((5, 16, 3), np.float32)
    coeffs[:, 0] = [[1.0, -1.0, 0.0], [-3.0, 0.2, 0.5], [0, 0, 0], [2.0, 2.0, 2.0], [-1, 1, -1]]
    coeffs[:, 1:] = 0.3  # higher bands do not enter
    expected = np.maximum(0.5 + 0.28209479177387814 * coeffs[:, 0], 0.0)
    np.testing.assert_allclose(step_module.base_colour(jnp.asarray(coeffs)), expected, rtol=1e-6)


class ContextRecorder:
    """Returns the original image and keeps the context of every call."""

    def __init__(self):
        self.contexts = []

    def edit(self, render, original, prompt, key, context):
        self.contexts.append(context)
        return np.array(original, np.float32)


def test_the_editor_reads_the_label_samples_of_the_view_it_edits(base):
    """The sampler hands the 2D editor the region labels of every ray in each pixel of the
    training view (the tracked mesh projected along them: the scene's 2 x 2 rays), which agree
    with the centre labels wherever all four rays see one region."""
    from gae_jax.scene.types import projected_label_samples

    s = session_for(base, iterations=1)
    recorder = ContextRecorder()
    sampler_ = edit.make_sampler(s, recorder)
    cam, row = int(s.scene.train_cameras[1]), 2
    sampler_.edit(s.original.trainable(), cam, row, jax.random.PRNGKey(0))
    context = recorder.contexts[-1]
    expected = projected_label_samples(s.scene, [s.pairs[row]], [cam])[0, 0]
    assert context["samples"].shape == (SIZE, SIZE, s.scene.supersample ** 2)
    np.testing.assert_array_equal(context["samples"], np.maximum(expected, -1))
    agree = np.all(expected == expected[..., :1], axis=-1)
    assert agree.mean() > 0.8 and (~agree).any()
    np.testing.assert_array_equal(context["regions"][agree], expected[agree][:, 0])


class CastEditor:
    """Recolours a region (the lips) by a gain drawn from the key (a colour cast that differs
    per call): edit = unedited x gain on the region's pixels."""

    def __init__(self, region="lips"):
        self.region, self.gains = region, []

    def edit(self, render, original, prompt, key, context):
        gain = np.asarray(jax.random.uniform(key, (3,), minval=0.4, maxval=1.6), np.float32)
        self.gains.append(gain)
        out = np.array(original, np.float32)
        inside = context["regions"] == head.REGION_ID[self.region]
        out[inside] = np.clip(out[inside] * gain, 0, 1)
        return out


def test_calibration_brings_every_call_to_the_median_cast_of_the_calls_so_far(base):
    """Calls that each recolour the lips by their own cast come out with the per-channel
    median of the casts so far (computed here from the casts themselves) on the lips' pure
    pixels; without calibration each keeps its own; a view without enough lip pixels is
    left as the editor made it and not counted."""
    s = session_for(base, iterations=2)
    params = s.original.trainable()
    views = [(int(c), r) for r in range(3) for c in s.scene.train_cameras]
    for on in (True, False):
        editor = CastEditor()
        sampler_ = edit.make_sampler(dataclasses.replace(
            s, config=dataclasses.replace(s.config, edit_calibration=on)), editor)
        read = []
        for n, (cam, row) in enumerate(views):
            labels = sampler_.labels(cam, row)
            unedited = sampler_.original_image(cam, row) / 255.0
            view = s.preview(params, s.rig, jnp.int32(cam), jnp.int32(row), s.canonical)
            context = sampler.editor_context(view, (cam,) + tuple(sampler_.pairs[row]), labels,
                                             None, sampler_.label_samples(cam, row))
            key = jax.random.PRNGKey(n)
            edited = sampler_.whole_edit(np.asarray(view.image), unedited, context, key, labels)
            out = (sampler_.calibrated(edited, unedited, context["samples"], labels) if on
                   else edited)
            samples = context["samples"]
            pure = (samples == head.REGION_ID["lips"]).all(-1)
            lit = pure & (unedited.max(-1) > calibration.DARK) & (
                np.abs(edited - unedited).max(-1) >= calibration.FULL_CHANGE)
            gain = editor.gains[-1]
            if lit.sum() < calibration.MIN_PIXELS:
                np.testing.assert_array_equal(out, edited)
                continue
            read.append(gain)
            expected = np.median(read, axis=0) if on else gain
            unclipped = lit & (unedited * np.maximum(gain, expected) < 1).all(-1)
            assert unclipped.sum() >= calibration.MIN_PIXELS
            np.testing.assert_allclose(out[unclipped], (unedited * expected)[unclipped],
                                       atol=2e-5)
        assert len(read) >= 5
        if on:
            assert len(sampler_.colours) == len(read)


def test_a_striped_region_is_not_calibrated(base):
    """Stripes are two colours in the region, not one cast: the loop reads no call's colour
    for them, while the same editor's calls on a recolour of the region are read."""
    for prompt, read in (("add green stripes to the skin", False), ("make the skin green", True)):
        s = session_for(base, iterations=2, prompt=prompt)
        sampler_ = edit.make_sampler(s, CastEditor("skin"))
        params = s.original.trainable()
        for n, cam in enumerate(s.scene.train_cameras[:3]):
            sampler_.edit(params, int(cam), 0, jax.random.PRNGKey(n))
        assert (len(sampler_.colours) == 3) if read else (sampler_.colours == [])
