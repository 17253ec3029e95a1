"""The ray-cast ground-truth renderer against closed-form ray/plane intersections."""

import numpy as np
import pytest

from gae_jax.render.camera import make_camera
from gae_jax.scene.raycast import raycast

# trimesh/embree intersect in float32 internally.
EMBREE_TOLERANCE = 1e-4


def two_triangles():
    """A red/green/blue triangle at z = 2 in front of a larger grey one at z = 3."""
    tri = np.array([[-0.6, -0.5], [0.7, -0.4], [0.0, 0.6]])
    verts = np.concatenate([np.c_[tri, np.full(3, 2.0)], np.c_[tri * 2.5, np.full(3, 3.0)]])
    colors = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5],
                       [0.5, 0.5, 0.5]], float)
    return verts, np.array([[0, 1, 2], [3, 4, 5]]), colors, np.array([7, 3])


def test_colour_depth_and_region_match_closed_form():
    verts, faces, colors, regions = two_triangles()
    camera = make_camera(np.eye(4), 40, 30, fov_degrees=60.0)
    out = raycast(verts, faces, colors, regions, camera, background=(0.1, 0.2, 0.3))
    fx, fy, cx, cy = np.asarray(camera.intrinsics)
    a, b, c = verts[:3, :2]
    checked = 0
    for i in range(30):
        for j in range(40):
            p = 2.0 * np.array([(j + 0.5 - cx) / fx, (i + 0.5 - cy) / fy])
            l1, l2 = np.linalg.solve(np.c_[b - a, c - a], p - a)
            bary = np.array([1 - l1 - l2, l1, l2])
            if bary.min() > 0.02:  # well inside the front triangle
                np.testing.assert_allclose(out.image[i, j], bary @ colors[:3],
                                           atol=EMBREE_TOLERANCE)
                assert out.depth[i, j] == pytest.approx(2.0, abs=EMBREE_TOLERANCE)
                assert out.regions[i, j] == 7
                checked += 1
    assert checked > 100
    behind = out.regions == 3
    assert behind.any(), "the larger back triangle shows around the front one"
    np.testing.assert_allclose(out.depth[behind], 3.0, atol=EMBREE_TOLERANCE)
    missed = ~out.hit
    assert missed.any() and np.all(out.regions[missed] == -1)
    np.testing.assert_allclose(out.image[missed], np.tile([0.1, 0.2, 0.3], (missed.sum(), 1)),
                               atol=1e-6)


def test_bad_shapes_are_rejected():
    verts, faces, colors, regions = two_triangles()
    camera = make_camera(np.eye(4), 8, 8)
    with pytest.raises(ValueError, match="vertex_colors"):
        raycast(verts, faces, colors[:2], regions, camera)
    with pytest.raises(ValueError, match="face_regions"):
        raycast(verts, faces, colors, regions[:1], camera)


def test_supersampled_edge_pixel_is_the_covered_fraction():
    """A red square whose right edge crosses pixel column 10 at 0.4 of its width: with 5 x 5
    rays (at 0.1, 0.3, ..., 0.9) exactly 2 of 5 columns of rays hit, so the pixel is 40 % red."""
    camera = make_camera(np.eye(4), 20, 12, fov_degrees=50.0)
    fx, _, cx, _ = np.asarray(camera.intrinsics, np.float64)
    z, edge = 2.0, (10.4 - cx) / fx * 2.0
    verts = np.array([[-5, -5, z], [edge, -5, z], [edge, 5, z], [-5, 5, z]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    colors = np.tile([1.0, 0.0, 0.0], (4, 1))
    out = raycast(verts, faces, colors, np.array([1, 1]), camera, background=(1, 1, 1),
                  supersample=5)
    np.testing.assert_allclose(out.image[:, 10], np.tile([1.0, 0.6, 0.6], (12, 1)), atol=1e-5)
    np.testing.assert_allclose(out.image[:, :10], 0 * out.image[:, :10] + [1, 0, 0], atol=1e-5)
    np.testing.assert_allclose(out.image[:, 11:], 1.0, atol=1e-6)
    # Labels and depth come from the centre ray, which misses at column 10.
    assert np.all(out.regions[:, 10] == -1) and np.all(out.regions[:, 9] == 1)
    single = raycast(verts, faces, colors, np.array([1, 1]), camera, background=(1, 1, 1))
    np.testing.assert_array_equal(single.regions, out.regions)
    # Each colour ray's region is kept: 2 of the edge pixel's 5 columns of rays hit the square.
    assert out.samples.shape == (12, 20, 25) and out.samples.dtype == np.int8
    assert np.all((out.samples[:, 10] == 1).sum(-1) == 10)
    assert np.all(out.samples[:, :10] == 1) and np.all(out.samples[:, 11:] == -1)
    np.testing.assert_array_equal(single.samples[..., 0], single.regions)
    with pytest.raises(ValueError, match="supersample"):
        raycast(verts, faces, colors, np.array([1, 1]), camera, supersample=0)


def test_threaded_views_equal_one_at_a_time():
    from gae_jax.scene.raycast import raycast_views

    verts, faces, colors, regions = two_triangles()
    cameras = [make_camera(np.eye(4), 24, 16, fov_degrees=f) for f in (40.0, 55.0, 70.0)]
    serial = raycast_views(verts, faces, colors, regions, cameras, supersample=3, workers=1)
    threaded = raycast_views(verts, faces, colors, regions, cameras, supersample=3, workers=2)
    for a, b in zip(serial, threaded):
        np.testing.assert_array_equal(a.image, b.image)
        np.testing.assert_array_equal(a.regions, b.regions)


def test_precomputed_rays_give_the_same_images_and_must_match_the_cameras():
    from gae_jax.scene.raycast import ray_sets, raycast_views

    verts, faces, colors, regions = two_triangles()
    cameras = [make_camera(np.eye(4), 24, 16, fov_degrees=f) for f in (40.0, 55.0)]
    for supersample in (1, 2, 3):
        rays = ray_sets(cameras, supersample)
        assert len(rays[0]) == supersample ** 2 + (supersample % 2 == 0)
        fresh = raycast_views(verts, faces, colors, regions, cameras, supersample=supersample)
        reused = raycast_views(verts, faces, colors, regions, cameras, supersample=supersample,
                               rays=rays)
        for a, b in zip(fresh, reused):
            for field in ("image", "regions", "depth", "hit", "faces", "samples"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    with pytest.raises(ValueError, match="rays holds 1 cameras"):
        raycast_views(verts, faces, colors, regions, cameras, rays=ray_sets(cameras[:1], 1))
