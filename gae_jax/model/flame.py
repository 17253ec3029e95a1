"""FLAME in JAX: shape/expression blendshapes, pose correctives and linear blend skinning.

Conventions (as FLAME and GaussianAvatars define them): 5 joints -- 0 global (root), 1 neck,
2 jaw, 3 left eye, 4 right eye -- with parents (-1, 0, 1, 1, 1); the pose vector is
[global 3 | neck 3 | jaw 3 | eyes 6] as axis-angle; pose correctives are driven by (R_j - I) of the
non-root joints, row-major, joint after joint. `lbs` works on one frame; `jax.vmap` it over frames.
Reading and writing model files, and GaussianAvatars' teeth, live in `flame_io`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

FLAME_PARENTS = (-1, 0, 1, 1, 1)
JOINT_NAMES = ("global", "neck", "jaw", "eye_left", "eye_right")
NECK_JOINT, JAW_JOINT = 1, 2
# smplx/FLAME take the rotation angle as |theta + 1e-8| so that the zero pose has a gradient.
RODRIGUES_EPS = 1e-8


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FlameModel:
    """FLAME constants (V vertices, J joints, F faces).

    Attributes:
      v_template: (V, 3) template vertices.
      shapedirs: (V, 3, S) identity blendshapes.
      exprdirs: (V, 3, E) expression blendshapes.
      posedirs: (V, 3, (J-1)*9) pose-corrective blendshapes.
      j_regressor: (J, V) joint regressor.
      lbs_weights: (V, J) skinning weights.
      faces: (F, 3) int32 triangles.
      parents: joint parents, parents[0] = -1 (static).
    """

    v_template: jax.Array
    shapedirs: jax.Array
    exprdirs: jax.Array
    posedirs: jax.Array
    j_regressor: jax.Array
    lbs_weights: jax.Array
    faces: jax.Array
    parents: tuple = dataclasses.field(metadata=dict(static=True), default=FLAME_PARENTS)

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_shape(self) -> int:
        return self.shapedirs.shape[-1]

    @property
    def num_expr(self) -> int:
        return self.exprdirs.shape[-1]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FlameParams:
    """Per-frame FLAME parameters (add a leading frame axis and `jax.vmap` for sequences).

    Attributes:
      shape: (S,) identity coefficients; expr: (E,) expression coefficients.
      rotation, neck, jaw: (3,) axis-angle; eyes: (6,) left then right axis-angle.
      translation: (3,) added after skinning.
      static_offset: optional (V, 3) per-vertex offset added to the shaped template.
    """

    shape: jax.Array
    expr: jax.Array
    rotation: jax.Array
    neck: jax.Array
    jaw: jax.Array
    eyes: jax.Array
    translation: jax.Array
    static_offset: Optional[jax.Array] = None

    @property
    def full_pose(self) -> jax.Array:
        """(15,) [global | neck | jaw | eyes]."""
        return jnp.concatenate([self.rotation, self.neck, self.jaw, self.eyes], axis=-1)


FLAME_VERTICES, TEETH_VERTICES = 5023, 120  # FLAME's, and GaussianAvatars' teeth's


def fit_static_offset(offset, num_vertices: int) -> np.ndarray:
    """(V, 3) float32 static offset for a model of V vertices from an (R, 3) or (1, R, 3) one:
    rows beyond R are zero (as GaussianAvatars pads a FLAME-sized offset for its teeth); the
    teeth's rows are dropped for plain FLAME; ValueError for any other R > V (an offset of
    another model)."""
    rows = np.asarray(offset, np.float32).reshape(-1, 3)
    if len(rows) == FLAME_VERTICES + TEETH_VERTICES and num_vertices == FLAME_VERTICES:
        rows = rows[:FLAME_VERTICES]
    if len(rows) > num_vertices:
        raise ValueError(f"static_offset has {len(rows)} rows, the model {num_vertices} "
                         "vertices (an offset of another model?)")
    return np.concatenate([rows, np.zeros((num_vertices - len(rows), 3), np.float32)])


def zero_params(model: FlameModel, dtype=jnp.float32) -> FlameParams:
    """Neutral shape and expression, zero pose and translation."""
    z3 = jnp.zeros(3, dtype)
    return FlameParams(shape=jnp.zeros(model.num_shape, dtype),
                       expr=jnp.zeros(model.num_expr, dtype), rotation=z3, neck=z3, jaw=z3,
                       eyes=jnp.zeros(6, dtype), translation=z3)


def rodrigues(axis_angle: jax.Array) -> jax.Array:
    """(..., 3) axis-angle -> (..., 3, 3) rotation, R = I + sin(a) K + (1 - cos(a)) K^2."""
    angle = jnp.linalg.norm(axis_angle + RODRIGUES_EPS, axis=-1, keepdims=True)
    axis = axis_angle / angle
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = jnp.zeros_like(x)
    k = jnp.stack([jnp.stack([zero, -z, y], -1), jnp.stack([z, zero, -x], -1),
                   jnp.stack([-y, x, zero], -1)], -2)
    s, c = jnp.sin(angle)[..., None], jnp.cos(angle)[..., None]
    eye = jnp.broadcast_to(jnp.eye(3, dtype=axis_angle.dtype), k.shape)
    return eye + s * k + (1.0 - c) * (k @ k)


def shaped_vertices(model: FlameModel, params: FlameParams) -> jax.Array:
    """(V, 3) template + identity and expression blendshapes (+ static offset)."""
    v = (model.v_template + jnp.einsum("vcs,s->vc", model.shapedirs, params.shape)
         + jnp.einsum("vce,e->vc", model.exprdirs, params.expr))
    if params.static_offset is not None:
        v = v + params.static_offset
    return v


@functools.partial(jax.jit, static_argnames="return_joints")
def lbs(model: FlameModel, params: FlameParams, return_joints: bool = False):
    """Posed vertices (V, 3) of one frame (and (J, 3) posed joints when asked). Jitted: called
    on the host it compiles one program per model and dtype, not one per operation (~40)."""
    v_shaped = shaped_vertices(model, params)
    joints = model.j_regressor @ v_shaped
    num_joints = len(model.parents)
    rots = rodrigues(params.full_pose.reshape(num_joints, 3))
    eye = jnp.eye(3, dtype=rots.dtype)
    pose_feature = (rots[1:] - eye[None]).reshape(-1)
    v_posed = v_shaped + jnp.einsum("vcp,p->vc", model.posedirs, pose_feature)

    def rigid(r, t):
        top = jnp.concatenate([r, t[:, None]], axis=1)
        return jnp.concatenate([top, jnp.asarray([[0.0, 0.0, 0.0, 1.0]], r.dtype)], axis=0)

    chain = []
    for j, parent in enumerate(model.parents):
        rel = joints[j] if parent < 0 else joints[j] - joints[parent]
        local = rigid(rots[j], rel)
        chain.append(local if parent < 0 else chain[parent] @ local)
    world = jnp.stack(chain)  # (J, 4, 4)
    posed_joints = world[:, :3, 3]
    # Remove the rest joint positions so each transform acts on rest-pose vertices.
    offset = posed_joints - jnp.einsum("jab,jb->ja", world[:, :3, :3], joints)
    transforms = world.at[:, :3, 3].set(offset)
    per_vertex = jnp.einsum("vj,jab->vab", model.lbs_weights, transforms)
    verts = (jnp.einsum("vab,vb->va", per_vertex[:, :3, :3], v_posed) + per_vertex[:, :3, 3]
             + params.translation[None, :])
    if return_joints:
        return verts, posed_joints + params.translation[None, :]
    return verts
