"""Views a capture never shows, labelled by its tracked mesh alone.

A reconstruction supervised only in the training views learns where regions end there; seen from
between the cameras, or with the jaw open wider than in any training frame, a region's
Gaussians can reach over their neighbours, and a recolour of that region then paints the
neighbours' pixels. The tracked mesh knows its face regions in any pose and from any camera,
so these views carry labels (and no image): cameras between two training cameras, and poses
between two training frames with the expression carried up to `reach` times as far.
"""

from __future__ import annotations

import dataclasses
import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import jax
import numpy as np

from gae_jax.model import flame
from gae_jax.render.camera import Camera
from gae_jax.scene.types import (LABEL_SUPERSAMPLE, UNKNOWN_REGION, Scene, frame_params,
                                 training_frames)


@dataclasses.dataclass(frozen=True)
class UnseenViews:
    """K views, each one posed mesh seen by one camera.

    vertices: (K, V, 3) posed mesh; intrinsics: (K, 4); w2c: (K, 4, 4);
    labels: (K, H, W, S) int8 region labels of S rays in each pixel (`UNKNOWN_REGION` where the
    rays miss the mesh: a capture's foreground there is not known).
    """

    vertices: np.ndarray
    intrinsics: np.ndarray
    w2c: np.ndarray
    labels: np.ndarray


def camera_between(intrinsics_a, w2c_a, intrinsics_b, w2c_b, t: float):
    """The camera a fraction `t` of the way from camera a to camera b: its centre on the line
    between theirs, its orientation on the shortest rotation between theirs, its intrinsics
    mixed linearly. Returns ((4,) intrinsics, (4, 4) w2c)."""
    rot_a, rot_b = np.asarray(w2c_a[:3, :3], np.float64), np.asarray(w2c_b[:3, :3], np.float64)
    centre_a = -rot_a.T @ np.asarray(w2c_a[:3, 3], np.float64)
    centre_b = -rot_b.T @ np.asarray(w2c_b[:3, 3], np.float64)
    turn = cv2.Rodrigues(rot_b @ rot_a.T)[0]
    rot = cv2.Rodrigues(t * turn)[0] @ rot_a
    centre = (1.0 - t) * centre_a + t * centre_b
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rot, -rot @ centre
    return (1.0 - t) * np.asarray(intrinsics_a) + t * np.asarray(intrinsics_b), w2c


def pose_between(a: flame.FlameParams, b: flame.FlameParams, t: float,
                 stretch: float) -> flame.FlameParams:
    """Frame parameters a fraction `t` of the way from a to b, the expression (blendshapes,
    jaw, eyes) then scaled by `stretch` (1: as mixed; > 1: a wider jaw, a stronger smile than
    either frame's)."""
    mixed = jax.tree_util.tree_map(lambda p, q: (1.0 - t) * p + t * q, a, b)
    return dataclasses.replace(mixed, expr=stretch * mixed.expr, jaw=stretch * mixed.jaw,
                               eyes=stretch * mixed.eyes)


def unseen_views(scene: Scene, count: int, seed: int, reach: float = 1.25) -> UnseenViews:
    """`count` views of identity A between the scene's training cameras and frames: for each, two
    random training cameras and a uniform fraction between them, two random training frames
    and a uniform fraction between them, the expression stretched by a uniform factor in
    [1, `reach`]. Labels are the mesh's face regions along `LABEL_SUPERSAMPLE`^2 rays per
    pixel; deterministic in `seed`."""
    from gae_jax.scene import raycast

    if count < 1 or reach < 1.0:
        raise ValueError(f"need count >= 1 and reach >= 1, got {count} and {reach}")
    rng = np.random.default_rng(seed)
    frames = training_frames(scene)
    cams = np.asarray(scene.train_cameras)
    faces = np.asarray(scene.model.faces)
    vertices, intrinsics, w2cs = [], [], []
    for _ in range(count):
        ca, cb = rng.choice(cams, 2, replace=False)
        fa, fb = rng.choice(len(frames), 2, replace=False)
        intr, w2c = camera_between(scene.intrinsics[ca], scene.w2c[ca], scene.intrinsics[cb],
                                   scene.w2c[cb], rng.uniform())
        params = pose_between(frame_params(scene, *frames[fa]), frame_params(scene, *frames[fb]),
                              rng.uniform(), rng.uniform(1.0, reach))
        vertices.append(np.asarray(flame.lbs(scene.model, params)))
        intrinsics.append(intr)
        w2cs.append(w2c)

    def labels_of(k):
        camera = Camera(intrinsics=np.float32(intrinsics[k]), w2c=np.float32(w2cs[k]),
                        width=scene.width, height=scene.height)
        hit = raycast.raycast_views(vertices[k], faces, np.zeros((vertices[k].shape[0], 3)),
                                    scene.face_regions, [camera],
                                    supersample=LABEL_SUPERSAMPLE, workers=1)[0]
        return np.where(hit.samples >= 0, hit.samples, UNKNOWN_REGION).astype(np.int8)

    # embree releases the GIL: one view per thread.
    with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
        labels = list(pool.map(labels_of, range(count)))
    return UnseenViews(np.stack(vertices).astype(np.float32),
                       np.stack(intrinsics).astype(np.float32), np.stack(w2cs).astype(np.float32),
                       np.stack(labels))
