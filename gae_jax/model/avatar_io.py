"""GaussianAvatars files: `point_cloud.ply` (triangle-local Gaussians with their binding) and
`flame_param.npz` (stacked per-frame FLAME parameters), plus a world-space 3DGS `.ply` of the
avatar posed at one frame, which common splat viewers open directly.

point_cloud.ply properties (all float32): x y z (local mean), nx ny nz (zeros), f_dc_0..2,
f_rest_* (channel-major: index = channel * (K - 1) + coefficient), opacity (logit), scale_0..2
(local log-scale), rot_0..3 (local wxyz), binding_0 (face index). Written with SH degree 3 (45
f_rest_*) by default, what GaussianAvatars and 3DGS load with their defaults (they assert the
count): a degree-0 fit is a degree-3 model with zero higher bands. Read at any degree.

flame_param.npz holds the nine keys GaussianAvatars' loader reads, float32: shape (S,), expr
(T, E), rotation, neck_pose, jaw_pose, translation (T, 3), eyes_pose (T, 6), static_offset
(1, V, 3) and dynamic_offset (T, V, 3) (zeros: GaussianAvatars ignores it); keys of an input
file this project does not use are carried through an edit (`extra`).
"""

from __future__ import annotations


import jax.numpy as jnp
import numpy as np

from gae_jax.render import sh
from gae_jax.model.avatar import Avatar
from gae_jax.model.flame import FlameParams
from gae_jax.util.fileio import PlyError, read_ply, require, write_npz, write_ply
from gae_jax.render.splat import Gaussians

FLAME_PARAM_KEYS = ("rotation", "neck_pose", "jaw_pose", "eyes_pose", "translation", "expr")
OFFSET_KEYS = ("static_offset", "dynamic_offset")
FILE_SH_DEGREE = 3  # what GaussianAvatars (--sh_degree) and 3DGS load by default


def _sh_properties(colors: np.ndarray) -> dict:
    """(N, K, 3) SH coefficients -> f_dc_* and channel-major f_rest_* properties."""
    props = {f"f_dc_{c}": colors[:, 0, c] for c in range(3)}
    rest = np.transpose(colors[:, 1:, :], (0, 2, 1)).reshape(colors.shape[0], -1)
    props.update({f"f_rest_{i}": rest[:, i] for i in range(rest.shape[1])})
    return props


def _sh_from_properties(props: dict, path: str) -> np.ndarray:
    dc = require(props, [f"f_dc_{c}" for c in range(3)], path)
    num_rest = sum(1 for k in props if k.startswith("f_rest_"))
    if num_rest % 3:
        raise PlyError(f"{path}: {num_rest} f_rest properties is not a multiple of 3")
    k = 1 + num_rest // 3
    sh.degree_of(k)
    if num_rest == 0:
        return dc[:, None, :]
    rest = require(props, [f"f_rest_{i}" for i in range(num_rest)], path)
    rest = np.transpose(rest.reshape(-1, 3, k - 1), (0, 2, 1))
    return np.concatenate([dc[:, None, :], rest], axis=1)


def _as_sh(colors, degree: int | None) -> np.ndarray:
    """(N, K, 3) SH coefficients of plain (N, 3) colours (as DC) or SH colours, zero-padded (or
    cut) to `degree`'s (degree + 1)^2 coefficients; None keeps them as they are."""
    colors = np.asarray(colors, np.float32)
    coefs = colors if colors.ndim == 3 else np.asarray(sh.rgb_to_dc(colors))[:, None, :]
    if degree is None:
        return coefs
    k = (degree + 1) ** 2
    if coefs.shape[1] >= k:
        return coefs[:, :k]
    return np.concatenate([coefs, np.zeros((len(coefs), k - coefs.shape[1], 3), np.float32)],
                          axis=1)


def save_avatar_ply(avatar: Avatar, path: str, sh_degree: int | None = FILE_SH_DEGREE) -> None:
    """Writes an avatar as GaussianAvatars' point_cloud.ply, its colours as SH coefficients of
    `sh_degree` (plain colours as the DC term, higher bands zero; None: as they are)."""
    n = avatar.num
    props = {k: v for k, v in zip("xyz", np.asarray(avatar.means).T)}
    props.update({f"n{k}": np.zeros(n) for k in "xyz"})
    props.update(_sh_properties(_as_sh(avatar.colors, sh_degree)))
    props["opacity"] = np.asarray(avatar.opacity_logits)
    props.update({f"scale_{i}": np.asarray(avatar.log_scales)[:, i] for i in range(3)})
    props.update({f"rot_{i}": np.asarray(avatar.quats)[:, i] for i in range(4)})
    props["binding_0"] = np.asarray(avatar.binding, np.float32)
    write_ply(path, props)


def load_avatar_ply(path: str, face_regions=None) -> Avatar:
    """Reads point_cloud.ply; regions come from `face_regions` (F,) when given, else 0."""
    props = read_ply(path)
    binding = require(props, ["binding_0"], path)[:, 0].astype(np.int32)
    regions = (np.zeros_like(binding) if face_regions is None
               else np.asarray(face_regions, np.int32)[binding])
    return Avatar(
        binding=jnp.asarray(binding), means=jnp.asarray(require(props, list("xyz"), path)),
        quats=jnp.asarray(require(props, [f"rot_{i}" for i in range(4)], path)),
        log_scales=jnp.asarray(require(props, [f"scale_{i}" for i in range(3)], path)),
        opacity_logits=jnp.asarray(require(props, ["opacity"], path)[:, 0]),
        colors=jnp.asarray(_sh_from_properties(props, path)), regions=jnp.asarray(regions))


def save_posed_ply(gaussians: Gaussians, path: str,
                   sh_degree: int | None = FILE_SH_DEGREE) -> None:
    """World-space 3DGS .ply (log-scales, opacity logits, unit wxyz, SH of `sh_degree`) that
    splat viewers and 3DGS's `load_ply` open with their defaults."""
    g = gaussians
    opac = np.clip(np.asarray(g.opacities, np.float64), 1e-6, 1 - 1e-6)
    quats = np.asarray(g.quats, np.float64)
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    props = {k: v for k, v in zip("xyz", np.asarray(g.means).T)}
    props.update({f"n{k}": np.zeros(g.num) for k in "xyz"})
    props.update(_sh_properties(_as_sh(g.colors, sh_degree)))
    props["opacity"] = np.log(opac / (1 - opac))
    props.update({f"scale_{i}": np.log(np.asarray(g.scales))[:, i] for i in range(3)})
    props.update({f"rot_{i}": quats[:, i] for i in range(4)})
    write_ply(path, props)


def save_flame_params(path: str, shape, frames: FlameParams, static_offset=None,
                      num_vertices: int | None = None, extra: dict | None = None) -> None:
    """Stacked per-frame parameters (T, ...) as GaussianAvatars' flame_param.npz: its nine keys
    in its order, float32, `shape` one-dimensional, `static_offset` (V, 3) of the identity
    (zeros of `num_vertices` rows when None), `dynamic_offset` zeros; `extra` keys (an input
    file's own) after them."""
    t = int(np.asarray(frames.expr).shape[0])
    if static_offset is None:
        if num_vertices is None:
            raise ValueError("save_flame_params needs static_offset or num_vertices")
        static_offset = np.zeros((num_vertices, 3), np.float32)
    offset = np.asarray(static_offset, np.float32).reshape(1, -1, 3)
    arrays = dict(shape=np.asarray(shape).reshape(-1), expr=np.asarray(frames.expr),
                  rotation=np.asarray(frames.rotation), neck_pose=np.asarray(frames.neck),
                  jaw_pose=np.asarray(frames.jaw), eyes_pose=np.asarray(frames.eyes),
                  translation=np.asarray(frames.translation), static_offset=offset,
                  dynamic_offset=np.zeros((t,) + offset.shape[1:], np.float32))
    arrays = {k: np.asarray(v, np.float32) for k, v in arrays.items()}
    arrays.update({k: v for k, v in (extra or {}).items() if k not in arrays})
    write_npz(path, arrays)


def extra_flame_params(path: str) -> dict:
    """The arrays of a flame_param.npz under keys GaussianAvatars' nine are not (carried through
    an edit as they were)."""
    known = set(("shape",) + FLAME_PARAM_KEYS + OFFSET_KEYS)
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: np.asarray(f[k]) for k in f.files if k not in known}
    except Exception as exc:  # truncated zip, bad CRC, unparsable member
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: {exc})") from None


def load_flame_params(path: str):
    """Reads flame_param.npz -> (shape (S,), FlameParams with a leading frame axis)."""
    try:
        with np.load(path, allow_pickle=False) as f:
            arr = {k: np.asarray(f[k], np.float32) for k in f.files}
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except Exception as exc:  # truncated zip, bad CRC, unparsable member
        raise ValueError(f"{path}: not a readable .npz ({type(exc).__name__}: {exc})") from None
    missing = [k for k in ("shape",) + FLAME_PARAM_KEYS if k not in arr]
    if missing:
        raise ValueError(f"{path}: missing keys {missing}")
    if arr["expr"].ndim != 2:
        raise ValueError(f"{path}: 'expr' must have shape (T, E), got {arr['expr'].shape}")
    t = arr["expr"].shape[0]
    for key, width in (("rotation", 3), ("neck_pose", 3), ("jaw_pose", 3), ("eyes_pose", 6),
                       ("translation", 3)):
        if arr[key].shape != (t, width):
            raise ValueError(f"{path}: '{key}' must have shape ({t}, {width}), got "
                             f"{arr[key].shape}")
    for key, value in arr.items():
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{path}: '{key}' contains NaN or infinite values")
    offset = arr.get("static_offset")
    if offset is not None and (offset.ndim not in (2, 3) or offset.shape[-1] != 3):
        raise ValueError(f"{path}: 'static_offset' must have shape (1, V, 3), got {offset.shape}")
    if offset is not None:
        offset = offset.reshape(1, -1, 3)  # GaussianAvatars writes (V, 3) without the offset
    frames = FlameParams(
        shape=jnp.broadcast_to(jnp.asarray(arr["shape"].reshape(-1)), (t, arr["shape"].size)),
        expr=jnp.asarray(arr["expr"]), rotation=jnp.asarray(arr["rotation"]),
        neck=jnp.asarray(arr["neck_pose"]), jaw=jnp.asarray(arr["jaw_pose"]),
        eyes=jnp.asarray(arr["eyes_pose"]), translation=jnp.asarray(arr["translation"]),
        static_offset=None if offset is None else jnp.broadcast_to(
            jnp.asarray(offset[0]), (t,) + offset.shape[1:]))
    return arr["shape"].reshape(-1), frames


def save_avatar_folder(folder: str, avatar: Avatar, shape, frames: FlameParams,
                       static_offset=None, num_vertices: int | None = None,
                       extra: dict | None = None) -> None:
    """A GaussianAvatars avatar folder: `point_cloud.ply` and `flame_param.npz` (the motion
    `frames`, stacked (T, ...), with identity `shape` and `static_offset`; see
    `save_flame_params`)."""
    import os

    os.makedirs(folder, exist_ok=True)
    save_avatar_ply(avatar, os.path.join(folder, "point_cloud.ply"))
    save_flame_params(os.path.join(folder, "flame_param.npz"), shape, frames, static_offset,
                      num_vertices, extra)


def load_bound_avatar(path: str, face_regions) -> Avatar:
    """A `point_cloud.ply` bound to a mesh with (F,) `face_regions`, ready to edit: SH whose
    higher bands are all zero (a degree-0 fit, written with the degree-3 layout) becomes plain
    RGB (an Adam step on the DC coefficient would move RGB by only C0 = 0.28 of it). PlyError
    when a binding names a face the mesh does not have."""
    face_regions = np.asarray(face_regions)
    binding = require(read_ply(path), ["binding_0"], path)[:, 0]
    if binding.size and (binding.min() < 0 or binding.max() >= len(face_regions)):
        raise PlyError(f"{path}: binding_0 names faces up to {int(binding.max())}, the mesh has "
                       f"{len(face_regions)} (an avatar of another FLAME model?)")
    loaded = load_avatar_ply(path, face_regions)
    if not np.any(np.asarray(loaded.colors)[:, 1:]):
        loaded = Avatar(binding=loaded.binding, means=loaded.means, quats=loaded.quats,
                        log_scales=loaded.log_scales, opacity_logits=loaded.opacity_logits,
                        colors=sh.dc_to_rgb(loaded.colors[:, 0]), regions=loaded.regions)
    return loaded
