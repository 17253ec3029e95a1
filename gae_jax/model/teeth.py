"""GaussianAvatars' teeth, exactly: the 120 vertices and 168 faces its `FlameHead` appends to
FLAME, in its vertex order and face order, with its skinning.

GaussianAvatars always builds FLAME with these teeth, and its avatars bind Gaussians to the
teeth faces (faces F .. F + 167 after FLAME's F), so a FLAME file is loaded with them
(`with_teeth`) for its avatars to bind and pose as in its code. Geometry from the template and
the two outer lip rings (15 vertex ids each, paired by position): with d the mean distance of
the pairs, m_i the midpoint of pair i with its height replaced by the mean height of all
midpoints and pushed back by 1.5 d, the upper edge is m + 0.1 d up and its root 2 d above it;
the lower edge m - 0.1 d up and 0.4 d back, its root 2 d below it; each row has a copy d behind
it. Rows are appended in the order upper root, lower root, upper edge, lower edge, upper root
back, upper edge back, lower root back, lower edge back (15 vertices each, column i of ring pair
i). Upper rows skin rigidly to the neck joint, lower rows to the jaw; the joint regressor and
pose correctives ignore them; the identity blendshapes of column i are the mean of ring pair
i's, the expression ones zero. The faces: six strips of 14 quads (two triangles each; the
diagonal flips at the mouth's centre, quad 7), upper teeth first; their corner order is
GaussianAvatars' (it defines each face's frame, hence each bound Gaussian's pose).
Axes as FLAME: y up, the face looks towards +z.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from gae_jax.model.flame import JAW_JOINT, NECK_JOINT, FlameModel

# FLAME's outer lip rings (GaussianAvatars' FlameMask), paired by position, left to right.
FLAME_UPPER_LIP = (1713, 1715, 1716, 1735, 1696, 1694, 1657, 3543, 2774, 2811, 2813, 2850, 2833,
                   2832, 2830)
FLAME_LOWER_LIP = (1576, 1577, 1773, 1774, 1795, 1802, 1865, 3503, 2948, 2905, 2898, 2881, 2880,
                   2713, 2712)
ROWS = ("upper_root", "lower_root", "upper_edge", "lower_edge", "upper_root_back",
        "upper_edge_back", "lower_root_back", "lower_edge_back")
UPPER_ROWS = (0, 2, 4, 5)
# (row X, row Y, left pair, right pair) per strip; a pair is two triangles of corners named
# X0, X1, Y0, Y1 (row X or Y at quad column c or c + 1).
STRIPS = (
    (0, 2, ("X0 Y1 Y0", "X0 X1 Y1"), ("X0 X1 Y0", "X1 Y1 Y0")),
    (4, 5, ("X0 Y0 Y1", "X0 Y1 X1"), ("X0 Y0 X1", "X1 Y0 Y1")),
    (5, 2, ("X0 Y0 X1", "X1 Y0 Y1"), ("X0 Y0 Y1", "X0 Y1 X1")),
    (3, 1, ("X0 X1 Y0", "X1 Y1 Y0"), ("X0 Y1 Y0", "X0 X1 Y1")),
    (6, 7, ("X0 Y1 Y0", "X0 X1 Y1"), ("X0 X1 Y0", "X1 Y1 Y0")),
    (7, 3, ("X0 X1 Y0", "X1 Y1 Y0"), ("X0 Y1 Y0", "X0 X1 Y1")),
)


def teeth_vertices(v_template, upper_ring, lower_ring) -> np.ndarray:
    """(8 n, 3) teeth vertices (module docstring), rows in `ROWS` order, float64."""
    v = np.asarray(v_template, np.float64)
    upper, lower = np.asarray(upper_ring), np.asarray(lower_ring)
    d = float(np.mean(np.linalg.norm(v[upper] - v[lower], axis=1)))
    mid = 0.5 * (v[upper] + v[lower])
    mid[:, 1] = mid[:, 1].mean()
    mid[:, 2] -= 1.5 * d
    up, back = np.array([0.0, d, 0.0]), np.array([0.0, 0.0, -d])
    upper_edge = mid + 0.1 * up
    upper_root = upper_edge + 2 * up
    lower_edge = mid - 0.1 * up + 0.4 * back
    lower_root = lower_edge - 2 * up
    rows = (upper_root, lower_root, upper_edge, lower_edge, upper_root + back,
            upper_edge + back, lower_root + back, lower_edge + back)
    return np.concatenate(rows)


def teeth_faces(first_vertex: int, n: int) -> np.ndarray:
    """(6 * 2 (n - 1), 3) int64 faces over the teeth vertices starting at `first_vertex`."""
    faces = []
    for x, y, left, right in STRIPS:
        for c in range(n - 1):
            corner = {"X0": (x, c), "X1": (x, c + 1), "Y0": (y, c), "Y1": (y, c + 1)}
            for triangle in (left if c < (n - 1) // 2 else right):
                faces.append([first_vertex + corner[k][0] * n + corner[k][1]
                              for k in triangle.split()])
    return np.asarray(faces, np.int64)


def with_teeth(model: FlameModel, upper_ring=FLAME_UPPER_LIP,
               lower_ring=FLAME_LOWER_LIP) -> FlameModel:
    """`model` with GaussianAvatars' teeth appended: 8 n vertices after the model's V and
    12 (n - 1) faces after its F (n = 15 ring vertices: 120 and 168). Rows before them are
    unchanged."""
    upper, lower = np.asarray(upper_ring), np.asarray(lower_ring)
    if upper.shape != lower.shape or upper.ndim != 1 or len(upper) < 2:
        raise ValueError("upper_ring and lower_ring must be 1-D index arrays of equal length >= 2")
    if max(upper.max(), lower.max()) >= model.num_vertices:
        raise ValueError(f"the lip rings name vertices up to {max(upper.max(), lower.max())}, "
                         f"the model has {model.num_vertices}")
    n, base = len(upper), model.num_vertices

    def extend(x, new):
        return jnp.concatenate([x, jnp.asarray(new, x.dtype)], axis=0)

    ring_dirs = 0.5 * (model.shapedirs[upper] + model.shapedirs[lower])  # (n, 3, S)
    weights = np.zeros((8, n, len(model.parents)))
    weights[list(UPPER_ROWS), :, NECK_JOINT] = 1.0
    weights[[r for r in range(8) if r not in UPPER_ROWS], :, JAW_JOINT] = 1.0
    return FlameModel(
        v_template=extend(model.v_template, teeth_vertices(model.v_template, upper, lower)),
        shapedirs=extend(model.shapedirs, jnp.tile(ring_dirs, (8, 1, 1))),
        exprdirs=extend(model.exprdirs, np.zeros((8 * n,) + model.exprdirs.shape[1:])),
        posedirs=extend(model.posedirs, np.zeros((8 * n,) + model.posedirs.shape[1:])),
        j_regressor=jnp.concatenate(
            [model.j_regressor, jnp.zeros((model.j_regressor.shape[0], 8 * n),
                                          model.j_regressor.dtype)], axis=1),
        lbs_weights=extend(model.lbs_weights, weights.reshape(8 * n, -1)),
        faces=extend(model.faces, teeth_faces(base, n)),
        parents=model.parents)


def teeth_regions(face_regions, teeth_id: int, num_teeth_faces: int = 168) -> np.ndarray:
    """(F + 168,) face regions with the teeth faces labelled `teeth_id`."""
    return np.concatenate([np.asarray(face_regions, np.int32),
                           np.full(num_teeth_faces, teeth_id, np.int32)])
