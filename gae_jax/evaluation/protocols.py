"""The paper's three evaluation protocols, as (sequence, frame) pairs and cameras of a scene.

  * `novel_view`: the held-out cameras on the training frames;
  * `self_reenactment`: the held-out sequence(s) of the same person from training cameras;
  * `cross_identity`: another person's motion (expression, pose, jaw, eyes) driving the avatar
    with its own shape, as GaussianAvatars' cross-identity reenactment.
A scene without held-out cameras or such sequences (a user's folder) simply lacks that protocol.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax.scene.types import Scene, training_frames

PROTOCOLS = ("novel_view", "self_reenactment", "cross_identity")


@dataclasses.dataclass(frozen=True)
class ProtocolFrames:
    """What to render for one protocol: (sequence, frame) pairs and cameras."""

    name: str
    pairs: list
    cameras: tuple


def available(scene: Scene) -> tuple:
    """The protocols the scene has data for."""
    have = {"novel_view": bool(scene.held_out_cameras),
            "self_reenactment": bool(scene.sequences_of("self_reenactment")),
            "cross_identity": bool(scene.sequences_of("cross_identity"))}
    return tuple(p for p in PROTOCOLS if have[p])


def _frames_of(scene: Scene, split: str) -> list:
    return [(n, t) for n in scene.sequences_of(split) for t in range(scene.sequences[n].num_frames)]


def protocol_frames(scene: Scene, name: str, frames: int = 6, cameras: int = 3) -> ProtocolFrames:
    """The (sequence, frame) pairs and cameras of a protocol, evenly subsampled."""
    if name not in PROTOCOLS:
        raise ValueError(f"unknown protocol {name!r}; choose from {PROTOCOLS}")
    if name not in available(scene):
        raise ValueError(f"the scene has no data for the {name} protocol")
    train = scene.train_cameras
    spread = tuple(train[i] for i in np.linspace(0, len(train) - 1, cameras).round().astype(int))
    if name == "novel_view":
        pairs, cams = training_frames(scene), tuple(scene.held_out_cameras)
    elif name == "self_reenactment":
        pairs, cams = _frames_of(scene, "self_reenactment"), spread
    else:
        pairs = _frames_of(scene, "cross_identity")
        cams = tuple(scene.held_out_cameras) + spread[:max(cameras - 1, 0)]
    pick = np.linspace(0, len(pairs) - 1, min(frames, len(pairs))).round().astype(int)
    return ProtocolFrames(name, [pairs[i] for i in pick], cams)


def temporal_frames(scene: Scene, name: str) -> ProtocolFrames:
    """A clip of consecutive frames at one camera for a protocol's flicker and CLIP-C: the first
    training sequence at the held-out camera (novel view), the held-out sequence at a training
    camera (self-reenactment), the other person's sequence at the held-out camera
    (cross-identity)."""
    if name not in PROTOCOLS:
        raise ValueError(f"unknown protocol {name!r}; choose from {PROTOCOLS}")
    if name not in available(scene):
        raise ValueError(f"the scene has no data for the {name} protocol")
    split = {"novel_view": "train", "self_reenactment": "self_reenactment",
             "cross_identity": "cross_identity"}[name]
    seq = scene.sequences_of(split)[0]
    held = scene.held_out_cameras
    cam = held[0] if held and name != "self_reenactment" else scene.train_cameras[0]
    return ProtocolFrames(name, [(seq, t) for t in range(scene.sequences[seq].num_frames)],
                          (cam,))
