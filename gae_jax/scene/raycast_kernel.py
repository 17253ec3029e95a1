"""The C++ ray caster (`kernel/raycast_cpu.cc`): first hits of rays that leave one point.

`pip install` compiles it into `gae_jax/scene/_raycast_cpu*.so` (see `setup.py`) and it is called
through ctypes, which releases the GIL, so views cast on threads run in parallel. It bins a
camera's rays by where they cross its image plane and intersects each triangle only with the rays
under its projected bounding box, exactly, in float64: the hits embree finds (in float32), with
float64 distances and barycentrics, and the hit faces' corner values mixed there when asked.
When it is not built, or the rays do not share an origin or spread wider than about 87 degrees
from their summed direction, `first_hits` returns None and the caller casts with embree.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
from typing import NamedTuple, Optional

import numpy as np

MODULE = "gae_jax.scene._raycast_cpu"

_DOUBLES = np.ctypeslib.ndpointer(np.float64, flags="C_CONTIGUOUS")
_INT64S = np.ctypeslib.ndpointer(np.int64, flags="C_CONTIGUOUS")


class Hits(NamedTuple):
    """First hits of N rays: face (N,) int64 (-1 = miss), distance (N,) float64 along the
    directions (inf = miss), u, v (N,) float64 barycentrics (the hit is (1 - u - v) a + u b + v c
    of the face's corners), values (N, K) float64: the corner values mixed at the hit (0 at a
    miss), when asked for, else None."""

    face: np.ndarray
    distance: np.ndarray
    u: np.ndarray
    v: np.ndarray
    values: Optional[np.ndarray] = None


@functools.cache
def _open() -> tuple:
    """Loads the kernel once per process: (its function, None), else (None, why not)."""
    spec = importlib.util.find_spec(MODULE)
    if spec is None or not spec.origin:
        return None, "not built (reinstall with `pip install -e .` and a C++17 compiler)"
    try:
        function = ctypes.CDLL(spec.origin).GaeFirstHitsFromPoint
    except (OSError, AttributeError) as error:
        return None, f"{spec.origin} did not load: {error}"
    function.restype = ctypes.c_int
    function.argtypes = [_DOUBLES, ctypes.c_int64, _INT64S, ctypes.c_int64, _DOUBLES, _DOUBLES,
                         ctypes.c_int64, _INT64S, _DOUBLES, _DOUBLES, _DOUBLES, ctypes.c_void_p,
                         ctypes.c_int64, ctypes.c_void_p]
    return function, None


def available() -> bool:
    """Whether the C++ ray caster is built and loads."""
    return _open()[0] is not None


def why_unavailable() -> str | None:
    """None when the kernel loads, else why not."""
    return _open()[1]


def first_hits(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray,
               dirs: np.ndarray, corner_values: np.ndarray | None = None) -> Hits | None:
    """First hit of each ray on the mesh, or None when the kernel cannot cast these rays (not
    built, origins not all one point, directions spread wider than about 87 degrees from their
    summed direction).

    Args:
      vertices: (V, 3); faces: (F, 3) int indices into vertices; origins, dirs: (N, 3);
      corner_values: (F, 3, K) values at each face's corners to mix at the hits by the
        barycentrics clipped to [0, 1] and renormalised, or None.
    """
    origins = np.ascontiguousarray(origins, np.float64)
    dirs = np.ascontiguousarray(dirs, np.float64)
    vertices = np.ascontiguousarray(vertices, np.float64)
    faces = np.ascontiguousarray(faces, np.int64)
    for name, array in (("vertices", vertices), ("faces", faces), ("origins", origins)):
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"{name} must be (n, 3), got {array.shape}")
    if dirs.shape != origins.shape:
        raise ValueError(f"dirs must be {origins.shape} like origins, got {dirs.shape}")
    if corner_values is not None:
        corner_values = np.ascontiguousarray(corner_values, np.float64)
        if corner_values.ndim != 3 or corner_values.shape[:2] != (len(faces), 3):
            raise ValueError(f"corner_values must be ({len(faces)}, 3, K), got "
                             f"{corner_values.shape}")
    function = _open()[0]
    if function is None:
        return None
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"faces index {len(vertices)} vertices out of range "
                         f"({faces.min()}..{faces.max()})")
    count = len(dirs)
    face, t = np.empty(count, np.int64), np.empty(count)
    u, v = np.empty(count), np.empty(count)
    num_values = 0 if corner_values is None else corner_values.shape[2]
    values = None if corner_values is None else np.empty((count, num_values))
    status = function(vertices, len(vertices), faces, len(faces), origins, dirs, count, face, t,
                      u, v, None if values is None else corner_values.ctypes.data, num_values,
                      None if values is None else values.ctypes.data)
    if status != 0:
        return None
    return Hits(face, t, u, v, values)
