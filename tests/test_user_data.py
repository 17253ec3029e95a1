"""The user's own data, end to end, as an outsider would run it: the embedded scene exported in
the NeRSemble layout, the head written as a FLAME pickle with a FLAME_masks.pkl, then the three
commands (reconstruct, train, evaluate) on those files only."""

import json
import os
import pickle

import numpy as np
import pytest

from gae_jax import evaluate, reconstruct, train
from gae_jax.model import flame_io, head
from gae_jax.scene import nersemble, synthetic
from gae_jax.scene.load import SceneConfig, load_scene


@pytest.fixture(scope="module")
def user_files(tmp_path_factory):
    root = tmp_path_factory.mktemp("user")
    scene = synthetic.make_synthetic_scene(size=32, num_cameras=6, frames_per_sequence=2,
                                           supersample=1, cache_dir=str(root / "cache"),
                                           progress=False)
    data = root / "subject"
    nersemble.export_scene(scene, str(data))
    model_path = root / "generic_model.pkl"
    flame_io.save_flame(scene.model, str(model_path))
    faces = np.asarray(scene.model.faces)
    names = {v: k for k, v in head.REGION_ID.items()}
    masks = {names[r]: np.unique(faces[scene.face_regions == r]) for r in
             np.unique(scene.face_regions) if names[r] != "skin"}
    masks_path = root / "FLAME_masks.pkl"
    with open(masks_path, "wb") as f:
        pickle.dump(masks, f, protocol=2)
    return scene, str(data), str(model_path), str(masks_path), root


def test_the_loaded_folder_is_the_exported_scene(user_files):
    scene, data, model_path, masks_path, _ = user_files
    loaded = load_scene(SceneConfig(data=data, flame_model=model_path, flame_masks=masks_path))
    assert loaded.kind == "capture"
    # Vertex masks are coarser than face labels: a skin face whose three vertices all lie on
    # the hair's border reads as hair. The lips (the default edit) must come through exactly.
    assert np.mean(loaded.face_regions == scene.face_regions) > 0.999
    lips = head.REGION_ID["lips"]
    np.testing.assert_array_equal(loaded.face_regions == lips, scene.face_regions == lips)
    np.testing.assert_allclose(loaded.w2c, scene.w2c, atol=1e-5)
    np.testing.assert_allclose(loaded.intrinsics, scene.intrinsics, atol=1e-4)
    assert loaded.held_out_cameras == scene.held_out_cameras
    train_names = scene.sequences_of("train")
    expected = np.concatenate([scene.images[n] for n in train_names], axis=1)
    cams = list(scene.train_cameras)
    np.testing.assert_array_equal(loaded.images["train"][cams], expected[cams])
    np.testing.assert_allclose(loaded.sequences["train"].jaw,
                               np.concatenate([scene.sequences[n].jaw for n in train_names]),
                               atol=1e-6)
    assert [n for n in loaded.sequences] == ["train", "test"]


def test_reconstruct_train_evaluate_on_the_files_only(user_files, tmp_path, capsys,
                                                      monkeypatch):
    _, data, model_path, masks_path, _ = user_files
    monkeypatch.setenv("GAE_JAX_CACHE", str(tmp_path / "empty-cache"))
    source = ["--data", data, "--flame-model", model_path, "--flame-masks", masks_path]
    avatar = tmp_path / "avatar"
    assert reconstruct.main(source + ["--out", str(avatar), "--iterations", "20"]) == 0
    assert (avatar / "point_cloud.ply").is_file() and (avatar / "flame_param.npz").is_file()
    report = json.loads((avatar / "reconstruct.json").read_text())
    assert np.isfinite(report["held_out_camera_psnr"])
    run = tmp_path / "run"
    assert train.main(source + ["--avatar", str(avatar), "--out", str(run), "--iterations", "3",
                                "--checkpoint-every", "0", "--no-video"]) == 0
    cache = tmp_path / "empty-cache"
    assert not (cache.exists() and os.listdir(cache)), "an edit of a given avatar fits nothing"
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["evaluation"]["truth"] == "capture"
    assert set(metrics["evaluation"]) >= {"novel_view", "self_reenactment"}
    capsys.readouterr()
    assert evaluate.main([str(run)]) == 0
    again = json.loads((run / "evaluation.json").read_text())
    for name in ("novel_view", "self_reenactment"):
        assert again[name]["ours"]["psnr"]["whole"] == pytest.approx(
            metrics["evaluation"][name]["ours"]["psnr"]["whole"], abs=0.01)


def test_a_malformed_folder_is_named_with_its_file_and_field(user_files, tmp_path, capsys,
                                                             monkeypatch):
    _, data, model_path, _, _ = user_files
    monkeypatch.chdir(tmp_path)  # the default --out runs/edit must not hold a run already
    bad = tmp_path / "bad"
    bad.mkdir()
    with open(os.path.join(data, "transforms_train.json")) as f:
        meta = json.load(f)
    del meta["frames"][0]["transform_matrix"]
    (bad / "transforms_train.json").write_text(json.dumps(meta))
    assert reconstruct.main(["--data", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "transforms_train.json: frame 0 lacks ['transform_matrix']" in err
    assert train.main(["--data", data, "--flame-model", str(tmp_path / "none.pkl")]) == 2
    assert "none.pkl: no such file" in capsys.readouterr().err
    assert train.main(["--flame-model", model_path]) == 2
    assert "need --data" in capsys.readouterr().err
