"""The C++ ray caster against a brute-force float64 intersection of every ray with every
triangle, and against embree on the default head."""

import numpy as np
import pytest

from gae_jax.render.camera import make_camera, look_at_w2c
from gae_jax.scene import raycast, raycast_kernel

pytestmark = pytest.mark.skipif(not raycast_kernel.available(),
                                reason=f"the C++ ray caster is {raycast_kernel.why_unavailable()}")

# Both sides compute in float64; they differ by the order of their arithmetic.
FLOAT64_TOLERANCE = 1e-9
# embree intersects in float32: hit points agree to its precision at the head's scale (metres),
# colours mixed by its barycentrics to a few float32 roundings.
EMBREE_POINT_TOLERANCE = 2e-4
EMBREE_COLOUR_TOLERANCE = 1e-5


def brute_force_first_hits(vertices, faces, origins, dirs):
    """Moller-Trumbore of every ray with every triangle (float64, two-sided), the nearest t > 0;
    ties to the first face. Returns face, t, u, v as `first_hits` does."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    e1, e2 = b - a, c - a                                          # (F, 3)
    p = np.cross(dirs[:, None, :], e2[None])                        # (N, F, 3)
    det = np.einsum("fk,nfk->nf", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origins[:, None, :] - a[None]
        u = np.einsum("nfk,nfk->nf", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("nk,nfk->nf", dirs, q) * inv
        t = np.einsum("fk,nfk->nf", e2, q) * inv
    valid = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(valid, t, np.inf)
    face = np.argmin(t, axis=1)
    rows = np.arange(len(dirs))
    hit = np.isfinite(t[rows, face])
    return (np.where(hit, face, -1), t[rows, face], np.where(hit, u[rows, face], 0.0),
            np.where(hit, v[rows, face], 0.0))


def camera_rays(eye, target, size=24, fov=70.0, offset=(0.5, 0.5)):
    camera = make_camera(look_at_w2c(np.asarray(eye, float), np.asarray(target, float)),
                         size, size, fov_degrees=fov)
    return raycast.camera_rays(camera, offset)


def random_triangles(rng, count=40):
    """Triangles scattered in front of the eye at the origin looking down +z, overlapping in
    depth, some seen from behind."""
    centres = rng.uniform([-0.6, -0.6, 1.5], [0.6, 0.6, 3.0], (count, 3))
    corners = centres[:, None, :] + rng.normal(0, 0.35, (count, 3, 3))
    return corners.reshape(-1, 3), np.arange(3 * count).reshape(count, 3)


def assert_same_hits(found, expected):
    face, t, u, v = found[:4]
    face_ref, t_ref, u_ref, v_ref = expected
    np.testing.assert_array_equal(face, face_ref)
    hit = face_ref >= 0
    assert np.all(np.isinf(t[~hit]))
    np.testing.assert_allclose(t[hit], t_ref[hit], rtol=0, atol=FLOAT64_TOLERANCE)
    np.testing.assert_allclose(u[hit], u_ref[hit], rtol=0, atol=FLOAT64_TOLERANCE)
    np.testing.assert_allclose(v[hit], v_ref[hit], rtol=0, atol=FLOAT64_TOLERANCE)


@pytest.mark.parametrize("offset", [(0.5, 0.5), (0.25, 0.75)])
def test_first_hits_match_brute_force_on_overlapping_triangles(offset):
    rng = np.random.default_rng(0)
    vertices, faces = random_triangles(rng)
    origins, dirs = camera_rays((0, 0, 0), (0, 0, 1), offset=offset)
    expected = brute_force_first_hits(vertices, faces, origins, dirs)
    assert 0.3 < np.mean(expected[0] >= 0) < 1.0  # hits and misses both tested
    assert_same_hits(raycast_kernel.first_hits(vertices, faces, origins, dirs), expected)


def test_corner_values_are_mixed_by_the_hits_barycentrics():
    rng = np.random.default_rng(3)
    vertices, faces = random_triangles(rng)
    corner_values = rng.uniform(-1, 1, (len(faces), 3, 5))
    origins, dirs = camera_rays((0, 0, 0), (0, 0, 1), offset=(0.75, 0.25))
    face, _, u, v = brute_force_first_hits(vertices, faces, origins, dirs)
    hit = face >= 0
    expected = np.zeros((len(dirs), 5))
    expected[hit] = np.einsum("nk,nkc->nc", np.stack([1 - u - v, u, v], -1)[hit],
                              corner_values[face[hit]])
    hits = raycast_kernel.first_hits(vertices, faces, origins, dirs, corner_values)
    np.testing.assert_allclose(hits.values, expected, rtol=0, atol=FLOAT64_TOLERANCE)
    assert raycast_kernel.first_hits(vertices, faces, origins, dirs).values is None


def test_images_are_the_same_cast_by_the_kernel_or_by_embree(monkeypatch):
    rng = np.random.default_rng(4)
    vertices, faces = random_triangles(rng)
    colours = rng.uniform(0, 1, (len(vertices), 3))
    regions = np.arange(len(faces)) % 4
    camera = make_camera(look_at_w2c(np.zeros(3), np.array([0.0, 0.0, 1.0])), 32, 32,
                         fov_degrees=70.0)
    ours = raycast.raycast(vertices, faces, colours, regions, camera, supersample=2)
    monkeypatch.setattr(raycast_kernel, "first_hits", lambda *args: None)
    theirs = raycast.raycast(vertices, faces, colours, regions, camera, supersample=2)
    same = np.all(ours.samples == theirs.samples, -1) & (ours.faces == theirs.faces)
    assert same.mean() > 0.99  # the rest have a ray grazing an edge
    np.testing.assert_allclose(ours.image[same], theirs.image[same], rtol=0,
                               atol=EMBREE_COLOUR_TOLERANCE)
    np.testing.assert_allclose(ours.depth[same & ours.hit], theirs.depth[same & ours.hit],
                               rtol=1e-5)


def test_triangles_reaching_behind_the_eye_match_brute_force():
    """The eye inside a box: every face crosses or lies behind the image plane of some ray."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))])
    origins, dirs = camera_rays((0.1, -0.2, 0.3), (0.5, 0.4, 2.0), fov=120.0)
    expected = brute_force_first_hits(corners, faces, origins, dirs)
    assert np.all(expected[0] >= 0)
    assert_same_hits(raycast_kernel.first_hits(corners, faces, origins, dirs), expected)


def test_no_ray_slips_between_triangles_that_share_an_edge():
    """Rays from inside a closed fan aimed exactly at its shared edges and vertex all hit."""
    ring = np.array([[np.cos(a), np.sin(a), 1.0] for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    vertices = np.concatenate([[[0.0, 0.0, 1.0]], ring])
    faces = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    fractions = np.linspace(0.0, 1.0, 101)
    dirs = np.concatenate([f[:, None] * ring[k] + (1 - f[:, None]) * vertices[0]
                           for k in range(6) for f in [fractions]])
    origins = np.zeros_like(dirs)
    hits = raycast_kernel.first_hits(vertices, faces, origins, dirs)
    face, t = hits.face, hits.distance
    assert np.all(face >= 0)
    np.testing.assert_allclose(t, 1.0, rtol=0, atol=FLOAT64_TOLERANCE)


def test_first_hits_match_embree_on_the_default_head():
    from gae_jax.model import head
    from gae_jax.scene import synthetic

    model, _ = head.make_head("makehuman")
    vertices, faces = np.asarray(model.v_template, np.float64), np.asarray(model.faces)
    intrinsics, w2c = synthetic.camera_rig(16, 64, distance=synthetic.CAMERA_DISTANCE["makehuman"])
    embree = raycast.embree_scene(vertices, faces)
    agree, total = 0, 0
    for camera in synthetic.rig_cameras(intrinsics, w2c, 64)[::3]:
        origins, dirs = raycast.camera_rays(camera, (0.25, 0.75))
        hits = raycast_kernel.first_hits(vertices, faces, origins, dirs)
        face, t = hits.face, hits.distance
        found = embree.run(origins.astype(np.float32), dirs.astype(np.float32), output=1)
        same = face == found["primID"]
        agree, total = agree + same.sum(), total + len(face)
        hit = same & (face >= 0)
        points = origins + t[:, None] * dirs
        embree_points = origins + found["tfar"][:, None].astype(np.float64) * dirs
        assert np.abs(points[hit] - embree_points[hit]).max() < EMBREE_POINT_TOLERANCE
    assert agree / total > 0.9999  # the rest graze an edge, where float32 decides otherwise


def test_rays_it_cannot_cast_fall_back_to_embree():
    rng = np.random.default_rng(1)
    vertices, faces = random_triangles(rng)
    origins, dirs = camera_rays((0, 0, 0), (0, 0, 1))
    apart = origins + rng.normal(0, 1e-3, origins.shape)
    behind = np.concatenate([dirs, -dirs])
    assert raycast_kernel.first_hits(vertices, faces, apart, dirs) is None
    assert raycast_kernel.first_hits(vertices, faces, np.concatenate([origins, origins]),
                                     behind) is None
    mesh = (vertices, faces, None)
    hits = raycast._intersect(mesh, apart, dirs)  # embree, built on the spot
    face, t = hits.face, hits.distance
    expected = brute_force_first_hits(vertices, faces, apart, dirs)
    assert np.mean(face == expected[0]) > 0.999
    hit = (face >= 0) & (face == expected[0])
    np.testing.assert_allclose(t[hit], expected[1][hit], rtol=1e-5)


def test_bad_inputs_are_refused_in_one_line():
    vertices, faces = random_triangles(np.random.default_rng(2), 3)
    origins, dirs = camera_rays((0, 0, 0), (0, 0, 1), size=4)
    with pytest.raises(ValueError, match="out of range"):
        raycast_kernel.first_hits(vertices, faces + 1, origins, dirs)
    with pytest.raises(ValueError, match="dirs must be"):
        raycast_kernel.first_hits(vertices, faces, origins, dirs[:-1])
    with pytest.raises(ValueError, match="vertices must be"):
        raycast_kernel.first_hits(vertices[:, :2], faces, origins, dirs)
    with pytest.raises(ValueError, match="corner_values must be"):
        raycast_kernel.first_hits(vertices, faces, origins, dirs, np.zeros((len(faces), 2, 3)))
