"""What a multi-view capture of a head holds: its FLAME model, cameras, motions and images.

A `Scene` is host data (numpy). It carries everything the later stages need -- the model that
poses the mesh, per-face region labels, cameras in OpenCV axes, sequences of FLAME parameters,
ground-truth images and splits -- so that the embedded synthetic scene (`synthetic`) and a
user's NeRSemble folder (`nersemble`) are used the same way. `scene.rig.put_rig` moves what a
jitted step needs onto the device.

Splits of a sequence: "train" (reconstruction and editing), "self_reenactment" (a held-out motion
of the same person) and "cross_identity" (another person's motion driving this avatar).
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.model import flame
from gae_jax.render.camera import Camera

SPLITS = ("train", "self_reenactment", "cross_identity")


@dataclasses.dataclass(frozen=True)
class Sequence:
    """A motion: FLAME parameters per frame (T, ...) for one identity, and its split."""

    name: str
    identity: str
    split: str  # one of SPLITS
    expr: np.ndarray  # (T, E)
    rotation: np.ndarray  # (T, 3)
    neck: np.ndarray
    jaw: np.ndarray
    eyes: np.ndarray  # (T, 6)
    translation: np.ndarray

    @property
    def num_frames(self) -> int:
        return self.expr.shape[0]

    def params(self, shape: np.ndarray, frame: int, static_offset=None) -> flame.FlameParams:
        """FlameParams of one frame with the given identity shape coefficients and optional
        (V, 3) static offset, as float32 host arrays (mixing frames on the host compiles
        nothing)."""
        f = np.float32
        return flame.FlameParams(
            shape=np.asarray(shape, f), expr=np.asarray(self.expr[frame], f),
            rotation=np.asarray(self.rotation[frame], f), neck=np.asarray(self.neck[frame], f),
            jaw=np.asarray(self.jaw[frame], f), eyes=np.asarray(self.eyes[frame], f),
            translation=np.asarray(self.translation[frame], f),
            static_offset=None if static_offset is None else np.asarray(static_offset, f))


@dataclasses.dataclass(frozen=True)
class Scene:
    """Model, cameras, identities, sequences and ground truth of one capture.

    Attributes:
      model: the FLAME model (or the built-in head in its layout) that poses the mesh.
      face_regions: (F,) int32 region label of each face (`model.head.REGIONS`).
      intrinsics: (C, 4) fx, fy, cx, cy; w2c: (C, 4, 4); width, height: image size.
      train_cameras, held_out_cameras: camera indices.
      shapes: identity name -> (S,) shape coefficients.
      vertex_colors: identity name -> (V, 3) colour to start a reconstruction from.
      sequences: name -> Sequence.
      images: sequence name -> (C, T, H, W, 3) uint8 ground truth (zeros where not captured).
      regions: sequence name -> (C, T, H, W) int8 per-pixel labels: region ids where the
        scene knows them (synthetic), 0 on the foreground mask otherwise; -1 background.
      region_samples: sequence name -> (C, T, H, W, S) int8 region labels of each of a pixel's
        S colour rays (synthetic scenes: how much of an edge pixel each region covers); absent
        for a capture, whose labels are projected from its tracked mesh when asked
        (`projected_label_samples`).
      background: (3,) background colour.
      kind: "synthetic" (ray-cast, so the ideal edit is known) or "capture" (a user's data).
      albedo: identity name -> (V, 3) unshaded albedo (synthetic scenes only: it defines the
        ideal edit).
      head: the built-in head that poses it (`head.HEAD_KINDS`), "" for a FLAME file.
      supersample: rays per pixel per axis of a synthetic scene's ground truth (its ideal edit
        is ray-cast the same way).
      static_offsets: identity name -> (V, 3) per-vertex offset of the tracked identity (VHAP's
        static_offset, added to the shaped template before skinning, as GaussianAvatars does);
        absent: none.
    """

    model: flame.FlameModel
    face_regions: np.ndarray
    intrinsics: np.ndarray
    w2c: np.ndarray
    width: int
    height: int
    train_cameras: tuple
    held_out_cameras: tuple
    shapes: dict
    vertex_colors: dict
    sequences: dict
    images: dict
    regions: dict
    background: np.ndarray
    kind: str = "synthetic"
    albedo: Optional[dict] = None
    supersample: int = 1
    head: str = ""
    static_offsets: dict = dataclasses.field(default_factory=dict)
    region_samples: dict = dataclasses.field(default_factory=dict)

    @property
    def num_cameras(self) -> int:
        return self.intrinsics.shape[0]

    def camera(self, index: int) -> Camera:
        """The index-th camera as a `Camera` pytree."""
        return Camera(intrinsics=jnp.asarray(self.intrinsics[index], jnp.float32),
                      w2c=jnp.asarray(self.w2c[index], jnp.float32), width=self.width,
                      height=self.height)

    def sequences_of(self, split: str) -> list:
        """Names of the sequences of one split, in the scene's order."""
        if split not in SPLITS:
            raise ValueError(f"unknown split {split!r}; choose from {SPLITS}")
        return [n for n, s in self.sequences.items() if s.split == split]


def training_frames(scene: Scene) -> list:
    """(sequence name, frame) pairs of the training sequences."""
    return [(n, t) for n in scene.sequences_of("train")
            for t in range(scene.sequences[n].num_frames)]


def frame_params(scene: Scene, name: str, frame: int, identity: str = "A") -> flame.FlameParams:
    """FlameParams of one frame of a sequence with an identity's shape and static offset."""
    return scene.sequences[name].params(scene.shapes[identity], frame,
                                        scene.static_offsets.get(identity))


def posed_vertices(scene: Scene, frames, identity: str = "A") -> np.ndarray:
    """(T, V, 3) mesh vertices of an identity's shape under the given (sequence, frame) motions."""
    return np.stack([np.asarray(flame.lbs(scene.model, frame_params(scene, n, t, identity)))
                     for n, t in frames])


def training_images(scene: Scene) -> np.ndarray:
    """(C, T, H, W, 3) uint8 images of `training_frames(scene)` (frames in the same order)."""
    return np.concatenate([scene.images[n] for n in scene.sequences_of("train")], axis=1)


UNKNOWN_REGION = -2  # a label that supervises nothing (foreground the tracked mesh misses)
# Rays per pixel per axis of a capture's projected label samples: 4 rays tell how much of an
# edge pixel each region covers to a quarter.
LABEL_SUPERSAMPLE = 2


def training_labels(scene: Scene, stride: int = 1) -> np.ndarray:
    """(C, T, H / stride, W / stride) int8 region labels of `training_images(scene)`'s views
    (every `stride`-th pixel): `projected_labels` of the training frames from every camera."""
    names = scene.sequences_of("train")
    if scene.kind == "synthetic":
        return np.concatenate([scene.regions[n] for n in names], axis=1)[..., ::stride, ::stride]
    return projected_labels(scene, training_frames(scene), range(scene.num_cameras), stride)


def training_label_samples(scene: Scene) -> np.ndarray:
    """(C, T, H, W, S) int8 region labels of each sub-pixel ray of `training_images(scene)`'s
    views: a synthetic scene's stored samples (`projected_label_samples`); a capture's centre
    labels, S = 1 (its training views are many, and the fit holds all their labels at once:
    one label per pixel keeps that to a byte per pixel)."""
    if scene.kind != "synthetic":
        return training_labels(scene)[..., None]
    return projected_label_samples(scene, training_frames(scene), range(scene.num_cameras))


def projected_label_samples(scene: Scene, pairs, cameras) -> np.ndarray:
    """(K, P, H, W, S) int8 region labels of S rays inside each pixel of the views of
    (sequence, frame) `pairs` from `cameras`: the tracked mesh's face regions projected along
    each ray, so that a pixel on a region's outline says how much of it each region covers (as
    `projected_labels` says which region its centre shows). A synthetic scene's stored samples
    are that projection already (S = its supersample squared; S = 1, the centre labels, for a
    scene that has none, e.g. rescaled); a capture's are ray-cast at `LABEL_SUPERSAMPLE`, a
    ray that misses the mesh on the capture's foreground being `UNKNOWN_REGION`."""
    cameras, pairs = list(cameras), list(pairs)
    if scene.kind == "synthetic":
        stored = all(n in scene.region_samples and scene.region_samples[n].shape[2:4]
                     == (scene.height, scene.width) for n, _ in pairs)
        if not stored:
            return projected_labels(scene, pairs, cameras)[..., None]
        return np.stack([np.stack([scene.region_samples[n][c, t] for n, t in pairs])
                         for c in cameras])
    from gae_jax.scene import raycast

    vertices = posed_vertices(scene, pairs)
    views = [scene.camera(c) for c in cameras]
    rays = raycast.ray_sets(views, LABEL_SUPERSAMPLE)
    faces = np.asarray(scene.model.faces)
    grey = np.zeros((vertices.shape[1], 3))
    samples = []
    for j, (name, t) in enumerate(pairs):
        hits = raycast.raycast_views(vertices[j], faces, grey, scene.face_regions, views,
                                     supersample=LABEL_SUPERSAMPLE, rays=rays)
        projected = np.stack([v.samples for v in hits])
        foreground = (scene.regions[name][cameras, t] >= 0)[..., None]
        samples.append(np.where(projected >= 0, projected,
                                np.where(foreground, UNKNOWN_REGION, -1)).astype(np.int8))
    return np.stack(samples, axis=1)


def projected_labels(scene: Scene, pairs, cameras, stride: int = 1) -> np.ndarray:
    """(K, P, H / stride, W / stride) int8 region labels of (sequence, frame) `pairs` seen by
    `cameras`: the tracked mesh's face regions projected into each view (what a user has,
    never an evaluation's truth). A synthetic scene's stored labels are that projection
    already; a capture's are ray-cast from its posed mesh where the mesh is hit,
    `UNKNOWN_REGION` where the capture's foreground shows what the mesh does not model (hair
    beyond the scalp, a neck below it), -1 elsewhere."""
    cameras, pairs = list(cameras), list(pairs)
    if scene.kind == "synthetic":
        return np.stack([np.stack([scene.regions[n][c, t, ::stride, ::stride]
                                   for n, t in pairs]) for c in cameras])
    from gae_jax.scene import raycast

    vertices = posed_vertices(scene, pairs)
    views = [scene.camera(c) for c in cameras]
    rays = [{(0.5, 0.5): _strided(r[(0.5, 0.5)], scene.height, scene.width, stride)}
            for r in raycast.ray_sets(views, 1)]
    faces = np.asarray(scene.model.faces)
    grey = np.zeros((vertices.shape[1], 3))
    height, width = -(-scene.height // stride), -(-scene.width // stride)
    labels = []
    for j, (name, t) in enumerate(pairs):
        hits = raycast.raycast_views(vertices[j], faces, grey, scene.face_regions, views,
                                     rays=rays, shape=(height, width))
        projected = np.stack([v.regions for v in hits])
        foreground = scene.regions[name][cameras, t, ::stride, ::stride] >= 0
        labels.append(np.where(projected >= 0, projected,
                               np.where(foreground, UNKNOWN_REGION, -1)).astype(np.int8))
    return np.stack(labels, axis=1)


def projected_rest_positions(scene: Scene, pair, camera: int) -> np.ndarray:
    """(H, W, 3) the tracked mesh's rest-pose (template) position at each pixel of one training
    view ((sequence, frame) `pair` from `camera`), interpolated at the ray's hit; zeros where
    the mesh is not hit. Like `projected_labels`, what a user has: head-space coordinates
    that stick to the head whatever its expression and pose."""
    from gae_jax.scene import raycast

    vertices = posed_vertices(scene, [pair])[0]
    hit = raycast.raycast_views(vertices, np.asarray(scene.model.faces),
                                np.asarray(scene.model.v_template, np.float64),
                                scene.face_regions, [scene.camera(camera)],
                                background=(0.0, 0.0, 0.0))[0]
    return np.asarray(hit.image, np.float32)


def _strided(rays, height: int, width: int, stride: int):
    """Every `stride`-th pixel's ray of a camera's (H*W, 3) origins and directions."""
    return tuple(a.reshape(height, width, 3)[::stride, ::stride].reshape(-1, 3) for a in rays)


def stacked_params(scene: Scene, names, identity: str = "A") -> flame.FlameParams:
    """FlameParams with a leading frame axis over all frames of the named sequences."""
    frames = [frame_params(scene, n, t, identity) for n in names
              for t in range(scene.sequences[n].num_frames)]
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *frames)


def interpolated_vertices(scene: Scene, name: str, per_frame: int,
                          identity: str = "A") -> np.ndarray:
    """((T - 1) per_frame + 1, V, 3) mesh vertices of a sequence with `per_frame` steps between
    consecutive frames, FLAME parameters interpolated linearly (a smooth drive for videos)."""
    seq = scene.sequences[name]
    times = np.linspace(0, seq.num_frames - 1, (seq.num_frames - 1) * per_frame + 1)
    out = []
    for x in times:
        lo = int(np.floor(x))
        hi, w = min(lo + 1, seq.num_frames - 1), float(x - lo)
        a, b = frame_params(scene, name, lo, identity), frame_params(scene, name, hi, identity)
        mixed = jax.tree_util.tree_map(lambda p, q: (1 - w) * p + w * q, a, b)
        out.append(np.asarray(flame.lbs(scene.model, mixed)))
    return np.stack(out)
