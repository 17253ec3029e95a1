"""The edit loop: it learns the edit where the edit is and leaves the occluded teeth alone, the
step compiles once, runs the same sharded over two devices, resumes exactly, and the CLI refuses
bad input clearly."""

import dataclasses

import jax
import numpy as np
import pytest
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from gae_jax.scene import synthetic
from gae_jax import evaluate, train
from gae_jax.model import head
from gae_jax import reconstruct as rc
from tests.helpers import near

SIZE = 96



@pytest.fixture(scope="module")
def base(tmp_path_factory):
    scene = synthetic.make_synthetic_scene(size=SIZE, num_cameras=9, frames_per_sequence=3,
                                      cache_dir=str(tmp_path_factory.mktemp("c")),
                                      progress=False)
    model, assets = head.make_head()
    original = rc.initial_avatar(model, scene, assets, rc.ReconstructConfig(),
                                 jax.random.PRNGKey(0))
    return scene, original


def session_for(base, **overrides):
    scene, original = base
    config = train.preset("fast", **{**dict(size=SIZE, editor_noise=0.0, checkpoint_every=0),
                                      **overrides})
    return train.setup(config, scene=scene, original=original)


def test_a_short_edit_turns_the_lips_and_leaves_the_teeth(base):
    s = session_for(base, iterations=40, lr=5e-2)
    edited, history = train.edit_avatar(s)
    assert len(history) == 40 and all(np.isfinite(h["recon"]) for h in history)
    assert np.mean([h["recon"] for h in history[-10:]]) < np.mean(
        [h["recon"] for h in history[:5]])
    teeth_id = head.REGION_ID["teeth"]
    shown = [(n, t) for n in ("talk", "jaw", "mix") for t in range(3)
             if (s.scene.regions[n][:, t] == teeth_id).sum() > 20]
    protocol = evaluate.ProtocolFrames("teeth_shown", shown, tuple(range(9)))
    verts = train.protocol_vertices(s, protocol)
    before = train.render_avatar_frames(s, s.original, verts, protocol.cameras)
    after = train.render_avatar_frames(s, edited, verts, protocol.cameras)
    _, regions = evaluate.ideal_frames(s.scene, s.model, s.assets, s.assets.vertex_colors,
                                       protocol)
    lips = regions == head.REGION_ID["lips"]
    # Teeth pixels not next to a lip pixel (a lip Gaussian's tail covers its neighbours).
    teeth = (regions == head.REGION_ID["teeth"]) & ~near(lips)
    assert lips.sum() > 20 and teeth.sum() > 3
    blue_gain = (after[..., 2] - before[..., 2])[lips].mean()
    teeth_change = np.abs(after - before).max(-1)[teeth].mean()
    assert blue_gain > 0.1, blue_gain
    assert teeth_change < 0.5 * blue_gain, (teeth_change, blue_gain)


def test_step_compiles_once(base):
    s = session_for(base, iterations=3)
    train.edit_avatar(s)
    assert s.step._cache_size() == 1
    assert s.preview._cache_size() == 1


def test_resume_after_interruption_equals_the_uninterrupted_run(base, tmp_path):
    s = session_for(base, iterations=6, checkpoint_every=3, editor_noise=0.5)
    full, full_history = train.edit_avatar(s, str(tmp_path / "a"))
    train.edit_avatar(s, str(tmp_path / "b"), stop_after=4)  # checkpoint at 3, dies at 4
    resumed, history = train.edit_avatar(s, str(tmp_path / "b"), resume=True)
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(history) == len(full_history) == 6
    other = session_for(base, iterations=7, checkpoint_every=3, editor_noise=0.5)
    with pytest.raises(ValueError, match="different EditConfig"):
        train.edit_avatar(other, str(tmp_path / "b"), resume=True)


def test_sharded_batch_over_two_devices_equals_one_device(base):
    assert len(jax.devices()) >= 2, "conftest forces two CPU devices"
    s = session_for(base, batch=2)
    state = train.initial_state(s)
    editing = train.Editing(s)
    batch = editing.batch(state.params, 0, jax.random.PRNGKey(0))
    single, m1 = s.step(state, batch)
    mesh = Mesh(np.array(jax.devices()[:2]), ("data",))
    sharded_batch = {k: jax.device_put(v, NamedSharding(mesh, PartitionSpec("data")))
                     for k, v in batch.items()}
    replicated = jax.device_put(state, NamedSharding(mesh, PartitionSpec()))
    double, m2 = s.step(replicated, sharded_batch)
    assert len(sharded_batch["target"].sharding.device_set) == 2
    for a, b in zip(jax.tree_util.tree_leaves(single), jax.tree_util.tree_leaves(double)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-5, atol=2e-6)
    np.testing.assert_allclose(float(m1["recon"]), float(m2["recon"]), rtol=1e-5)


def test_in2n_dataset_update_replaces_one_image_per_iteration(base):
    s = session_for(base, iterations=4, dataset_update=True, adversarial=False,
                    blend="standard")
    editing = train.Editing(s)
    state = train.initial_state(s)
    for i in range(4):
        editing.batch(state.params, i, jax.random.PRNGKey(0))
    assert sorted(editing.dataset) == sorted(editing.spots[:4])


def test_config_and_cli_refuse_bad_input_clearly(capsys):
    with pytest.raises(ValueError, match="blend must be one of"):
        train.EditConfig(blend="additive")
    with pytest.raises(ValueError, match="unknown preset"):
        train.preset("best")
    with pytest.raises(SystemExit):
        train.main(["--iterations", "many"])
    assert "invalid int value" in capsys.readouterr().err
    assert train.main(["--prompt", "make him look older"]) == 2
    assert "understands regions:" in capsys.readouterr().err
    assert train.main(["--editor", "ip2p", "--ip2p-folder", "/nonexistent"]) == 2
    assert "model_index.json" in capsys.readouterr().err
    assert train.main(["--editor", "ip2p"]) == 2
    assert "--ip2p-folder" in capsys.readouterr().err
    text = train.parser().format_help()
    for field in dataclasses.fields(train.EditConfig):
        assert "--" + field.name.replace("_", "-") in text
    assert set(train.HELP) == {f.name for f in dataclasses.fields(train.EditConfig)}


def test_every_preset_is_a_valid_config():
    for name in train.PRESETS:
        config = train.preset(name)
        assert isinstance(config, train.EditConfig)
    assert train.preset("paper").blend == "wabe" and train.preset("paper").iterations == 1000
    assert train.preset("in2n").dataset_update and not train.preset("in2n").adversarial
    assert train.preset("code").pair_mode == "code"


def test_run_writes_outputs_and_the_evaluate_cli_rescores_them(base, tmp_path, monkeypatch,
                                                                capsys):
    import json

    from tests.test_clip_score import tiny_clip_folder

    scene, original = base
    real_setup = train.setup
    monkeypatch.setattr(train, "setup", lambda config, progress=False: real_setup(
        config, scene=scene, original=original))
    config = train.preset("fast", size=SIZE, iterations=3, checkpoint_every=0)
    out = tmp_path / "run"
    metrics = train.run(config, str(out), progress=False, video=False)
    for name in ("metrics.json", "grid.png", "edited_posed.ply", "edited_avatar/point_cloud.ply",
                 "edited_avatar/flame_param.npz"):
        assert (out / name).is_file(), name
    written = metrics["evaluation"]
    assert "skipped" in written["clip"]
    for name in evaluate.PROTOCOLS:
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
    for name in evaluate.PROTOCOLS:
        # the reloaded .ply scores as the in-memory avatar did (SH DC round trip)
        assert again[name]["ours"]["psnr"]["whole"] == pytest.approx(
            written[name]["ours"]["psnr"]["whole"], abs=0.01)
        assert -1 <= again[name]["clip_s"] <= 1 and -1 <= again[name]["clip_c"] <= 1
    assert (out / "evaluation.md").read_text().startswith("| protocol |")
