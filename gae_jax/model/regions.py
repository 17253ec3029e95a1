"""The region vocabulary every head shares, the assets a built-in head comes with, and region
outlines on a mesh.

A face's region is an index into `REGIONS`; FLAME files get theirs from `FLAME_masks.pkl`
(`flame_io.face_regions_from_masks`), the built-in heads from their builders. "tongue" is the
MakeHuman head's; the procedural head has none.
"""

from __future__ import annotations

import dataclasses

import numpy as np

REGIONS = ("skin", "hair", "brows", "lips", "mouth", "teeth", "sclera", "iris", "pupil", "tongue")
REGION_ID = {name: i for i, name in enumerate(REGIONS)}


@dataclasses.dataclass(frozen=True)
class HeadAssets:
    """Per-face region labels (F,) int32 (index into `REGIONS`), per-vertex albedo (V, 3), and
    the names of the model's expression and identity directions (in column order)."""

    face_regions: np.ndarray
    vertex_colors: np.ndarray
    expr_names: tuple
    shape_names: tuple
    region_names: tuple = REGIONS


def region_faces(face_regions, name: str) -> np.ndarray:
    """(F,) bool: the faces of region `name`."""
    return np.asarray(face_regions) == REGION_ID[name]


def rim_faces(faces, face_regions, name: str) -> np.ndarray:
    """(F,) bool: faces of region `name` with an edge no other face of the region shares (the
    region's outline; a region that is a mesh piece of its own shares no vertex with others)."""
    faces = np.asarray(faces)
    inside = np.flatnonzero(region_faces(face_regions, name))
    edges = np.sort(np.stack([faces[inside][:, [0, 1]], faces[inside][:, [1, 2]],
                              faces[inside][:, [2, 0]]], axis=1), axis=-1)  # (n, 3, 2)
    _, index, counts = np.unique(edges.reshape(-1, 2), axis=0, return_inverse=True,
                                 return_counts=True)
    open_edge = (counts[index.reshape(-1)] == 1).reshape(-1, 3)
    rim = np.zeros(faces.shape[0], bool)
    rim[inside[open_edge.any(axis=1)]] = True
    return rim
