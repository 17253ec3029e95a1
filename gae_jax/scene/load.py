"""Where a scene comes from: the embedded synthetic default, or a user's NeRSemble folder.

`load_scene(SceneConfig(data, flame_model, flame_masks, size))` is what every entry point calls:
with no `data` it builds (or reads from the cache) the embedded scene at `size` pixels; with a
folder it reads it (`nersemble.load_scene`), posed by the FLAME file `flame_model` (a FLAME
`.pkl` or our `.npz`) or, without one, by the embedded head. Region labels of a FLAME file's
faces come from `flame_masks` (FLAME_masks.pkl) when given, else every face is skin.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from gae_jax.model import flame, flame_io, head
from gae_jax.model.teeth import teeth_regions, with_teeth
from gae_jax.scene import nersemble, synthetic
from gae_jax.scene.types import Scene


def load_model(flame_model: str = "", flame_masks: str = "", data: str = "", dims=None,
               head_kind: str = "procedural", teeth: bool = True):
    """(FlameModel, (F,) face regions): the embedded head `head_kind`, or a FLAME file with as
    many shape / expression components as `dims` = (S, E) says or, without it, as the data's
    flame_param files hold (300 / 100 without either). A FLAME-sized file (5023 vertices) gets
    GaussianAvatars' teeth unless `teeth` is False (`model.teeth`: their faces are labelled
    teeth), as GaussianAvatars always builds it: its avatars bind Gaussians to them."""
    if not flame_model:
        if flame_masks:
            raise ValueError("--flame-masks needs --flame-model (the embedded head has its "
                             "own regions)")
        model, assets = head.make_head(head_kind)
        return model, assets.face_regions
    n_shape, n_expr = 300, 100
    if dims is not None:
        n_shape, n_expr = dims
    elif data:
        first = nersemble.first_flame_param(data)
        n_shape, n_expr = first["shape"].size, first["expr"].shape[-1]
    model = flame_io.load_flame(flame_model, n_shape=n_shape, n_expr=n_expr)
    if flame_masks:
        masks = flame_io.load_flame_masks(flame_masks)
        regions = flame_io.face_regions_from_masks(model.faces, masks, model.num_vertices)
    else:
        regions = np.full(model.faces.shape[0], head.REGION_ID["skin"], np.int32)
    if teeth and model.num_vertices == flame.FLAME_VERTICES:
        model = with_teeth(model)
        regions = teeth_regions(regions, head.REGION_ID["teeth"])
    return model, regions


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Where the scene comes from (flags of every entry point that loads one)."""

    data: str = ""
    flame_model: str = ""
    flame_masks: str = ""
    flame_teeth: bool = True
    size: int = 128
    head: str = head.DEFAULT_KIND

    def __post_init__(self):
        if self.size < 8:
            raise ValueError(f"size must be >= 8, got {self.size}")
        if self.head not in head.HEAD_KINDS:
            raise ValueError(f"unknown head {self.head!r}; --head takes "
                             f"{' or '.join(head.HEAD_KINDS)}")


SCENE_HELP = dict(
    data="a NeRSemble / GaussianAvatars folder (transforms_*.json, images, flame_param); "
         "empty: the embedded synthetic scene",
    flame_model="FLAME model file (.pkl or gae_jax .npz) posing --data; empty: the embedded head",
    flame_masks="FLAME_masks.pkl naming the FLAME model's regions (lips, eyeballs, scalp)",
    flame_teeth="append GaussianAvatars' teeth to a FLAME-sized --flame-model, as "
                "GaussianAvatars does (its avatars bind Gaussians to them); false: plain FLAME",
    size="image size of the embedded scene (pixels; --data keeps its own; a new size builds and "
         "caches a new scene, about a minute at 128 px, and reconstructs its avatar)",
    head="the embedded head: makehuman (the MakeHuman base head with the 52 ARKit face units) "
         "or procedural (a few primitives, fast); it also poses --data without --flame-model")


def load_scene(source: SceneConfig = SceneConfig(), progress: bool = False) -> Scene:
    """The scene a `SceneConfig` names."""
    data, flame_model, flame_masks = source.data, source.flame_model, source.flame_masks
    if not data:
        if flame_model or flame_masks:
            raise ValueError("--flame-model and --flame-masks need --data (the embedded scene "
                             "is posed by the embedded head)")
        return synthetic.make_synthetic_scene(size=source.size, progress=progress,
                                              head_kind=source.head)
    model, regions = load_model(flame_model, flame_masks, data, head_kind=source.head,
                                teeth=source.flame_teeth)
    return nersemble.load_scene(data, model, regions)
