"""The embedded default scene: a built-in head (`head.make_head(kind)`: the procedural head or
the MakeHuman head), filmed by a camera rig, with ground truth.

The scene is a `scene.types.Scene` that carries the head model and its albedo, so the ideal
edit of any instruction can be ray-cast too (`evaluation.truth`).

`make_synthetic_scene(...)` builds identity A and identity B (different shape coefficients and
albedo), several expression / pose sequences per identity, a rig of cameras on the frontal
hemisphere (one held out, as NeRSemble's camera 8), and ground-truth images rendered by ray
casting the coloured mesh (`raycast`, independent of the splatting renderer), with per-pixel
region labels (the centre ray's, and each colour ray's: how much of an edge pixel each region
covers). Shading is baked per vertex in head space (Lambert from a light fixed to the head),
so it moves with the head. Splits: identity A's training sequences on the training cameras
(reconstruction / editing), the held-out camera (novel view), A's held-out sequence
(self-reenactment) and B's sequence (cross-identity reenactment).

Scenes are cached on disk as `.npz`, keyed by their parameters and `SCENE_VERSION`, written
atomically, so the second call is a file read.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys

import numpy as np

from gae_jax.model import avatar, flame, head
from gae_jax.render.camera import Camera, look_at_w2c, make_camera
from gae_jax.scene.raycast import ray_sets, raycast_views
from gae_jax.scene.types import Scene, Sequence
from gae_jax.util.fileio import cache_root, write_npz
from gae_jax.util.image import to_uint8

# 4: embree's own barycentrics (float32) instead of a float64 re-intersection; 1.3e-5 of the
# 8-bit values changed (77.9 dB between versions at worst). 5: the colour rays' region labels
# are kept (`Scene.region_samples`); images unchanged. 6: the C++ caster's float64 hits instead of
# embree's float32 ones; 1.3e-5 of the 8-bit values changed (77.2 dB at worst), 3 centre labels
# and 13 ray labels of 4.5 M.
SCENE_VERSION = 6
LIGHT_DIRECTION = np.array([0.35, 0.55, 0.75])  # in head space, towards the light
AMBIENT = 0.45
IDENTITY_B_SHAPE = {
    "procedural": dict(head_width=0.6, nose_length=0.8, jaw_width=-0.6),
    "makehuman": {"head-square": 0.7, "head-fat-incr": 0.5, "nose-scale-vert-incr": 0.8,
                  "nose-point-width-incr": 0.6, "chin-width-incr": -0.6,
                  "mouth-lowerlip-volume-incr": 0.7, "eyebrows-trans-up": 0.5}}
IDENTITY_B_ALBEDO = dict(skin=(0.62, 0.45, 0.36), hair=(0.08, 0.07, 0.07),
                         brows=(0.07, 0.06, 0.06), iris=(0.30, 0.55, 0.30))
# Camera distance per head: the MakeHuman head with its neck is taller than the procedural one.
CAMERA_DISTANCE = {"procedural": 0.6, "makehuman": 0.68}
TRAIN_SEQUENCES = ("talk", "smile", "blink", "jaw", "turn")
HELD_OUT_SEQUENCE = "mix"
CROSS_SEQUENCE = "b_mix"
HELD_OUT_CAMERA = 8
LOOK_AT = np.array([0.0, -0.01, 0.0])


def camera_rig(num_cameras: int, size: int, distance: float = 0.6, fov_degrees: float = 26.0,
               max_yaw_degrees: float = 60.0, max_pitch_degrees: float = 20.0):
    """Cameras on the frontal hemisphere looking at the head: (C, 4) intrinsics, (C, 4, 4) w2c.

    Yaw and pitch follow a low-discrepancy spiral, so any count covers the hemisphere evenly;
    camera `HELD_OUT_CAMERA` is placed nearly frontal, as NeRSemble's validation camera.
    """
    if num_cameras < 2:
        raise ValueError(f"the rig needs at least 2 cameras, got {num_cameras}")
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    intr, w2cs = [], []
    for i in range(num_cameras):
        u = (i + 0.5) / num_cameras
        v = (i * golden) % 1.0
        yaw = np.deg2rad(max_yaw_degrees) * (2 * u - 1)
        pitch = np.deg2rad(max_pitch_degrees) * (2 * v - 1)
        if i == HELD_OUT_CAMERA % num_cameras:
            yaw, pitch = np.deg2rad(8.0), np.deg2rad(4.0)
        eye = LOOK_AT + distance * np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch),
                                             np.cos(yaw) * np.cos(pitch)])
        cam = make_camera(look_at_w2c(eye, LOOK_AT, up=(0, 1, 0)), size, size,
                          fov_degrees=fov_degrees)
        intr.append(np.asarray(cam.intrinsics, np.float64))
        w2cs.append(np.asarray(cam.w2c, np.float64))
    return np.stack(intr), np.stack(w2cs)


def _wave(t, period, phase=0.0):
    return 0.5 - 0.5 * np.cos(2 * np.pi * (t / period + phase))


def make_sequences(frames_per_sequence: int, num_expr: int, kind: str = "procedural",
                   names: tuple = head.EXPR_NAMES) -> dict:
    """The motion library of a built-in head: name -> Sequence (deterministic); `names` are the
    model's expression names (`HeadAssets.expr_names`)."""
    t = np.arange(frames_per_sequence, dtype=np.float64)
    n = frames_per_sequence
    e = {name: i for i, name in enumerate(names)}

    def seq(name, identity, split, expr=None, rotation=None, neck=None, jaw=None, eyes=None):
        z3 = np.zeros((n, 3))
        return Sequence(name=name, identity=identity, split=split,
                        expr=np.zeros((n, num_expr)) if expr is None else expr,
                        rotation=z3 if rotation is None else rotation,
                        neck=z3 if neck is None else neck,
                        jaw=z3 if jaw is None else np.stack([jaw, 0 * jaw, 0 * jaw], -1),
                        eyes=np.zeros((n, 6)) if eyes is None else eyes, translation=z3)

    def expr_of(**curves):
        x = np.zeros((n, num_expr))
        for k, v in curves.items():
            x[:, e[k]] = v
        return x

    if kind == "makehuman":
        return {s.name: s for s in _face_unit_sequences(t, n, seq, expr_of)}
    talk_jaw = 0.18 * _wave(t, 5.0) * (0.6 + 0.4 * _wave(t, 13.0))
    out = [
        seq("talk", "A", "train", expr_of(lips_part=0.5 * _wave(t, 7.0), pout=0.4 * _wave(t, 11)),
            jaw=talk_jaw),
        seq("smile", "A", "train", expr_of(smile=_wave(t, n), brow_raise=0.8 * _wave(t, n, 0.2))),
        seq("blink", "A", "train", expr_of(blink_left=_wave(t, 6.0), blink_right=_wave(t, 6.0)),
            eyes=np.stack([0 * t, 0.25 * np.sin(t / 3), 0 * t, 0 * t, 0.25 * np.sin(t / 3),
                           0 * t], -1)),
        seq("jaw", "A", "train", jaw=0.32 * _wave(t, n)),
        seq("turn", "A", "train",
            rotation=np.stack([0.15 * np.sin(t / 4), 0.55 * np.sin(2 * np.pi * t / n), 0 * t],
                              -1),
            neck=np.stack([0.1 * np.sin(t / 3), 0 * t, 0.08 * np.sin(t / 5)], -1),
            jaw=0.1 * _wave(t, 9.0)),
        seq(HELD_OUT_SEQUENCE, "A", "self_reenactment",
            expr_of(smile=0.7 * _wave(t, 9.0), blink_left=_wave(t, 8.0, 0.3),
                    lips_part=0.4 * _wave(t, 6.0)),
            rotation=np.stack([0 * t, 0.35 * np.sin(t / 3), 0.1 * np.sin(t / 4)], -1),
            jaw=0.22 * _wave(t, 7.0, 0.5)),
        seq(CROSS_SEQUENCE, "B", "cross_identity",
            expr_of(pout=_wave(t, 10.0), blink_right=_wave(t, 7.0), brow_raise=_wave(t, 12.0)),
            rotation=np.stack([0.1 * np.sin(t / 2), -0.4 * np.sin(t / 5), 0 * t], -1),
            jaw=0.26 * _wave(t, 8.0)),
    ]
    return {s.name: s for s in out}


def _face_unit_sequences(t, n, seq, expr_of) -> list:
    """The MakeHuman head's motions, driven by ARKit face units: the jaw opens by `jawOpen` (its
    joint stays), the held-out sequence sticks the tongue out."""
    eyes = np.stack([0 * t, 0.25 * np.sin(t / 3), 0 * t, 0 * t, 0.25 * np.sin(t / 3), 0 * t], -1)
    talk_jaw = 0.35 * _wave(t, 5.0) * (0.6 + 0.4 * _wave(t, 13.0))
    return [
        seq("talk", "A", "train", expr_of(jawOpen=talk_jaw, mouthFunnel=0.4 * _wave(t, 7.0),
                                          mouthPucker=0.4 * _wave(t, 11.0))),
        seq("smile", "A", "train", expr_of(mouthSmileLeft=_wave(t, n), mouthSmileRight=_wave(t, n),
                                           cheekSquintLeft=0.5 * _wave(t, n),
                                           cheekSquintRight=0.5 * _wave(t, n),
                                           browInnerUp=0.8 * _wave(t, n, 0.2))),
        seq("blink", "A", "train", expr_of(eyeBlinkLeft=_wave(t, 6.0),
                                           eyeBlinkRight=_wave(t, 6.0)), eyes=eyes),
        seq("jaw", "A", "train", expr_of(jawOpen=0.8 * _wave(t, n))),
        seq("turn", "A", "train", expr_of(jawOpen=0.25 * _wave(t, 9.0)),
            rotation=np.stack([0.15 * np.sin(t / 4), 0.55 * np.sin(2 * np.pi * t / n), 0 * t],
                              -1),
            neck=np.stack([0.1 * np.sin(t / 3), 0 * t, 0.08 * np.sin(t / 5)], -1)),
        seq(HELD_OUT_SEQUENCE, "A", "self_reenactment",
            expr_of(mouthSmileLeft=0.7 * _wave(t, 9.0), mouthSmileRight=0.5 * _wave(t, 9.0),
                    eyeBlinkLeft=_wave(t, 8.0, 0.3), jawOpen=0.6 * _wave(t, 7.0, 0.5),
                    tongueOut=0.8 * _wave(t, 7.0, 0.5)),
            rotation=np.stack([0 * t, 0.35 * np.sin(t / 3), 0.1 * np.sin(t / 4)], -1)),
        seq(CROSS_SEQUENCE, "B", "cross_identity",
            expr_of(mouthPucker=_wave(t, 10.0), eyeBlinkRight=_wave(t, 7.0),
                    browInnerUp=_wave(t, 12.0), jawOpen=0.6 * _wave(t, 8.0)),
            rotation=np.stack([0.1 * np.sin(t / 2), -0.4 * np.sin(t / 5), 0 * t], -1)),
    ]


def shaded_colors(model: flame.FlameModel, albedo: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """(V, 3) albedo x Lambert shading of the identity's neutral mesh, baked in head space."""
    params = flame.zero_params(model)
    params = dataclasses.replace(params, shape=np.asarray(shape, np.float32))
    normals = avatar.vertex_normals(np.asarray(flame.lbs(model, params), np.float64),
                                    model.faces)
    light = LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
    shade = AMBIENT + (1 - AMBIENT) * np.clip(normals @ light, 0, 1)
    return np.clip(albedo * shade[:, None], 0, 1)


def identity_albedo(model: flame.FlameModel, assets: head.HeadAssets,
                    overrides: dict) -> np.ndarray:
    """(V, 3) albedo with some regions recoloured. A head whose vertices each belong to one
    region (the MakeHuman head) scales each region's vertices by new colour / default colour,
    keeping their variation; otherwise (the procedural head, whose regions share vertices) the
    vertices of exactly the default colour take the new one."""
    albedo = assets.vertex_colors.astype(np.float64).copy()
    faces = np.asarray(model.faces)
    owners = np.zeros((len(albedo), len(head.REGIONS)), bool)
    owners[faces.ravel(), np.repeat(assets.face_regions, 3)] = True
    split = bool((owners.sum(1) <= 1).all())
    for region, colour in overrides.items():
        default = np.asarray(head.ALBEDO[region])
        if split:
            mask = owners[:, head.REGION_ID[region]]
            albedo[mask] = np.clip(albedo[mask] / default * np.asarray(colour), 0, 1)
        else:
            albedo[np.all(np.isclose(albedo, default, atol=1e-6), axis=1)] = colour
    return albedo


def rig_cameras(intrinsics, w2c, size: int) -> list:
    """The rig's cameras, size x size each, from (C, 4) intrinsics and (C, 4, 4) w2c."""
    return [Camera(intrinsics=k, w2c=m, width=size, height=size) for k, m in zip(intrinsics, w2c)]


def render_frame(model, face_regions, vertex_colors, shape, sequence: Sequence, frame: int,
                 intrinsics, w2c, size: int, background, supersample: int = 1,
                 rays: list | None = None, shader=None):
    """Ground truth of one frame from every camera by ray casting the posed, coloured mesh.

    Pass edited `vertex_colors` to get the ideal edit of the same frame; `supersample` rays per
    pixel per axis anti-alias the colour (see `raycast`); `rays`: `raycast.ray_sets` of the rig,
    built once by a caller that renders many frames; `shader`: `raycast_views`' per-ray
    colouring of (V, K) `vertex_colors` (a pattern sharper than the mesh).
    Returns images (C, H, W, 3) uint8 and region maps (C, H, W) int8 (-1 background); the
    region of every colour ray is in `render_views`.
    """
    views = render_views(model, face_regions, vertex_colors, shape, sequence, frame, intrinsics,
                         w2c, size, background, supersample, rays, shader)
    return (np.stack([to_uint8(v.image) for v in views]),
            np.stack([v.regions for v in views]).astype(np.int8))


def render_views(model, face_regions, vertex_colors, shape, sequence: Sequence, frame: int,
                 intrinsics, w2c, size: int, background, supersample: int = 1,
                 rays: list | None = None, shader=None) -> list:
    """`render_frame`'s ray casts, one `raycast.RaycastImage` per camera (with each colour
    ray's region label, `samples`)."""
    verts = np.asarray(flame.lbs(model, sequence.params(shape, frame)))
    return raycast_views(verts, np.asarray(model.faces), vertex_colors, face_regions,
                         rig_cameras(intrinsics, w2c, size), background, supersample, rays=rays,
                         shader=shader)


def _model_fingerprint(model: flame.FlameModel, assets: head.HeadAssets) -> str:
    """12 hex digits of a head's geometry, bases and albedo (a re-converted asset rebuilds)."""
    h = hashlib.sha256()
    for array in (model.v_template, model.faces, model.shapedirs, model.exprdirs,
                  model.lbs_weights, assets.face_regions, assets.vertex_colors):
        h.update(np.ascontiguousarray(np.asarray(array)).tobytes())
    return h.hexdigest()[:12]


def _cache_key(params: dict) -> str:
    blob = json.dumps(dict(params, version=SCENE_VERSION), sort_keys=True).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def make_synthetic_scene(size: int = 128, num_cameras: int = 16, frames_per_sequence: int = 16,
                         background: str = "white", supersample: int = 2,
                         cache_dir: str | None = None, progress: bool = True,
                         head_kind: str = "procedural") -> Scene:
    """Builds (or loads from the cache) the default scene.

    Args:
      size: image width and height in pixels.
      num_cameras: rig size (camera `HELD_OUT_CAMERA` is held out for novel views).
      frames_per_sequence: frames in each of the 7 sequences.
      background: "white" or "black".
      supersample: ground-truth rays per pixel per axis. 2 (4 rays) is 40.4 dB from a 6x6
        reference at 128 px, 3 is 44.7 dB and takes twice the build time.
      cache_dir: where cached scenes live; `$GAE_JAX_CACHE` or ~/.cache/gae_jax when None.
      head_kind: the built-in head (`head.HEAD_KINDS`).
    """
    if size < 8 or num_cameras < 2 or frames_per_sequence < 2 or supersample < 1:
        raise ValueError("need size >= 8, num_cameras >= 2, frames_per_sequence >= 2 and "
                         "supersample >= 1")
    if background not in ("white", "black"):
        raise ValueError(f"background must be 'white' or 'black', got {background!r}")
    model, assets = head.make_head(head_kind)  # ValueError on an unknown kind
    params = dict(size=size, num_cameras=num_cameras, frames=frames_per_sequence,
                  background=background, supersample=supersample)
    if head_kind != "procedural":  # the procedural head keeps its caches' keys
        params["head"] = head_kind
        params["model"] = _model_fingerprint(model, assets)
    key = _cache_key(params)
    cache_dir = cache_dir or cache_root()
    path = os.path.join(cache_dir, f"scene-{key}.npz")
    sequences = make_sequences(frames_per_sequence, model.num_expr, head_kind, assets.expr_names)
    intrinsics, w2c = camera_rig(num_cameras, size, distance=CAMERA_DISTANCE[head_kind])
    shapes = {"A": np.zeros(model.num_shape),
              "B": np.asarray(head.identity(assets.shape_names, **IDENTITY_B_SHAPE[head_kind]))}
    albedos = {"A": assets.vertex_colors,
               "B": identity_albedo(model, assets, IDENTITY_B_ALBEDO)}
    colours = {k: shaded_colors(model, albedos[k], shapes[k]) for k in albedos}
    bg = np.ones(3) if background == "white" else np.zeros(3)
    held_out = (HELD_OUT_CAMERA % num_cameras,)
    train = tuple(i for i in range(num_cameras) if i not in held_out)

    images, regions, samples = _read_cache(path, sequences,
                                           (num_cameras, frames_per_sequence, size))
    if images is None:
        images, regions, samples = {}, {}, {}
        total = sum(s.num_frames for s in sequences.values())
        bar = _progress(total, "ground truth frames", progress)
        rays = ray_sets(rig_cameras(intrinsics, w2c, size), supersample)
        for name, seq in sequences.items():
            per_frame = []
            for t in range(seq.num_frames):
                per_frame.append(render_views(model, assets.face_regions, colours[seq.identity],
                                              shapes[seq.identity], seq, t, intrinsics, w2c,
                                              size, bg, supersample, rays))
                bar.update(1)
            images[name] = np.stack([[to_uint8(v.image) for v in f] for f in per_frame], 1)
            regions[name] = np.stack([[v.regions for v in f] for f in per_frame], 1).astype(
                np.int8)
            samples[name] = np.stack([[v.samples for v in f] for f in per_frame], 1)
        bar.close()
        _save_cache(path, images, regions, samples)
    return Scene(model=model, face_regions=assets.face_regions,
                 intrinsics=intrinsics.astype(np.float32), w2c=w2c.astype(np.float32),
                 width=size, height=size, train_cameras=train, held_out_cameras=held_out,
                 shapes=shapes, vertex_colors=colours, sequences=sequences, images=images,
                 regions=regions, region_samples=samples, background=bg.astype(np.float32),
                 kind="synthetic",
                 albedo=albedos, supersample=supersample, head=head_kind)


def scene_fingerprint(scene: Scene) -> str:
    """16 hex digits identifying a scene's cameras and ground truth (for caches built on it)."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(scene.intrinsics).tobytes())
    h.update(np.ascontiguousarray(scene.w2c).tobytes())
    for name in sorted(scene.images):
        h.update(name.encode())
        h.update(np.ascontiguousarray(scene.images[name]).tobytes())
    return h.hexdigest()[:16]


def _progress(total, desc, enabled):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, disable=not enabled, leave=False)


def _read_cache(path, sequences, shape):
    """(images, regions, region samples) from a cached scene, or Nones when there is none or
    it is unreadable (then it says so in one line and the scene is rebuilt)."""
    if not os.path.isfile(path):
        return None, None, None
    cameras, frames, size = shape
    try:
        images, regions, samples = {}, {}, {}
        with np.load(path) as f:
            for name in sequences:
                images[name], regions[name] = f[f"images/{name}"], f[f"regions/{name}"]
                samples[name] = f[f"samples/{name}"]
                if images[name].shape != (cameras, frames, size, size, 3):
                    raise ValueError(f"images/{name} has shape {images[name].shape}")
                if samples[name].shape[:4] != (cameras, frames, size, size):
                    raise ValueError(f"samples/{name} has shape {samples[name].shape}")
        return images, regions, samples
    except Exception as e:  # truncated zip, flipped bytes, missing member: rebuild
        print(f"warning: the cached scene {path} is unreadable ({type(e).__name__}: {e}); "
              "rebuilding it", file=sys.stderr)
        return None, None, None


def _save_cache(path, images, regions, samples):
    arrays = {f"images/{k}": v for k, v in images.items()}
    arrays.update({f"regions/{k}": v for k, v in regions.items()})
    arrays.update({f"samples/{k}": v for k, v in samples.items()})
    write_npz(path, arrays, compressed=True)
