"""Ground-truth images by ray casting a coloured triangle mesh (the C++ caster of
`raycast_kernel`; embree, through embreex, where it is not built or the rays do not share an
origin).

An independent renderer: it shares nothing with `splat` but the `Camera` convention (OpenCV axes,
pixel centres at +0.5). Each ray hits the first triangle; its colour is the barycentric
interpolation of the vertex colours. A pixel's colour is the box-filtered mean of
`supersample` x `supersample` stratified rays (a camera integrates over its pixel; a single ray
per pixel leaves aliased, stair-stepped edges no smooth renderer can match). The region label,
depth and face come from the pixel's centre ray; the region label of each colour ray is kept too
(`samples`: how much of an edge pixel each region covers). Runs outside jit on numpy arrays.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax.render.camera import Camera
from gae_jax.scene import raycast_kernel


@dataclasses.dataclass(frozen=True)
class RaycastImage:
    """image (H, W, 3), regions (H, W) int32 (-1 = background), depth (H, W) (inf = miss),
    hit (H, W) bool, faces (H, W) int (-1 = miss), samples (H, W, S) int8: the region label
    of each of the pixel's S = supersample^2 colour rays (row-major over the stratified
    offsets; S = 1: the centre ray's)."""

    image: np.ndarray
    regions: np.ndarray
    depth: np.ndarray
    hit: np.ndarray
    faces: np.ndarray
    samples: np.ndarray


def camera_rays(camera: Camera, offset=(0.5, 0.5)):
    """World-space ray origins and unit directions, (H*W, 3) each, row-major over pixels.

    offset: (x, y) position of the ray inside each pixel, in pixels (0.5, 0.5 = centre).
    """
    fx, fy, cx, cy = (float(v) for v in np.asarray(camera.intrinsics, np.float64))
    w2c = np.asarray(camera.w2c, np.float64)
    rot = w2c[:3, :3]
    eye = -rot.T @ w2c[:3, 3]
    ys, xs = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    xs, ys = xs + offset[0], ys + offset[1]
    d_cam = np.stack([(xs - cx) / fx, (ys - cy) / fy, np.ones_like(xs)], -1).reshape(-1, 3)
    d_world = d_cam @ rot
    d_world /= np.linalg.norm(d_world, axis=1, keepdims=True)
    return np.broadcast_to(eye, d_world.shape).copy(), d_world


def ray_sets(cameras, supersample: int) -> list:
    """Per camera, {(x, y) offset inside the pixel: (origins, directions)} of every ray
    `raycast_views` casts (the centre (0.5, 0.5) and the `supersample`^2 stratified offsets).
    A fixed rig's rays are the same for every frame: build them once and pass them in."""
    cells = (np.arange(supersample) + 0.5) / supersample
    offsets = {(0.5, 0.5)} | {(float(x), float(y)) for y in cells for x in cells}
    return [{o: camera_rays(camera, o) for o in sorted(offsets)} for camera in cameras]


def embree_scene(vertices, faces):
    """An embree scene of the mesh (float32 vertices: embree intersects in float32)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=np.ascontiguousarray(vertices, np.float32),
                 indices=np.ascontiguousarray(faces, np.int32))
    return scene


def _intersect(mesh, origins, dirs, corner_values=None) -> raycast_kernel.Hits:
    """First hits of rays on `mesh` = (vertices (V, 3), faces (F, 3), embree scene or None), and
    `corner_values` (F, 3, K) mixed at them when given: the C++ caster when it can cast these
    rays, else embree (float32, its scene built here if not given; values left to the caller)."""
    vertices, faces, embree = mesh
    hits = raycast_kernel.first_hits(vertices, faces, origins, dirs, corner_values)
    if hits is not None:
        return hits
    embree = embree if embree is not None else embree_scene(vertices, faces)
    found = embree.run(np.ascontiguousarray(origins, np.float32),
                       np.ascontiguousarray(dirs, np.float32), output=1)
    face_of = found["primID"].astype(np.int64)
    distance = np.where(face_of >= 0, found["tfar"].astype(np.float64), np.inf)
    return raycast_kernel.Hits(face_of, distance, found["u"].astype(np.float64),
                               found["v"].astype(np.float64))


def _first_hits(mesh, face_colors, origins, dirs, background, shade=True, shader=None):
    """Face (N,) int64 (-1 = miss), distance along the ray (N,) float64 (inf at a miss) and,
    when `shade`, colour (N, 3) float64: the corner values mixed with the hits' barycentrics
    (clipped to [0, 1], renormalised), through `shader` when given. face_colors: (F, 3, K)
    float64, the K values of each face's corners; mesh: as `_intersect` takes it."""
    hits = _intersect(mesh, origins, dirs, face_colors if shade else None)
    face_of, hit = hits.face, hits.face >= 0
    if not shade:
        return face_of, hits.distance, None
    values = hits.values
    if values is None:
        u, v = hits.u[hit], hits.v[hit]
        bary = np.clip(np.stack([1 - u - v, u, v], -1), 0, 1)
        bary /= bary.sum(-1, keepdims=True)
        values = np.zeros((len(face_of), face_colors.shape[2]))
        values[hit] = np.einsum("nk,nkc->nc", bary, face_colors[face_of[hit]])
    if shader is None:
        image = np.where(hit[:, None], values[:, :3], np.asarray(background, np.float64))
    else:
        image = np.tile(np.asarray(background, np.float64), (len(face_of), 1))
        image[hit] = shader(values[hit], face_of[hit])
    return face_of, hits.distance, image


def raycast(vertices, faces, vertex_colors, face_regions, camera: Camera,
            background=(1.0, 1.0, 1.0), supersample: int = 1) -> RaycastImage:
    """Renders a mesh by ray casting.

    Args:
      vertices: (V, 3) world positions; faces: (F, 3) int; vertex_colors: (V, 3) in [0, 1];
      face_regions: (F,) int labels; background: (3,) colour of pixels that miss.
      supersample: rays per pixel along each axis for the colour (1 = the centre ray only).
    """
    return raycast_views(vertices, faces, vertex_colors, face_regions, [camera], background,
                         supersample, workers=1)[0]


def raycast_views(vertices, faces, vertex_colors, face_regions, cameras, background=(1.0, 1.0, 1.0),
                  supersample: int = 1, workers: int | None = None,
                  rays: list | None = None, shape: tuple | None = None,
                  shader=None) -> list[RaycastImage]:
    """`raycast` of one mesh from several cameras on `workers` threads (the C++ caster and embree
    release the GIL; None = one per CPU). `rays`: the cameras' `ray_sets(cameras, supersample)`,
    when the caller casts the same rig again; `shape`: the
    (H, W) the rays form when they are not the cameras' full pixel grids (a subsampled grid).

    `shader(values (N, K), faces (N,)) -> (N, 3)` colours each ray's hit from the K values of
    `vertex_colors` (V, K) interpolated there, before the pixel's rays are averaged (a pattern
    decided per ray, e.g. stripes sharper than the mesh); without it K is 3 and the values are
    the colour."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    colors = np.asarray(vertex_colors, np.float64)
    regions = np.asarray(face_regions)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3), got {vertices.shape}")
    if colors.ndim != 2 or len(colors) != len(vertices) or (
            colors.shape[1] != 3 if shader is None else colors.shape[1] < 1):
        raise ValueError(f"vertex_colors must be {vertices.shape} (or (V, K) with a shader), "
                         f"got {colors.shape}")
    if regions.shape != (faces.shape[0],):
        raise ValueError(f"face_regions must be ({faces.shape[0]},), got {regions.shape}")
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    rays = ray_sets(cameras, supersample) if rays is None else rays
    if len(rays) != len(cameras):
        raise ValueError(f"rays holds {len(rays)} cameras' rays for {len(cameras)} cameras")
    mesh = (vertices, faces, None if raycast_kernel.available() else embree_scene(vertices, faces))
    face_colors = colors[faces]

    def view(args):
        return _view(mesh, face_colors, regions, *args, background, supersample, shape,
                     shader)

    workers = workers or os.cpu_count() or 1
    if workers == 1 or len(cameras) == 1:
        return [view(a) for a in zip(cameras, rays)]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(view, zip(cameras, rays)))


def _view(mesh, face_colors, regions, camera, rays, background, supersample, shape=None,
          shader=None):
    """One camera's RaycastImage: colour from `supersample`^2 stratified rays per pixel; face,
    region and depth from the centre ray (whose colour is one of the samples when the count is
    odd and is not computed when it is even); each colour ray's region in `samples`."""
    origins, dirs = rays[(0.5, 0.5)]
    centre_is_sample = supersample % 2 == 1
    face_of, distance, centre = _first_hits(mesh, face_colors, origins, dirs, background,
                                            shade=centre_is_sample, shader=shader)

    def region_of(faces_hit):
        return np.where(faces_hit >= 0, regions[np.maximum(faces_hit, 0)], -1).astype(np.int8)

    if supersample == 1:
        image, samples = centre, [region_of(face_of)]
    else:
        image, samples = np.zeros((origins.shape[0], 3)), []
        cells = (np.arange(supersample) + 0.5) / supersample
        for oy in cells:
            for ox in cells:
                if ox == oy == 0.5:
                    image += centre
                    samples.append(region_of(face_of))
                    continue
                hit_faces, _, colour = _first_hits(mesh, face_colors,
                                                   *rays[(float(ox), float(oy))], background,
                                                   shader=shader)
                image += colour
                samples.append(region_of(hit_faces))
        image /= supersample ** 2
    w2c = np.asarray(camera.w2c, np.float64)
    hit = face_of >= 0
    points = origins + np.where(hit, distance, 0.0)[:, None] * dirs
    depth = np.where(hit, points @ w2c[2, :3] + w2c[2, 3], np.inf)
    shape = shape or (camera.height, camera.width)
    region_map = np.where(hit, regions[np.maximum(face_of, 0)], -1).astype(np.int32)
    return RaycastImage(image=image.reshape(shape + (3,)).astype(np.float32),
                        regions=region_map.reshape(shape), depth=depth.reshape(shape),
                        hit=hit.reshape(shape), faces=face_of.reshape(shape),
                        samples=np.stack(samples, -1).reshape(shape + (len(samples),)))
