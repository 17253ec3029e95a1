"""Gaussians bound to triangles: frames, deformation, initialisation, densify and prune."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gae_jax.model import avatar as av
from gae_jax.render.projection import quat_to_rotmat


def random_mesh(seed=0, v=30, f=20):
    rng = np.random.default_rng(seed)
    verts = rng.normal(size=(v, 3))
    faces = np.stack([rng.choice(v, 3, replace=False) for _ in range(f)])
    return jnp.asarray(verts), jnp.asarray(faces, jnp.int32)


def random_rotation(seed):
    q = np.random.default_rng(seed).normal(size=4)
    return np.asarray(quat_to_rotmat(jnp.asarray(q[None]))[0])


def test_face_frames_are_orthonormal_right_handed_and_match_definition(x64):
    verts, faces = random_mesh()
    rot, k, centroid = av.face_frames(verts, faces)
    v = np.asarray(verts)
    for i, (a, b, c) in enumerate(np.asarray(faces)):
        r = np.asarray(rot[i])
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        e1, e2 = v[b] - v[a], v[c] - v[a]
        normal = np.cross(e1, e2)
        np.testing.assert_allclose(r[:, 0], e1 / np.linalg.norm(e1), atol=1e-12)
        np.testing.assert_allclose(r[:, 1], normal / np.linalg.norm(normal), atol=1e-12)
        height = np.linalg.norm(normal) / np.linalg.norm(e1)  # triangle height over edge e1
        assert float(k[i]) == pytest.approx(0.5 * (np.linalg.norm(e1) + height))
        np.testing.assert_allclose(centroid[i], (v[a] + v[b] + v[c]) / 3, atol=1e-12)


def test_rotmat_to_quat_round_trips(x64):
    rots = np.stack([random_rotation(s) for s in range(50)]
                    + [np.diag([1, -1, -1.0]), np.diag([-1, 1, -1.0]), np.diag([-1, -1, 1.0]),
                       np.eye(3)])
    q = av.rotmat_to_quat(jnp.asarray(rots))
    np.testing.assert_allclose(quat_to_rotmat(q), rots, atol=1e-12)
    grad = jax.grad(lambda r: jnp.sum(av.rotmat_to_quat(r) * jnp.arange(4.0)[None, :]))(jnp.asarray(rots))
    assert np.all(np.isfinite(np.asarray(grad)))


def test_gaussian_at_local_origin_lands_on_centroid_with_face_scale(x64):
    verts, faces = random_mesh(1)
    colors = jnp.ones((verts.shape[0], 3))
    a = av.init_from_mesh(verts, faces, colors, jnp.arange(faces.shape[0]))
    g = av.deform(a, verts, faces)
    _, k, centroid = av.face_frames(verts, faces)
    np.testing.assert_allclose(g.means, centroid, atol=1e-12)
    np.testing.assert_allclose(g.scales, np.repeat(np.asarray(k)[:, None], 3, 1), atol=1e-12)
    np.testing.assert_allclose(g.opacities, av.INIT_OPACITY, atol=1e-12)
    np.testing.assert_array_equal(a.regions, np.arange(faces.shape[0]))


def test_deform_follows_a_rigid_motion_of_the_mesh(x64):
    verts, faces = random_mesh(2)
    rng = np.random.default_rng(3)
    n = 40
    a = av.Avatar(binding=jnp.asarray(rng.integers(0, faces.shape[0], n), jnp.int32),
                  means=jnp.asarray(rng.normal(size=(n, 3))),
                  quats=jnp.asarray(rng.normal(size=(n, 4))),
                  log_scales=jnp.asarray(rng.normal(size=(n, 3))),
                  opacity_logits=jnp.zeros(n), colors=jnp.ones((n, 3)),
                  regions=jnp.zeros(n, jnp.int32))
    rot, shift = random_rotation(4), np.array([0.3, -1.0, 2.0])
    g0 = av.deform(a, verts, faces)
    g1 = av.deform(a, verts @ rot.T + shift[None, :], faces)
    np.testing.assert_allclose(g1.means, np.asarray(g0.means) @ rot.T + shift, atol=1e-10)
    np.testing.assert_allclose(g1.scales, g0.scales, atol=1e-10)
    np.testing.assert_allclose(quat_to_rotmat(g1.quats), rot @ quat_to_rotmat(g0.quats),
                               atol=1e-10)


def test_deform_gradients_match_finite_differences(x64):
    verts, faces = random_mesh(5, v=8, f=4)
    rng = np.random.default_rng(6)
    a = av.init_from_mesh(verts, faces, jnp.ones((8, 3)), jnp.zeros(4), per_face=2,
                          key=jax.random.PRNGKey(0))
    a = av.Avatar(a.binding, a.means, jnp.asarray(rng.normal(size=(8, 4))), a.log_scales,
                  a.opacity_logits, a.colors, a.regions)
    w = jax.random.normal(jax.random.PRNGKey(1), (8, 14), jnp.float64)

    def loss(verts, means, quats, log_scales):
        b = av.Avatar(a.binding, means, quats, log_scales, a.opacity_logits, a.colors, a.regions)
        g = av.deform(b, verts, faces)
        flat = jnp.concatenate([g.means, g.quats, g.scales, g.opacities[:, None],
                                g.colors[:, 0]], axis=-1)
        return jnp.sum(flat * w)

    check_grads(loss, (verts, a.means, a.quats, a.log_scales), order=1, modes=["rev"], eps=1e-6)


def test_init_with_several_per_face_puts_gaussians_inside_their_triangle(x64):
    verts, faces = random_mesh(7)
    a = av.init_from_mesh(verts, faces, jnp.ones((30, 3)), jnp.zeros(20), per_face=4,
                          key=jax.random.PRNGKey(2), sh_degree=3)
    assert a.num == 80 and a.colors.shape == (80, 16, 3)
    g = av.deform(a, verts, faces)
    tri = np.asarray(verts)[np.asarray(faces)[np.asarray(a.binding)]]
    # Barycentric coordinates of each mean in its own triangle are all >= 0.
    for p, t in zip(np.asarray(g.means), tri):
        m = np.stack([t[1] - t[0], t[2] - t[0]], -1)
        uv, *_ = np.linalg.lstsq(m, p - t[0], rcond=None)
        assert np.allclose(m @ uv, p - t[0], atol=1e-9)
        assert uv.min() > -1e-9 and uv.sum() < 1 + 1e-9


def test_prune_never_removes_the_last_gaussian_of_a_face():
    verts, faces = random_mesh(8)
    a = av.init_from_mesh(verts, faces, jnp.ones((30, 3)), jnp.arange(20), per_face=3,
                          key=jax.random.PRNGKey(3))
    logits = np.arange(60, dtype=np.float32)
    a = av.Avatar(a.binding, a.means, a.quats, a.log_scales, jnp.asarray(logits), a.colors,
                  a.regions)
    remove = np.zeros(60, bool)
    remove[np.asarray(a.binding) == 0] = True  # every Gaussian of face 0
    remove[np.asarray(a.binding) == 1][:2] = True
    pruned = av.prune(a, remove, 20)
    counts = np.bincount(np.asarray(pruned.binding), minlength=20)
    assert counts.min() >= 1 and counts[0] == 1
    survivor = np.asarray(pruned.opacity_logits)[np.asarray(pruned.binding) == 0][0]
    assert survivor == logits[np.asarray(a.binding) == 0].max()
    np.testing.assert_array_equal(pruned.regions, pruned.binding)
    again, source = av.prune(a, remove, 20, return_source=True)
    np.testing.assert_array_equal(np.asarray(again.opacity_logits), logits[source])
    emptied = av.prune(a, remove, 20, keep_every_face=False)
    assert emptied.num == 60 - remove.sum() and 0 not in np.asarray(emptied.binding)


def test_densify_children_inherit_binding_and_split_shrinks():
    verts, faces = random_mesh(9)
    a = av.init_from_mesh(verts, faces, jnp.ones((30, 3)), jnp.arange(20))
    clone = np.zeros(20, bool)
    split = np.zeros(20, bool)
    clone[[1, 2]] = True
    split[[2, 5]] = True  # split wins over clone
    d = av.densify(a, clone, split, jax.random.PRNGKey(4))
    assert d.num == 20 - 2 + 1 + 4
    counts = np.bincount(np.asarray(d.binding), minlength=20)
    assert counts[1] == 2 and counts[2] == 2 and counts[5] == 2 and counts[0] == 1
    np.testing.assert_array_equal(d.regions, d.binding)
    kids = np.asarray(d.binding) == 5
    np.testing.assert_allclose(np.asarray(d.log_scales)[kids], -np.log(1.6), atol=1e-6)
    assert not np.allclose(np.asarray(d.means)[kids][0], np.asarray(d.means)[kids][1])
    same, source = av.densify(a, clone, split, jax.random.PRNGKey(4), return_source=True)
    np.testing.assert_array_equal(np.asarray(same.binding), np.asarray(a.binding)[source])
    np.testing.assert_array_equal(np.asarray(same.colors), np.asarray(a.colors)[source])
    unchanged = ~np.isin(source, np.flatnonzero(split))
    np.testing.assert_array_equal(np.asarray(same.means)[unchanged],
                                  np.asarray(a.means)[source[unchanged]])


def test_deform_vmaps_over_frames(x64):
    verts, faces = random_mesh(10)
    a = av.init_from_mesh(verts, faces, jnp.ones((30, 3)), jnp.zeros(20))
    frames = jnp.stack([verts, verts * 1.3, verts[:, ::-1]])
    batched = jax.vmap(av.deform, in_axes=(None, 0, None))(a, frames, faces)
    for i in range(3):
        single = av.deform(a, frames[i], faces)
        np.testing.assert_allclose(batched.means[i], single.means, atol=1e-12)
        np.testing.assert_allclose(batched.quats[i], single.quats, atol=1e-12)


def test_vertex_normals_match_trimesh_and_gaussian_normals_average_their_face():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    verts = np.asarray(sphere.vertices) * np.array([1.0, 0.7, 1.3])
    faces = np.asarray(sphere.faces)
    mine = av.vertex_normals(verts, faces)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    # trimesh's mean of the adjacent faces' normals, each weighted by the face's area
    theirs = trimesh.geometry.mean_vertex_normals(
        len(verts), faces, mesh.face_normals * mesh.area_faces[:, None])
    np.testing.assert_allclose(mine, theirs, atol=1e-9)
    binding = np.array([0, 5, 5, 17])
    expected = mine[faces[binding]].mean(1)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(av.gaussian_normals(binding, verts, faces), expected, atol=1e-6)
