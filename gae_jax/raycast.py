"""Ground-truth images by ray casting a coloured triangle mesh (trimesh, embree when installed).

An independent renderer: it shares nothing with `splat` but the `Camera` convention (OpenCV axes,
pixel centres at +0.5). Each pixel's ray hits the first triangle; colour is the barycentric
interpolation of the vertex colours, the region label is the hit triangle's, depth is the camera
z of the hit. Runs outside jit on numpy arrays.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax.camera import Camera


@dataclasses.dataclass(frozen=True)
class RaycastImage:
    """image (H, W, 3), regions (H, W) int32 (-1 = background), depth (H, W) (inf = miss),
    hit (H, W) bool, faces (H, W) int (-1 = miss)."""

    image: np.ndarray
    regions: np.ndarray
    depth: np.ndarray
    hit: np.ndarray
    faces: np.ndarray


def camera_rays(camera: Camera):
    """World-space ray origins and unit directions, (H*W, 3) each, row-major over pixels."""
    fx, fy, cx, cy = (float(v) for v in np.asarray(camera.intrinsics, np.float64))
    w2c = np.asarray(camera.w2c, np.float64)
    rot = w2c[:3, :3]
    eye = -rot.T @ w2c[:3, 3]
    ys, xs = np.mgrid[0:camera.height, 0:camera.width] + 0.5
    d_cam = np.stack([(xs - cx) / fx, (ys - cy) / fy, np.ones_like(xs)], -1).reshape(-1, 3)
    d_world = d_cam @ rot
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    return np.broadcast_to(eye, d_world.shape).copy(), d_world


def raycast(vertices, faces, vertex_colors, face_regions, camera: Camera,
            background=(1.0, 1.0, 1.0)) -> RaycastImage:
    """Renders a mesh by ray casting.

    Args:
      vertices: (V, 3) world positions; faces: (F, 3) int; vertex_colors: (V, 3) in [0, 1];
      face_regions: (F,) int labels; background: (3,) colour of pixels that miss.
    """
    import trimesh

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    colors = np.asarray(vertex_colors, np.float64)
    regions = np.asarray(face_regions)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got {vertices.shape}")
    if colors.shape != vertices.shape:
        raise ValueError(f"vertex_colors must be {vertices.shape}, got {colors.shape}")
    if regions.shape != (faces.shape[0],):
        raise ValueError(f"face_regions must be ({faces.shape[0]},), got {regions.shape}")
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    origins, dirs = camera_rays(camera)
    locations, ray_index, tri_index = mesh.ray.intersects_location(origins, dirs,
                                                                  multiple_hits=False)
    n = origins.shape[0]
    face_of = np.full(n, -1, np.int64)
    face_of[ray_index] = tri_index
    image = np.tile(np.asarray(background, np.float64), (n, 1))
    depth = np.full(n, np.inf)
    if len(ray_index):
        tri = vertices[faces[tri_index]]
        bary = trimesh.triangles.points_to_barycentric(tri, locations)
        image[ray_index] = np.einsum("nk,nkc->nc", bary, colors[faces[tri_index]])
        w2c = np.asarray(camera.w2c, np.float64)
        depth[ray_index] = locations @ w2c[2, :3] + w2c[2, 3]
    shape = (camera.height, camera.width)
    region_map = np.where(face_of >= 0, regions[np.maximum(face_of, 0)], -1).astype(np.int32)
    return RaycastImage(image=image.reshape(shape + (3,)).astype(np.float32),
                        regions=region_map.reshape(shape), depth=depth.reshape(shape),
                        hit=(face_of >= 0).reshape(shape), faces=face_of.reshape(shape))
