"""Reconstruction: the jitted fit step learns (the photometric loss falls)."""

import numpy as np

from gae_jax import data, reconstruct


def test_fit_lowers_the_photometric_loss(tmp_path):
    scene = data.make_synthetic_scene(size=32, num_cameras=9, frames_per_sequence=2,
                                      cache_dir=str(tmp_path), progress=False)
    config = reconstruct.ReconstructConfig(iterations=120, tile_capacity=256, seed=1)
    fitted, history = reconstruct.fit(scene, config)
    photo = np.array([h["photometric"] for h in history])
    assert len(history) == 120 and np.all(np.isfinite(photo))
    assert photo[-30:].mean() < 0.9 * photo[:10].mean(), (photo[:10].mean(), photo[-30:].mean())
    assert fitted.num == int(np.asarray(fitted.binding).shape[0]) > 0
