"""Scenes for the claims study: a training split in which the mouth stays closed and
the eyes open, so that an edit that leaks into the teeth or irises is never corrected in
training, while the held-out sequences open the jaw and close the eyes.

`closed_split(scene)` keeps, of every training sequence, the frames whose training views show
at most a few pixels of teeth or tongue and at least `eyes_open` of the most iris pixels
any training frame shows; each run of consecutive kept frames becomes its own sequence named
by its first frame (`talk~0`, `talk~6`, ...) so that temporal neighbours stay neighbours.
Cameras, held-out sequences and identities are untouched. The selection reads the scene's rendered labels of its
training images (what a capture's face parser would give), never the edit's ideal.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax.model import head

# The mouth cavity is not among them: the procedural head's dark band between the lips shows in
# every frame (~115 px), while its teeth show on 0-5 px with the jaw closed, 30 open.
MOUTH_INTERIOR = ("teeth", "tongue")


def _runs(keep: np.ndarray) -> list:
    """[(start, stop)] of the runs of True in a (T,) bool array."""
    runs, start = [], None
    for t, k in enumerate(list(keep) + [False]):
        if k and start is None:
            start = t
        elif not k and start is not None:
            runs.append((start, t))
            start = None
    return runs


def closed_frames(scene, eyes_open: float = 0.8, mouth_pixels: int = 5) -> dict:
    """{training sequence: (T,) bool}, True where every training view shows at most
    `mouth_pixels` teeth or tongue pixels and the views' iris pixels reach `eyes_open` of the
    most any training frame shows."""
    interior = [head.REGION_ID[n] for n in MOUTH_INTERIOR]
    iris = [head.REGION_ID["iris"], head.REGION_ID["pupil"]]
    cams = list(scene.train_cameras)
    counts = {}
    for name in scene.sequences_of("train"):
        labels = scene.regions[name][cams]  # (C, T, H, W)
        counts[name] = (np.isin(labels, interior).sum(axis=(2, 3)).max(axis=0),
                        np.isin(labels, iris).sum(axis=(0, 2, 3)))
    most_iris = max(int(c[1].max()) for c in counts.values())
    return {n: (m <= mouth_pixels) & (i >= eyes_open * most_iris) for n, (m, i) in counts.items()}


def closed_split(scene, eyes_open: float = 0.8, mouth_pixels: int = 5, min_run: int = 2):
    """`scene` with its training sequences cut to their closed-mouth, open-eye runs of at least
    `min_run` frames (see the module docstring). ValueError when no frame qualifies."""
    others = [n for n, seq in scene.sequences.items() if seq.split != "train"]
    sequences = {n: scene.sequences[n] for n in others}
    images = {n: scene.images[n] for n in others}
    regions = {n: scene.regions[n] for n in others}
    samples = {n: v for n, v in scene.region_samples.items() if n in others}
    kept = closed_frames(scene, eyes_open, mouth_pixels)
    for name, keep in kept.items():
        seq = scene.sequences[name]
        for a, b in (r for r in _runs(keep) if r[1] - r[0] >= min_run):
            part = f"{name}~{a}"  # the run's first frame in the original sequence
            per_frame = {f.name: getattr(seq, f.name)[a:b] for f in dataclasses.fields(seq)
                         if isinstance(getattr(seq, f.name), np.ndarray)}
            sequences[part] = dataclasses.replace(seq, name=part, **per_frame)
            images[part] = scene.images[name][:, a:b]
            regions[part] = scene.regions[name][:, a:b]
            if name in scene.region_samples:
                samples[part] = scene.region_samples[name][:, a:b]
    if not any(s.split == "train" for s in sequences.values()):
        raise ValueError("no training frame has a closed mouth and open eyes")
    return dataclasses.replace(scene, sequences=sequences, images=images, regions=regions,
                               region_samples=samples)
