"""What an edit is scored against, gathered once into an `EvalSet` that a run folder keeps.

For a synthetic scene the truth is the *ideal edit*: the ray-cast mesh with the instruction
applied to its albedo (`instructions.ideal_albedo`; stripes decided per ray,
`instructions.stripe_shader`), at the scene's own supersampling; styles have no ideal and are
scored against the unedited truth. For a user's capture the truth is the
captured images (an edit necessarily departs from them: the scores measure what changed).

An `EvalSet` holds, per protocol, the frames to score and a clip for flicker: posed mesh
vertices, cameras, truth images and region labels, plus the faces and per-face regions. It is
written into the run folder (`save` / `load`) so that `python -m gae_jax.evaluate RUN_DIR`
needs nothing else: no scene, no model, no refit.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Callable, Optional

import numpy as np

from gae_jax import instructions
from gae_jax.evaluation import protocols
from gae_jax.scene import raycast, synthetic
from gae_jax.scene.types import Scene, posed_vertices
from gae_jax.util.fileio import write_npz

FILE_NAME = "evaluation_set.npz"


@dataclasses.dataclass(frozen=True)
class EvalFrames:
    """One protocol's frames: P (sequence, frame) pairs x K cameras.

    vertices: (P, V, 3) posed mesh (A's shape); truth: (P, K, H, W, 3) uint8; regions:
    (P, K, H, W) int8 (-1 background).
    """

    name: str
    pairs: list
    cameras: tuple
    vertices: np.ndarray
    truth: np.ndarray
    regions: np.ndarray


@dataclasses.dataclass(frozen=True)
class EvalSet:
    """Everything the evaluation reads. protocols: name -> (frames, clip)."""

    prompt: str
    edited_region: Optional[str]
    truth_kind: str  # "ideal edit", "unedited truth (style: no ideal)" or "capture"
    faces: np.ndarray
    face_regions: np.ndarray
    intrinsics: np.ndarray
    w2c: np.ndarray
    background: np.ndarray
    width: int
    height: int
    protocols: dict


def ideal_albedo(scene: Scene, prompt: str, mode: int = 0, modes: int = 1):
    """(instruction or None, (V, 3) albedo of the ideal edit of identity A; `mode` of `modes`:
    the answer of a multimodal editor, `instructions.mode_of`). A prompt outside the semantic
    vocabulary (a style) has no ideal: None and the unedited albedo."""
    try:
        instruction = instructions.parse(prompt)
    except ValueError:
        return None, scene.albedo["A"]
    instruction, phase = instructions.mode_of(instruction, mode, modes)
    return instruction, instructions.ideal_albedo(instruction, scene.albedo["A"],
                                                  scene.model.faces, scene.face_regions,
                                                  scene.model.v_template, phase)


@dataclasses.dataclass(frozen=True)
class Ideal:
    """What a synthetic truth ray-casts: (V, K) per-vertex values and the `raycast_views`
    shader that colours each ray from them (None: the values are the shaded colour)."""

    values: np.ndarray
    shader: Optional[Callable] = None


def ideal_of(scene: Scene, prompt: str, mode: int = 0, modes: int = 1):
    """(instruction or None, `Ideal`) of identity A: the shaded ideal albedo, or for stripes
    the shaded colours, the shaded stripe colour and the rest height with a per-ray stripe
    shader (`instructions.stripe_shader`)."""
    instruction, albedo = ideal_albedo(scene, prompt, mode, modes)
    shape = scene.shapes["A"]
    if instruction is None or not instruction.stripes:
        return instruction, Ideal(synthetic.shaded_colors(scene.model, albedo, shape))
    phase = instructions.mode_of(instructions.parse(prompt), mode, modes)[1]
    paint = np.broadcast_to(np.asarray(instruction.colour), albedo.shape)
    values = np.concatenate([synthetic.shaded_colors(scene.model, scene.albedo["A"], shape),
                             synthetic.shaded_colors(scene.model, paint, shape),
                             np.asarray(scene.model.v_template, np.float64)[:, 1:2]], 1)
    return instruction, Ideal(values, instructions.stripe_shader(instruction, scene.face_regions,
                                                                 phase))


def frames_truth(scene: Scene, protocol: protocols.ProtocolFrames, ideal) -> EvalFrames:
    """Truth of one protocol: ray-cast (synthetic) with `ideal`, an `Ideal` or a (V, 3) albedo,
    or the captured images."""
    vertices = posed_vertices(scene, protocol.pairs, identity="A")
    cams = list(protocol.cameras)
    if scene.kind == "synthetic":
        if not isinstance(ideal, Ideal):
            ideal = Ideal(synthetic.shaded_colors(scene.model, ideal, scene.shapes["A"]))
        images, regions = [], []
        rays = raycast.ray_sets(synthetic.rig_cameras(scene.intrinsics[cams], scene.w2c[cams],
                                                      scene.width), scene.supersample)
        for name, t in protocol.pairs:
            img, reg = synthetic.render_frame(
                scene.model, scene.face_regions, ideal.values, scene.shapes["A"],
                scene.sequences[name], t, scene.intrinsics[cams], scene.w2c[cams], scene.width,
                scene.background, supersample=scene.supersample, rays=rays, shader=ideal.shader)
            images.append(img)
            regions.append(reg)
        truth, labels = np.stack(images), np.stack(regions)
    else:
        truth = np.stack([scene.images[n][cams, t] for n, t in protocol.pairs])
        labels = np.stack([scene.regions[n][cams, t] for n, t in protocol.pairs])
    return EvalFrames(protocol.name, list(protocol.pairs), tuple(protocol.cameras), vertices,
                      truth, labels)


def build(scene: Scene, prompt: str, frames: int = 4, mode: int = 0, modes: int = 1) -> EvalSet:
    """The EvalSet of an edit with `prompt` on `scene` (`frames` pairs per protocol; the ideal
    of answer `mode` of a `modes`-modal editor, `instructions.mode_of`)."""
    if scene.kind == "synthetic":
        instruction, albedo = ideal_of(scene, prompt, mode, modes)
        kind = "ideal edit" if instruction else "unedited truth (style: no ideal)"
    else:
        try:
            instruction = instructions.parse(prompt)
        except ValueError:
            instruction = None
        albedo, kind = None, "capture"
    sets = {}
    for name in protocols.available(scene):
        sets[name] = (frames_truth(scene, protocols.protocol_frames(scene, name, frames=frames),
                                   albedo),
                      frames_truth(scene, protocols.temporal_frames(scene, name), albedo))
    return EvalSet(prompt, instruction.region if instruction else None, kind,
                   np.asarray(scene.model.faces), np.asarray(scene.face_regions),
                   np.asarray(scene.intrinsics), np.asarray(scene.w2c),
                   np.asarray(scene.background), int(scene.width), int(scene.height), sets)


def save(evalset: EvalSet, path: str) -> None:
    """Writes an EvalSet as one `.npz` (atomically)."""
    arrays = dict(faces=evalset.faces, face_regions=evalset.face_regions,
                  intrinsics=evalset.intrinsics, w2c=evalset.w2c, background=evalset.background)
    meta = dict(prompt=evalset.prompt, edited_region=evalset.edited_region,
                truth_kind=evalset.truth_kind, width=evalset.width, height=evalset.height,
                protocols={})
    for name, pair in evalset.protocols.items():
        for part, f in zip(("frames", "clip"), pair):
            key = f"{name}/{part}"
            meta["protocols"].setdefault(name, {})[part] = dict(
                pairs=[list(p) for p in f.pairs], cameras=list(f.cameras))
            arrays.update({f"{key}/vertices": f.vertices, f"{key}/truth": f.truth,
                           f"{key}/regions": f.regions})
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    write_npz(path, arrays, compressed=True)


def load(path: str) -> EvalSet:
    """Reads `save`'s file; ValueError naming the file when it is unreadable or incomplete."""
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {k: f[k] for k in f.files}
        meta = json.loads(bytes(data["meta"]).decode())
        sets = {}
        for name, parts in meta["protocols"].items():
            sets[name] = tuple(EvalFrames(
                name, [tuple(p) for p in parts[part]["pairs"]], tuple(parts[part]["cameras"]),
                data[f"{name}/{part}/vertices"], data[f"{name}/{part}/truth"],
                data[f"{name}/{part}/regions"]) for part in ("frames", "clip"))
        return EvalSet(meta["prompt"], meta["edited_region"], meta["truth_kind"], data["faces"],
                       data["face_regions"], data["intrinsics"], data["w2c"],
                       data["background"], meta["width"], meta["height"], sets)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except (OSError, ValueError, KeyError, EOFError) as e:
        raise ValueError(f"{path}: not a readable evaluation set ({type(e).__name__}: {e})") \
            from e
