"""Gaussians bound to mesh triangles, as in GaussianAvatars.

Each Gaussian stores *local* parameters in the frame of its triangle (its `binding`):
  frame columns R = [a0, a1, a2] with a0 = normalise(v1 - v0), a1 = normalise(a0 x (v2 - v0)) (the
  face normal) and a2 = normalise(a0 x a1); scale k = (|v1 - v0| + |a2 . (v2 - v0)|) / 2; origin =
  centroid. World mean = k R mu + origin, world scale = k exp(s), world rotation = q_face (x) q,
  with q_face the quaternion of R (Hamilton product, wxyz). Positions and scales are therefore in
  units of triangle size. Activations (exp of log-scales, sigmoid of opacity logits) happen here.

Changing the number of Gaussians (`densify`, `prune`) runs outside jit on host arrays; children
inherit their parent's binding and region, and pruning never removes the last Gaussian of a face.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.render import sh
from gae_jax.render.projection import quat_to_rotmat
from gae_jax.render.splat import Gaussians

INIT_OPACITY = 0.1
# The per-Gaussian arrays an optimiser changes; `binding` and `regions` stay fixed.
TRAINABLE = ("means", "quats", "log_scales", "opacity_logits", "colors")
# A split child's scale is its parent's divided by this (3DGS: 0.8 * N with N = 2 children).
SPLIT_SCALE_DIVISOR = 1.6


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Avatar:
    """Gaussians in triangle-local coordinates.

    Attributes:
      binding: (N,) int32 face index of each Gaussian.
      means: (N, 3) local position, in units of the face scale k.
      quats: (N, 4) local rotation, wxyz (any non-zero norm).
      log_scales: (N, 3) local log-scale (world scale = k exp(s)).
      opacity_logits: (N,) opacity before the sigmoid.
      colors: (N, K, 3) SH coefficients or (N, C) plain colours (world orientation).
      regions: (N,) int32 region label inherited from the face.
    """

    binding: jax.Array
    means: jax.Array
    quats: jax.Array
    log_scales: jax.Array
    opacity_logits: jax.Array
    colors: jax.Array
    regions: jax.Array

    @property
    def num(self) -> int:
        return self.binding.shape[0]

    def trainable(self) -> dict:
        """The `TRAINABLE` arrays as a dict (what optimisers and `rig.render_bound` take)."""
        return {k: getattr(self, k) for k in TRAINABLE}

    def with_params(self, params: dict) -> "Avatar":
        """This avatar's binding and regions with new trainable arrays."""
        return Avatar(binding=self.binding, regions=self.regions, **params)


def face_frames(vertices: jax.Array, faces: jax.Array):
    """Per-face frames of a mesh.

    Args:
      vertices: (V, 3); faces: (F, 3) int.
    Returns:
      rotations (F, 3, 3) with columns [edge, normal, in-plane], scales (F,), centroids (F, 3).
    """
    v0, v1, v2 = (vertices[faces[:, i]] for i in range(3))
    e1, e2 = v1 - v0, v2 - v0

    def normalise(x):
        n = jnp.sqrt(jnp.sum(x * x, axis=-1, keepdims=True))
        return x / jnp.where(n > 0, n, 1.0)

    a0 = normalise(e1)
    a1 = normalise(jnp.cross(a0, e2))
    a2 = normalise(jnp.cross(a0, a1))
    rotations = jnp.stack([a0, a1, a2], axis=-1)
    scales = 0.5 * (jnp.sqrt(jnp.sum(e1 * e1, axis=-1)) + jnp.abs(jnp.sum(a2 * e2, axis=-1)))
    return rotations, scales, (v0 + v1 + v2) / 3.0


def vertex_normals(vertices, faces) -> np.ndarray:
    """(V, 3) unit vertex normals of a mesh: the sum of its faces' area-weighted normals (numpy,
    float64). vertices: (V, 3); faces: (F, 3) int."""
    verts = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    normals = np.zeros_like(verts)
    face_normals = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]],
                            verts[faces[:, 2]] - verts[faces[:, 0]])
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


def gaussian_normals(binding, vertices, faces) -> np.ndarray:
    """(N, 3) float32 unit normal of each Gaussian's place on the mesh: the mean of its face's
    three vertex normals (smooth across faces, as the surface's shading is). binding: (N,)."""
    corner = vertex_normals(vertices, faces)[np.asarray(faces)[np.asarray(binding)]].mean(1)
    return (corner / np.maximum(np.linalg.norm(corner, axis=1, keepdims=True), 1e-12)
            ).astype(np.float32)


def rotmat_to_quat(rot: jax.Array) -> jax.Array:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions, wxyz, w >= 0.

    Branch-free Shepperd: the four candidate quaternions are formed and the numerically best one
    (largest denominator) is selected, so values and gradients stay finite for every rotation.
    """
    m = rot
    t = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cands = jnp.stack([
        jnp.stack([1 + t, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0],
                   m[..., 1, 0] - m[..., 0, 1]], -1),
        jnp.stack([m[..., 2, 1] - m[..., 1, 2], 1 + 2 * m[..., 0, 0] - t,
                   m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
        jnp.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                   1 + 2 * m[..., 1, 1] - t, m[..., 1, 2] + m[..., 2, 1]], -1),
        jnp.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                   m[..., 1, 2] + m[..., 2, 1], 1 + 2 * m[..., 2, 2] - t], -1),
    ], axis=-2)  # (..., 4, 4); candidate i has component i equal to 4 q_i^2
    diag = jnp.stack([1 + t, 1 + 2 * m[..., 0, 0] - t, 1 + 2 * m[..., 1, 1] - t,
                      1 + 2 * m[..., 2, 2] - t], -1)
    best = jnp.argmax(diag, axis=-1)
    q = jnp.take_along_axis(cands, best[..., None, None], axis=-2)[..., 0, :]
    q = q / jnp.sqrt(jnp.sum(q * q, axis=-1, keepdims=True))
    return jnp.where(q[..., :1] < 0, -q, q)


def quat_multiply(a: jax.Array, b: jax.Array) -> jax.Array:
    """Hamilton product a (x) b of (..., 4) wxyz quaternions."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return jnp.stack([aw * bw - ax * bx - ay * by - az * bz,
                      aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx,
                      aw * bz + ax * by - ay * bx + az * bw], axis=-1)


@jax.jit
def deform(avatar: Avatar, vertices: jax.Array, faces: jax.Array) -> Gaussians:
    """World-space Gaussians of an avatar on a posed mesh ((V, 3) vertices, (F, 3) faces).
    Jitted: called on the host it compiles one program, not one per operation."""
    rotations, scales, centroids = face_frames(vertices, faces)
    rot, k, origin = (x[avatar.binding] for x in (rotations, scales, centroids))
    means = k[:, None] * jnp.einsum("nab,nb->na", rot, avatar.means) + origin
    norm = jnp.sqrt(jnp.sum(avatar.quats ** 2, axis=-1, keepdims=True))
    local_q = avatar.quats / jnp.where(norm > 0, norm, 1.0)
    quats = quat_multiply(rotmat_to_quat(rot), local_q)
    return Gaussians(means=means, quats=quats,
                     scales=k[:, None] * jnp.exp(avatar.log_scales),
                     opacities=jax.nn.sigmoid(avatar.opacity_logits), colors=avatar.colors)


@functools.partial(jax.jit, static_argnames=("per_face", "sh_degree", "opacity", "normal_scale"))
def init_from_mesh(vertices, faces, vertex_colors, face_regions, *, per_face: int = 1,
                   sh_degree: int | None = 0, key=None, opacity: float = INIT_OPACITY,
                   normal_scale: float = 1.0) -> Avatar:
    """Gaussians on every face (GaussianAvatars' initialisation, optionally denser).

    Args:
      vertices: (V, 3) rest mesh; faces: (F, 3); vertex_colors: (V, 3) albedo in [0, 1];
      face_regions: (F,) int region labels.
      per_face: Gaussians per face. One sits at the centroid with scale k (as GaussianAvatars);
        more are spread at random barycentric points (needs `key`) with scale k / sqrt(per_face).
      sh_degree: 0..3 stores SH coefficients (DC from the albedo, the rest zero); None stores
        plain RGB.
      opacity: initial opacity (GaussianAvatars: 0.1).
      normal_scale: scale factor along the face normal (1: spheres as GaussianAvatars; < 1:
        surfel-like discs that cover the surface without thickness).
    Jitted (the keyword settings static).
    """
    if per_face < 1:
        raise ValueError(f"per_face must be >= 1, got {per_face}")
    vertices = jnp.asarray(vertices)
    faces = jnp.asarray(faces, jnp.int32)
    num_faces = faces.shape[0]
    binding = jnp.repeat(jnp.arange(num_faces, dtype=jnp.int32), per_face)
    dtype = vertices.dtype
    if per_face == 1:
        local = jnp.zeros((num_faces, 3), dtype)
        bary = jnp.full((num_faces, 3), 1.0 / 3.0, dtype)
    else:
        if key is None:
            raise ValueError("init_from_mesh with per_face > 1 needs a PRNG key")
        bary = jax.random.dirichlet(key, jnp.ones(3, dtype), (num_faces * per_face,))
        rotations, scales, centroids = face_frames(vertices, faces)
        points = jnp.einsum("nk,nkc->nc", bary, vertices[faces[binding]])
        local = jnp.einsum("nba,nb->na", rotations[binding], points - centroids[binding])
        local = local / scales[binding, None]
    rgb = jnp.einsum("nk,nkc->nc", bary, jnp.asarray(vertex_colors, dtype)[faces[binding]])
    if sh_degree is None:
        colors = rgb
    else:
        colors = jnp.zeros((binding.shape[0], sh.num_coefficients(sh_degree), 3), dtype)
        colors = colors.at[:, 0].set(sh.rgb_to_dc(rgb))
    n = binding.shape[0]
    return Avatar(
        binding=binding, means=local.astype(dtype),
        quats=jnp.tile(jnp.asarray([1.0, 0.0, 0.0, 0.0], dtype), (n, 1)),
        log_scales=jnp.full((n, 3), -0.5 * np.log(per_face), dtype).at[:, 1].add(
            float(np.log(normal_scale))),
        opacity_logits=jnp.full((n,), float(np.log(opacity / (1 - opacity))), dtype),
        colors=colors, regions=jnp.asarray(face_regions, jnp.int32)[binding])


def take(avatar: Avatar, index) -> Avatar:
    """The Gaussians at `index` (host indices or a bool mask), in that order."""
    index = np.asarray(index)
    return jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)[index]), avatar)


def concat(a: Avatar, b: Avatar) -> Avatar:
    """`a`'s Gaussians followed by `b`'s."""
    return jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y]), a, b)


def prune(avatar: Avatar, remove, num_faces: int, return_source: bool = False,
          keep_every_face: bool = True):
    """Drops Gaussians where `remove` (N,) is True, by default keeping at least one per face.

    Where every Gaussian of a face is marked, the most opaque one survives unless
    `keep_every_face` is False (e.g. faces no camera ever sees). With `return_source`
    also returns (M,) the old index of every kept Gaussian (to carry optimiser state along).
    """
    remove = np.asarray(remove, bool).copy()
    if remove.shape != (avatar.num,):
        raise ValueError(f"remove must have shape ({avatar.num},), got {remove.shape}")
    binding = np.asarray(avatar.binding)
    kept_per_face = np.bincount(binding[~remove], minlength=num_faces)
    orphaned = np.flatnonzero((kept_per_face == 0) & (np.bincount(binding, minlength=num_faces)
                                                       > 0))
    if orphaned.size and keep_every_face:
        logits = np.asarray(avatar.opacity_logits)
        order = np.lexsort((-logits, binding))  # by face, most opaque first
        first = order[np.r_[True, binding[order][1:] != binding[order][:-1]]]
        rescue = first[np.isin(binding[first], orphaned)]
        remove[rescue] = False
    source = np.flatnonzero(~remove)
    pruned = take(avatar, source)
    return (pruned, source) if return_source else pruned


def densify(avatar: Avatar, clone, split, key, return_source: bool = False):
    """Clones Gaussians where `clone` is True and splits those where `split` is True.

    Clones copy their parent. A split parent is replaced by two children whose means are drawn
    from N(0, parent scale) in the parent's local frame (local units throughout) and whose
    scales are the parent's / 1.6. Children keep the parent's binding and region. With
    `return_source` also returns (M,) the old index each new Gaussian came from.
    """
    clone, split = np.asarray(clone, bool), np.asarray(split, bool)
    if clone.shape != (avatar.num,) or split.shape != (avatar.num,):
        raise ValueError("clone and split masks must have shape (N,)")
    clone = clone & ~split
    parents = take(avatar, np.flatnonzero(split))
    children = concat(parents, parents)
    m = parents.binding.shape[0]
    if m:
        noise = jax.random.normal(key, (2 * m, 3), children.means.dtype)
        offsets = jnp.einsum("nab,nb->na", quat_to_rotmat(children.quats),
                             noise * jnp.exp(children.log_scales))
        children = dataclasses.replace(
            children, means=children.means + offsets,
            log_scales=children.log_scales - np.log(SPLIT_SCALE_DIVISOR))
    kept = take(avatar, np.flatnonzero(~split))
    grown = concat(concat(kept, take(avatar, np.flatnonzero(clone))), children)
    if not return_source:
        return grown
    parents_index = np.flatnonzero(split)
    source = np.concatenate([np.flatnonzero(~split), np.flatnonzero(clone), parents_index,
                             parents_index])
    return grown, source
