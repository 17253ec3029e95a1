"""What the viewer shows, read from disk: a run folder of `python -m gae_jax.train`, or any
GaussianAvatars avatar folder bound to the embedded head or a FLAME file.

A run folder gives the edited and the original avatar, the model (named by `metrics.json`'s
scene settings), the blend the edit trained with, the rig's cameras (`evaluation_set.npz`) and
the scene's motions (`motion.npz`; older runs: the avatars' own `flame_param.npz`). An avatar
folder gives one avatar and its `flame_param.npz`; the cameras are the embedded rig's.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from gae_jax.model import avatar_io, flame, head
from gae_jax.model.flame import FlameModel
from gae_jax.render import wabe
from gae_jax.run import folder as run_folder
from gae_jax.scene import motion_io, synthetic
from gae_jax.scene.load import load_model
from gae_jax.scene.types import Sequence

RIG_CAMERAS = 16
RIG_SIZE = 256
AVATAR_MOTION = "avatar motion"  # the sequence name of an avatar folder's flame_param.npz


@dataclasses.dataclass(frozen=True)
class Viewable:
    """Host data of one viewer session.

    Attributes:
      title: what the page's header says (folder, prompt).
      model: the FLAME model (or built-in head) that poses the mesh; expr_names: (E,) labels.
      avatars: label -> Avatar, the edited one first ("edited", "original"; or "avatar").
      shapes: identity -> (S,) shape coefficients ("A": the avatar's own); static_offsets:
        identity -> (V, 3) static offset (GaussianAvatars' flame_param), where one exists.
      sequences: name -> `types.Sequence` the player offers.
      intrinsics: (C, 4); w2c: (C, 4, 4); width, height: the camera presets' image size.
      background: (3,) colour; blend: the blending the avatar was trained with.
    """

    title: str
    model: FlameModel
    expr_names: tuple
    avatars: dict
    shapes: dict
    sequences: dict
    intrinsics: np.ndarray
    w2c: np.ndarray
    width: int
    height: int
    background: np.ndarray
    blend: wabe.Blend
    static_offsets: dict = dataclasses.field(default_factory=dict)


def _motion_of(shape, frames, folder: str, model: FlameModel) -> tuple[np.ndarray, Sequence]:
    """(shape, Sequence) of an avatar folder's flame_param.npz (read as `shape`, `frames`),
    checked against the model."""
    if shape.size != model.num_shape or frames.expr.shape[-1] != model.num_expr:
        raise ValueError(f"{folder}/flame_param.npz: {shape.size} shape and "
                         f"{frames.expr.shape[-1]} expression components, the model has "
                         f"{model.num_shape} and {model.num_expr} (an avatar of another model?)")
    seq = Sequence(name=AVATAR_MOTION, identity="A", split="train",
                   expr=np.asarray(frames.expr), rotation=np.asarray(frames.rotation),
                   neck=np.asarray(frames.neck), jaw=np.asarray(frames.jaw),
                   eyes=np.asarray(frames.eyes), translation=np.asarray(frames.translation))
    return shape, seq


def _static_offset(frames, model: FlameModel):
    """The (V, 3) static offset of an avatar folder's flame_param.npz (`frames`), or None."""
    if frames.static_offset is None:
        return None
    return flame.fit_static_offset(np.asarray(frames.static_offset)[0], model.num_vertices)


def _expr_names(model: FlameModel, assets) -> tuple:
    if assets is not None and len(assets.expr_names) == model.num_expr:
        return tuple(assets.expr_names)
    return tuple(f"expression {i}" for i in range(model.num_expr))


def _model_for(folder: str, head_kind: str, flame_model: str, flame_masks: str,
               teeth: bool = True):
    """(model, face regions, built-in head assets or None, shape, frames): the model an avatar
    folder is bound to, a FLAME file cut to as many components as its flame_param.npz holds
    (with GaussianAvatars' teeth unless `teeth` is False)."""
    shape, frames = avatar_io.load_flame_params(os.path.join(folder, "flame_param.npz"))
    if not flame_model:
        if flame_masks:
            raise ValueError("--flame-masks needs --flame-model (the embedded head has its "
                             "own regions)")
        model, assets = head.make_head(head_kind)
        return model, assets.face_regions, assets, shape, frames
    model, regions = load_model(flame_model, flame_masks,
                                dims=(shape.size, int(frames.expr.shape[-1])), teeth=teeth)
    return model, regions, None, shape, frames


def from_run(run_dir: str) -> Viewable:
    """The edited and original avatars of a run folder; FileNotFoundError / ValueError naming
    what is missing or unreadable."""
    run = run_folder.read(run_dir)
    edited_dir = run.avatar_folder("edited")
    model, regions, assets, shape, frames = _model_for(
        edited_dir, run.scene.head, run.scene.flame_model, run.scene.flame_masks,
        run.scene.flame_teeth)
    loaded = run.avatars(regions)
    avatars = {"edited": loaded["edited"], "original": loaded["original"]}
    offset = _static_offset(frames, model)
    shape, own = _motion_of(shape, frames, edited_dir, model)
    motion_path = run.motion_file()
    if motion_path is not None:
        sequences, shapes, offsets = motion_io.load(motion_path, model.num_expr,
                                                    model.num_shape)
    else:
        sequences, shapes = {AVATAR_MOTION: own}, {"A": shape}
        offsets = {} if offset is None else {"A": offset}
    evalset = run.evaluation_set()
    return Viewable(
        title=f'{os.path.basename(os.path.normpath(run_dir))}: "{run.config.prompt}"',
        model=model, expr_names=_expr_names(model, assets), avatars=avatars, shapes=shapes,
        sequences=sequences, intrinsics=evalset.intrinsics, w2c=evalset.w2c,
        width=evalset.width, height=evalset.height, background=evalset.background,
        blend=run.blend, static_offsets=offsets)


def from_avatar(folder: str, head_kind: str = "procedural", flame_model: str = "",
                flame_masks: str = "", blend: str = "standard") -> Viewable:
    """A GaussianAvatars folder (point_cloud.ply + flame_param.npz) bound to the built-in head
    `head_kind` or to `flame_model`; the cameras are the embedded scene's rig, the motions the
    folder's own plus, for a built-in head, the embedded scene's library."""
    if not os.path.isdir(folder):
        raise NotADirectoryError(f"{folder}: no such folder")
    ply = run_folder.avatar_file(folder)
    model, regions, assets, shape, frames = _model_for(folder, head_kind, flame_model,
                                                       flame_masks)
    offset = _static_offset(frames, model)
    shape, own = _motion_of(shape, frames, folder, model)
    sequences, shapes = {AVATAR_MOTION: own}, {"A": shape}
    if assets is not None:
        frames = synthetic.make_sequences(16, model.num_expr, head_kind, assets.expr_names)
        sequences.update({n: s for n, s in frames.items() if s.identity == "A"})
    intrinsics, w2c = synthetic.camera_rig(
        RIG_CAMERAS, RIG_SIZE, distance=synthetic.CAMERA_DISTANCE.get(head_kind, 0.6))
    return Viewable(
        title=os.path.basename(os.path.normpath(folder)), model=model,
        expr_names=_expr_names(model, assets),
        avatars={"avatar": avatar_io.load_bound_avatar(ply, regions)}, shapes=shapes,
        sequences=sequences, intrinsics=intrinsics, w2c=w2c, width=RIG_SIZE, height=RIG_SIZE,
        background=np.ones(3), blend=wabe.named(blend),
        static_offsets={} if offset is None else {"A": offset})
