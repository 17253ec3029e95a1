"""What a user can get wrong gets one clear line (exit code 2), and nothing is lost: run folders
are not overwritten by accident, corrupt caches are rebuilt, an unreadable checkpoint falls back
to the previous one, a finished run can be extended, and a corruption sweep over every file the
project reads ends in success with finite values or the project's own error naming the file."""

import dataclasses
import json
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from gae_jax import evaluate, loop, train
from gae_jax.edit import config as edit_config
from gae_jax.edit import edit
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import initial_avatar
from gae_jax.model import avatar_io
from gae_jax.run import job, original
from gae_jax.scene import synthetic
from gae_jax.scene.types import stacked_params
from gae_jax.util.fileio import PlyError

SWEEP_POINTS = 20


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    scene = synthetic.make_synthetic_scene(size=32, num_cameras=6, frames_per_sequence=2,
                                           supersample=1, cache_dir=str(cache), progress=False)
    original = initial_avatar(scene, ReconstructConfig(), jax.random.PRNGKey(0))
    return scene, original, cache


def run_cli(*args):
    """The CLI as a user runs it: a subprocess; (exit code, stderr)."""
    out = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                         timeout=300, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    return out.returncode, out.stderr


def test_bad_run_folders_are_one_line_errors(tmp_path):
    a_file = tmp_path / "file.txt"
    a_file.write_text("not a folder")
    code, err = run_cli("gae_jax.train", "--out", str(a_file))
    assert code == 2 and err.strip() == f"error: --out {a_file}: is a file, not a folder"
    code, err = run_cli("gae_jax.train", "--out", str(a_file / "sub"))
    assert code == 2 and "cannot make the folder (Not a directory)" in err
    assert "Traceback" not in err
    run = tmp_path / "run"
    run.mkdir()
    (run / "metrics.json").write_text("{}")
    code, err = run_cli("gae_jax.train", "--out", str(run))
    assert code == 2 and "already holds a run; pass --overwrite" in err
    code, err = run_cli("gae_jax.train", "--out", str(run), "--resume")
    assert code == 2 and "holds no edit_checkpoint.npz (the run finished" in err
    code, err = run_cli("gae_jax.train", "--out", str(tmp_path / "new"), "--resume")
    assert code == 2 and "(nothing to resume)" in err
    code, err = run_cli("gae_jax.train", "--checkpoint-every", "-1", "--out", str(tmp_path / "x"))
    assert code == 2 and "checkpoint_every must be >= 0" in err


def test_evaluate_on_a_truncated_or_garbage_avatar_is_one_line(small, tmp_path, capsys):
    scene, original, _ = small
    config = edit_config.preset("fast", iterations=1, checkpoint_every=0)
    run = tmp_path / "run"
    job.run(config, str(run), scene, original, progress=False, video=False)
    ply = run / "edited_avatar" / "point_cloud.ply"
    data = ply.read_bytes()
    for broken in (data[: len(data) // 2], b"garbage" * 10):
        ply.write_bytes(broken)
        assert evaluate.main([str(run)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and str(ply) in err and "\n" not in err


def test_corrupt_scene_cache_is_reported_and_rebuilt(small, capsys):
    scene, _, cache = small
    (path,) = [p for p in cache.iterdir() if p.name.startswith("scene-")]
    path.write_bytes(path.read_bytes()[:1000])
    again = synthetic.make_synthetic_scene(size=32, num_cameras=6, frames_per_sequence=2,
                                           supersample=1, cache_dir=str(cache), progress=False)
    assert "the cached scene" in capsys.readouterr().err
    for name in scene.images:
        np.testing.assert_array_equal(again.images[name], scene.images[name])


def test_corrupt_cached_avatar_is_reported_and_refitted(small, tmp_path, monkeypatch, capsys):
    scene, _, _ = small
    monkeypatch.setenv("GAE_JAX_CACHE", str(tmp_path))
    first = original.original_avatar(scene, 2, progress=False)
    (path,) = [p for p in tmp_path.iterdir() if p.name.startswith("avatar-")]
    path.write_bytes(path.read_bytes()[:500])
    again = original.original_avatar(scene, 2, progress=False)
    assert "the cached avatar is unreadable" in capsys.readouterr().err
    np.testing.assert_array_equal(np.asarray(first.means), np.asarray(again.means))


def session_of(small, **overrides):
    scene, original, _ = small
    config = edit_config.preset("fast", **{**dict(editor_noise=0.5, checkpoint_every=2),
                                           **overrides})
    return edit.setup(config, scene, original)


def test_unreadable_checkpoint_falls_back_to_the_previous_one(small, tmp_path, capsys):
    full, _ = edit.edit_avatar(session_of(small, iterations=6), str(tmp_path / "a"))
    folder = str(tmp_path / "b")
    edit.edit_avatar(session_of(small, iterations=6), folder, stop_after=5)  # at 2 and 4
    path = os.path.join(folder, edit.CHECKPOINT)
    assert os.path.isfile(loop.previous_path(path))
    with open(path, "r+b") as f:
        f.truncate(os.path.getsize(path) // 3)
    resumed, history = edit.edit_avatar(session_of(small, iterations=6), folder, resume=True)
    assert "resuming from the previous checkpoint" in capsys.readouterr().err
    for a, b in zip(jax.tree_util.tree_leaves(full), jax.tree_util.tree_leaves(resumed)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(history) == 6


def test_a_finished_run_is_extended_by_more_iterations(small, tmp_path):
    straight, _ = edit.edit_avatar(session_of(small, iterations=5), str(tmp_path / "a"))
    folder = str(tmp_path / "b")
    edit.edit_avatar(session_of(small, iterations=3), folder, keep_checkpoint=True)
    extended, history = edit.edit_avatar(session_of(small, iterations=5), folder, resume=True,
                                         keep_checkpoint=False)
    for a, b in zip(jax.tree_util.tree_leaves(straight), jax.tree_util.tree_leaves(extended)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(history) == 5
    assert not os.path.exists(os.path.join(folder, edit.CHECKPOINT)), "finished: removed"
    edit.edit_avatar(session_of(small, iterations=3), str(tmp_path / "c"), keep_checkpoint=True)
    with pytest.raises(ValueError, match=r"different EditConfig: lr \(there 0.1, here 0.02\)"):
        edit.edit_avatar(session_of(small, iterations=4, lr=0.02), str(tmp_path / "c"),
                         resume=True)


def corrupted(data: bytes, seed: int):
    """SWEEP_POINTS truncations and SWEEP_POINTS single-byte flips of `data`."""
    rng = np.random.default_rng(seed)
    for cut in np.linspace(0, len(data) - 1, SWEEP_POINTS).astype(int):
        yield data[:cut]
    for at in rng.integers(0, len(data), SWEEP_POINTS):
        flipped = bytearray(data)
        flipped[at] ^= 1 << int(rng.integers(0, 8))
        yield bytes(flipped)


def sweep(path, data, load, errors, seed):
    outcomes = {"ok": 0, "refused": 0}
    for i, broken in enumerate(corrupted(data, seed)):
        with open(path, "wb") as f:
            f.write(broken)
        try:
            loaded = load(path)
        except errors as e:
            assert str(path) in str(e), f"case {i}: the error does not name the file: {e}"
            outcomes["refused"] += 1
            continue
        for leaf in jax.tree_util.tree_leaves(loaded):
            arr = np.asarray(leaf)
            if np.issubdtype(arr.dtype, np.floating):
                assert np.all(np.isfinite(arr)), f"case {i}: loaded non-finite values"
        outcomes["ok"] += 1
    assert outcomes["refused"] >= SWEEP_POINTS - 1, outcomes  # every truncation but the 0th
    return outcomes


def test_corruption_sweep_over_every_file_the_project_reads(small, tmp_path):
    scene, original, cache = small
    ply = tmp_path / "point_cloud.ply"
    avatar_io.save_avatar_ply(original, str(ply))
    sweep(ply, ply.read_bytes(), lambda p: avatar_io.load_bound_avatar(str(p),
                                                                        scene.face_regions),
          (PlyError,), 0)

    params = tmp_path / "flame_param.npz"
    avatar_io.save_flame_params(str(params), scene.shapes["A"],
                                stacked_params(scene, scene.sequences_of("train")),
                                num_vertices=scene.model.num_vertices)
    sweep(params, params.read_bytes(), lambda p: avatar_io.load_flame_params(str(p)),
          (ValueError,), 1)

    session = session_of(small, iterations=2, checkpoint_every=1)
    folder = tmp_path / "run"
    edit.edit_avatar(session, str(folder))
    checkpoint = folder / edit.CHECKPOINT
    os.remove(loop.previous_path(str(checkpoint)))  # no fallback: each corruption must show
    template = edit.fresh_state(session)
    sweep(checkpoint, checkpoint.read_bytes(),
          lambda p: loop.load_checkpoint(str(p), dict(state=template), session.config)[0],
          (ValueError,), 2)

    (scene_file,) = [p for p in cache.iterdir() if p.name.startswith("scene-")]
    good = scene_file.read_bytes()
    for i, broken in enumerate(corrupted(good, 3)):
        scene_file.write_bytes(broken)
        images, _, samples = synthetic._read_cache(str(scene_file), scene.sequences,
                                                   (6, 2, 32))
        if images is not None:
            for name in scene.images:  # a zip member's CRC catches any flipped data byte
                np.testing.assert_array_equal(images[name], scene.images[name], f"case {i}")
                np.testing.assert_array_equal(samples[name], scene.region_samples[name],
                                              f"case {i}")
    scene_file.write_bytes(good)



def test_help_shows_real_defaults_and_choices():
    text = train.parser().format_help()
    assert "--editor {semantic,style,ip2p}" in text and "--blend {standard,wabe,wabe_grad}" in text
    assert "(default: 100)" in text and "(default: 0.3)" in text and "(default: None)" not in text
    assert "builds and caches a new scene" in text


def test_the_bar_says_compiling_until_the_first_step_is_done(capsys):
    recorder = loop.Recorder("edit", 3, progress=True)
    before = capsys.readouterr().err
    assert "edit (compiling)" in before
    recorder.push(1, dict(loss=np.float32(1.0)))
    recorder.push(2, dict(loss=np.float32(0.5)))
    after = capsys.readouterr().err
    assert "edit:" in after and "compiling" not in after.split("\r")[-1]
    assert recorder.close() == [dict(loss=1.0), dict(loss=0.5)]


def test_the_video_is_labelled_smooth_and_warns_of_nothing(small, tmp_path):
    import warnings

    import imageio.v2 as imageio

    from gae_jax.run import outputs

    session = session_of(small, iterations=1)
    path = str(tmp_path / "reenactment.mp4")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outputs.write_video(session.scene, session.rig, session.step_config.blend,
                            session.original, session.original, path)
    assert not [w for w in caught if "fork" in str(w.message)]
    with warnings.catch_warnings():  # the test's own ffmpeg reader forks too
        warnings.simplefilter("ignore", RuntimeWarning)
        reader = imageio.get_reader(path)
        frames = [f for f in reader]
    assert reader.get_meta_data()["fps"] == 24
    scene = session.scene
    # two sequences of 2 frames, 3 steps between frames: 4 frames each; header + two panels
    assert len(frames) == 2 * ((2 - 1) * 3 + 1)
    assert frames[0].shape == (14 + scene.height, 2 * scene.width, 3)


def test_a_checkpoint_written_before_a_field_existed_reads_it_as_that_run_behaved():
    config = edit_config.EditConfig()
    saved = json.loads(json.dumps(dataclasses.asdict(config)))
    del saved["editor_bleed"]
    loop.check_config(saved, config, "ckpt")  # the old run behaved as bleed 0
    with pytest.raises(ValueError, match=r"editor_bleed \(there 0, here 2\)"):
        loop.check_config(saved, edit_config.EditConfig(editor_bleed=2), "ckpt")
    # a field that came with a new default reads as what old runs did: SSIM in the loss
    del saved["ssim_weight"]
    loop.check_config(saved, edit_config.EditConfig(ssim_weight=1.0), "ckpt")
    with pytest.raises(ValueError, match=r"ssim_weight \(there 1.0, here 0.0\)"):
        loop.check_config(saved, config, "ckpt")


def test_a_run_from_before_the_coherence_prior_reads_as_without_it():
    saved = json.loads(json.dumps(dataclasses.asdict(edit_config.EditConfig())))
    del saved["coherence_weight"]
    loop.check_config(saved, edit_config.EditConfig(coherence_weight=0.0), "ckpt")
    with pytest.raises(ValueError, match=r"coherence_weight \(there 0.0, here 0.0001\)"):
        loop.check_config(saved, edit_config.EditConfig(), "ckpt")
    with pytest.raises(ValueError, match="coherence_weight must be >= 0"):
        edit_config.EditConfig(coherence_weight=-1.0)
