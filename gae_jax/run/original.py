"""The original avatar of a scene: its reconstruction, fitted once and cached on disk."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys

from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import RECONSTRUCTION_VERSION, fit
from gae_jax.model import avatar_io
from gae_jax.scene.synthetic import scene_fingerprint
from gae_jax.util.fileio import PlyError, cache_root


def cache_path(scene, config: ReconstructConfig) -> str:
    """Where the reconstruction of `scene` with `config` is cached: the key covers the scene's
    ground truth and every reconstruction setting (the screen filter under the name the cache
    has always used)."""
    key = dataclasses.asdict(config)
    key = dict(key, cov2d_dilation=key.pop("screen_filter"), version=RECONSTRUCTION_VERSION)
    settings = hashlib.sha256(json.dumps(key, sort_keys=True).encode())
    return os.path.join(cache_root(), f"avatar-{scene_fingerprint(scene)}-"
                                      f"{settings.hexdigest()[:12]}.ply")


def original_avatar(scene, iterations: int, progress: bool, **settings):
    """The reconstruction of the scene's identity A with `iterations` steps and any other
    `ReconstructConfig` settings, from the cache or fitted now (then cached)."""
    config = ReconstructConfig(iterations=iterations, **settings)
    path = cache_path(scene, config)
    if os.path.isfile(path):
        try:
            return avatar_io.load_bound_avatar(path, scene.face_regions)
        except (PlyError, OSError) as e:
            print(f"warning: the cached avatar is unreadable ({e}); reconstructing it",
                  file=sys.stderr)
    fitted, _ = fit(scene, config, progress=progress)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    avatar_io.save_avatar_ply(fitted, path)
    return avatar_io.load_bound_avatar(path, scene.face_regions)
