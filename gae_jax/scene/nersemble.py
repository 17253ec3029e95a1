"""The GaussianAvatars / NeRSemble dataset layout (as written by VHAP), read and written.

    <subject>/transforms_{train,val,test}.json   camera-to-world in OpenGL axes, intrinsics
    <subject>/images/{ti:05d}_{ci:02d}.png        (white background)
    <subject>/fg_masks/{ti:05d}_{ci:02d}.png
    <subject>/flame_param/{ti:05d}.npz            translation, rotation, neck_pose, jaw_pose (1,3);
                                                  eyes_pose (1,6); shape (S,); expr (1,E);
                                                  static_offset (1,V,3) (VHAP's default)
    <subject>/canonical_flame_param.npz           zero pose, jaw_pose [[0.3, 0, 0]], shape

OpenGL axes are converted to ours (OpenCV) by flipping the Y and Z columns of camera-to-world.
VHAP writes the principal point of that OpenGL camera, `cy` measured from the image's bottom
edge: ours is h - cy (GaussianAvatars ignores cx, cy and centres it; we honour both). As in
GaussianAvatars, the identity's shape and static offset are those of the first timestep's file
and serve every frame. A multi-sequence ("UNION") folder's frames point into sibling sequence
folders (`../SEQ/flame_param/...`): every path is taken relative to the folder read.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from gae_jax.model.flame import fit_static_offset
from gae_jax.scene.types import Scene, Sequence
from gae_jax.util.fileio import atomic_write_bytes, encode_png, npz_bytes

OPENGL_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
FRAME_FIELDS = ("timestep_index", "camera_index", "cx", "cy", "fl_x", "fl_y", "h", "w",
                "transform_matrix", "file_path", "flame_param_path")
FLAME_KEYS = {"translation": 3, "rotation": 3, "neck_pose": 3, "jaw_pose": 3, "eyes_pose": 6}
CANONICAL_JAW = 0.3


@dataclasses.dataclass(frozen=True)
class Frame:
    """One (timestep, camera) record of a split, resolved to absolute paths."""

    timestep: int
    camera: int
    intrinsics: np.ndarray  # (4,) fx, fy, cx, cy
    w2c: np.ndarray  # (4, 4) OpenCV axes
    width: int
    height: int
    image_path: str
    mask_path: str | None
    flame_param_path: str


def _write_json(path, obj):
    atomic_write_bytes(path, json.dumps(obj, indent=1).encode())


def _npz_bytes(**arrays) -> bytes:
    """An uncompressed .npz of float32 arrays (VHAP writes float32)."""
    return npz_bytes({k: np.asarray(v, np.float32) for k, v in arrays.items()})


def export_scene(scene, folder: str) -> dict:
    """Writes a `data.Scene`'s identity-A data in the NeRSemble layout.

    Splits as in GaussianAvatars: train = training sequences x training cameras, val = training
    sequences x held-out cameras (novel view), test = the held-out sequence x training cameras
    (self-reenactment). Returns {split: number of frames}.
    """
    names = [n for n, s in scene.sequences.items() if s.identity == "A"]
    os.makedirs(folder, exist_ok=True)
    timesteps = []  # (sequence name, frame) per global timestep index
    for name in names:
        timesteps += [(name, t) for t in range(scene.sequences[name].num_frames)]
    shape = np.asarray(scene.shapes["A"], np.float32)
    offset = scene.static_offsets.get("A")
    offset = np.zeros((scene.model.num_vertices, 3)) if offset is None else offset
    offset = np.asarray(offset, np.float32)[None]
    os.makedirs(os.path.join(folder, "flame_param"), exist_ok=True)
    for ti, (name, t) in enumerate(timesteps):
        seq = scene.sequences[name]
        atomic_write_bytes(os.path.join(folder, "flame_param", f"{ti:05d}.npz"), _npz_bytes(
            translation=seq.translation[t][None], rotation=seq.rotation[t][None],
            neck_pose=seq.neck[t][None], jaw_pose=seq.jaw[t][None], eyes_pose=seq.eyes[t][None],
            shape=shape, expr=seq.expr[t][None], static_offset=offset))
    z3 = np.zeros((1, 3))
    atomic_write_bytes(os.path.join(folder, "canonical_flame_param.npz"), _npz_bytes(
        translation=z3, rotation=z3, neck_pose=z3, jaw_pose=np.array([[CANONICAL_JAW, 0, 0]]),
        eyes_pose=np.zeros((1, 6)), shape=shape,
        expr=np.zeros((1, scene.sequences[names[0]].expr.shape[1])), static_offset=offset))

    splits = {"train": ([n for n in names if scene.sequences[n].split == "train"],
                        scene.train_cameras),
              "val": ([n for n in names if scene.sequences[n].split == "train"],
                      scene.held_out_cameras),
              "test": ([n for n in names if scene.sequences[n].split == "self_reenactment"],
                       scene.train_cameras)}
    counts = {}
    for split, (seqs, cams) in splits.items():
        frames = []
        for ti, (name, t) in enumerate(timesteps):
            if name not in seqs:
                continue
            for ci in cams:
                fx, fy, cx, cy = (float(v) for v in scene.intrinsics[ci])
                cy = scene.height - cy  # VHAP's cy: from the bottom edge
                c2w = np.linalg.inv(scene.w2c[ci].astype(np.float64)) @ OPENGL_TO_OPENCV
                stem = f"{ti:05d}_{ci:02d}"
                image_rel, mask_rel = f"images/{stem}.png", f"fg_masks/{stem}.png"
                for rel, arr in ((image_rel, scene.images[name][ci, t]),
                                 (mask_rel, (scene.regions[name][ci, t] >= 0).astype(np.uint8)
                                  * 255)):
                    path = os.path.join(folder, rel)
                    if not os.path.exists(path):
                        atomic_write_bytes(path, encode_png(arr))
                frames.append(dict(
                    timestep_index=ti, timestep_index_original=ti, timestep_id=f"{name}_{t:03d}",
                    camera_index=int(ci), camera_id=f"{ci:02d}", cx=cx, cy=cy, fl_x=fx, fl_y=fy,
                    h=scene.height, w=scene.width,
                    camera_angle_x=float(2 * np.arctan(scene.width / (2 * fx))),
                    camera_angle_y=float(2 * np.arctan(scene.height / (2 * fy))),
                    transform_matrix=c2w.tolist(), file_path=image_rel, fg_mask_path=mask_rel,
                    flame_param_path=f"flame_param/{ti:05d}.npz"))
        _write_json(os.path.join(folder, f"transforms_{split}.json"), dict(frames=frames))
        counts[split] = len(frames)
    return counts


def load_split(folder: str, split: str) -> list:
    """Reads transforms_{split}.json into `Frame`s (OpenCV cameras), checking every field."""
    path = os.path.join(folder, f"transforms_{split}.json")
    try:
        with open(path, encoding="utf-8") as f:
            meta = json.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise ValueError(f"{path}: expected an object with a 'frames' list")
    frames = []
    for i, fr in enumerate(meta["frames"]):
        missing = [k for k in FRAME_FIELDS if k not in fr and k not in meta]
        if missing:
            raise ValueError(f"{path}: frame {i} lacks {missing}")

        def get(key, frame=fr):
            return frame.get(key, meta.get(key))  # shared intrinsics may sit at the top level

        c2w = np.asarray(get("transform_matrix"), np.float64)
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise ValueError(f"{path}: frame {i} 'transform_matrix' must be a finite 4x4 matrix")
        intr = np.asarray([get("fl_x"), get("fl_y"), get("cx"), get("h") - get("cy")],
                          np.float64)
        if not np.all(np.isfinite(intr)) or intr[0] <= 0 or intr[1] <= 0:
            raise ValueError(f"{path}: frame {i} has invalid intrinsics {intr.tolist()}")
        mask = get("fg_mask_path") if "fg_mask_path" in fr or "fg_mask_path" in meta else None
        frames.append(Frame(
            timestep=int(get("timestep_index")), camera=int(get("camera_index")),
            intrinsics=intr, w2c=np.linalg.inv(c2w @ OPENGL_TO_OPENCV),
            width=int(get("w")), height=int(get("h")),
            image_path=os.path.join(folder, get("file_path")),
            mask_path=None if mask is None else os.path.join(folder, mask),
            flame_param_path=os.path.join(folder, get("flame_param_path"))))
    return frames


def load_flame_param(path: str) -> dict:
    """Reads one per-timestep flame_param .npz into name -> array, checking keys and shapes."""
    try:
        with np.load(path, allow_pickle=False) as f:
            arr = {k: np.asarray(f[k], np.float32) for k in f.files}
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except Exception as exc:
        raise ValueError(f"{path}: not a readable .npz ({exc})") from exc
    for key, width in FLAME_KEYS.items():
        if key not in arr:
            raise ValueError(f"{path}: missing '{key}'")
        if arr[key].shape != (1, width):
            raise ValueError(f"{path}: '{key}' must have shape (1, {width}), got "
                             f"{arr[key].shape}")
    for key in ("shape", "expr"):
        if key not in arr:
            raise ValueError(f"{path}: missing '{key}'")
    for key, value in arr.items():
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{path}: '{key}' contains NaN or infinite values")
    return arr


def first_flame_param(folder: str) -> dict:
    """The flame_param of a folder's first training frame (what sizes its FLAME model), read
    from where transforms_train.json points (a UNION folder holds none of its own)."""
    frames = load_split(folder, "train")
    if not frames:
        raise ValueError(f"{os.path.join(folder, 'transforms_train.json')}: no frames")
    return load_flame_param(min(frames, key=lambda fr: fr.timestep).flame_param_path)


def read_image(path: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB (or (H, W) for masks) from a PNG, with a clear error."""
    import cv2

    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: missing or unreadable image")
    return img[..., ::-1].copy() if img.ndim == 3 else img


def load_scene(folder: str, model, face_regions) -> Scene:
    """A user's capture in this layout as a `Scene` posed by `model` (with (F,) `face_regions`).

    The train split's timesteps become the training sequence "train" (its cameras the training
    cameras), cameras that appear only in the val split are held out (novel view), and the test
    split's timesteps not used for training become the self-reenactment sequence "test". Each
    camera's intrinsics and pose are read from its first frame; the shape is the first flame
    param file's. Images of (camera, timestep) pairs the folder does not hold stay zero.
    Errors name the file and the field.
    """
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"{folder}: no such folder")
    splits = {"train": load_split(folder, "train")}
    for split in ("val", "test"):
        if os.path.isfile(os.path.join(folder, f"transforms_{split}.json")):
            splits[split] = load_split(folder, split)
    if not splits["train"]:
        raise ValueError(f"{os.path.join(folder, 'transforms_train.json')}: no frames")
    cameras = {}
    for frames in splits.values():
        for fr in frames:
            cameras.setdefault(fr.camera, fr)
    sizes = {(fr.width, fr.height) for fr in cameras.values()}
    if len(sizes) != 1:
        raise ValueError(f"{folder}: every camera must have the same image size, got "
                         f"{sorted(sizes)}")
    (width, height), = sizes
    cam_ids = sorted(cameras)
    column = {c: i for i, c in enumerate(cam_ids)}
    train_cams = sorted({fr.camera for fr in splits["train"]})
    held_out = sorted({fr.camera for fr in splits.get("val", [])} - set(train_cams))
    train_steps = sorted({fr.timestep for fr in splits["train"]})
    test_steps = sorted({fr.timestep for fr in splits.get("test", [])} - set(train_steps))

    param_paths = {fr.timestep: fr.flame_param_path for frames in splits.values()
                   for fr in frames}
    params = {t: load_flame_param(param_paths[t]) for t in train_steps + test_steps}
    first = min(params)
    shape = params[first]["shape"].reshape(-1)
    static_offsets = {}
    if "static_offset" in params[first]:
        try:
            static_offsets["A"] = fit_static_offset(params[first]["static_offset"],
                                                    model.num_vertices)
        except ValueError as e:
            raise ValueError(f"{param_paths[first]}: {e}") from None
    for t, p in params.items():
        if p["expr"].shape[1] != model.num_expr:
            raise ValueError(f"{param_paths[t]}: 'expr' has {p['expr'].shape[1]} coefficients, "
                             f"the FLAME model {model.num_expr}")
    if shape.shape[0] != model.num_shape:
        raise ValueError(f"{param_paths[first]}: 'shape' has {shape.shape[0]} "
                         f"coefficients, the FLAME model {model.num_shape}")

    def sequence(name, split, steps):
        def stack(key):
            return np.concatenate([params[t][key] for t in steps]).astype(np.float64)

        return Sequence(name=name, identity="A", split=split, expr=stack("expr"),
                        rotation=stack("rotation"), neck=stack("neck_pose"),
                        jaw=stack("jaw_pose"), eyes=stack("eyes_pose"),
                        translation=stack("translation"))

    sequences = {"train": sequence("train", "train", train_steps)}
    steps_of = {"train": train_steps}
    if test_steps:
        sequences["test"] = sequence("test", "self_reenactment", test_steps)
        steps_of["test"] = test_steps
    images, regions = {}, {}
    for name, steps in steps_of.items():
        row = {t: i for i, t in enumerate(steps)}
        images[name] = np.zeros((len(cam_ids), len(steps), height, width, 3), np.uint8)
        regions[name] = np.full((len(cam_ids), len(steps), height, width), -1, np.int8)
        for frames in splits.values():
            for fr in frames:
                if fr.timestep not in row:
                    continue
                image = read_image(fr.image_path)
                if image.shape != (height, width, 3):
                    raise ValueError(f"{fr.image_path}: expected a ({height}, {width}, 3) RGB "
                                     f"image, got {image.shape}")
                images[name][column[fr.camera], row[fr.timestep]] = image
                if fr.mask_path is not None:
                    mask = read_image(fr.mask_path)
                    mask = mask if mask.ndim == 2 else mask[..., 0]
                    regions[name][column[fr.camera], row[fr.timestep]] = np.where(
                        mask > 127, 0, -1)
    grey = np.full((model.num_vertices, 3), 0.5, np.float32)
    return Scene(model=model, face_regions=np.asarray(face_regions, np.int32),
                 intrinsics=np.stack([cameras[c].intrinsics for c in cam_ids]).astype(np.float32),
                 w2c=np.stack([cameras[c].w2c for c in cam_ids]).astype(np.float32),
                 width=width, height=height,
                 train_cameras=tuple(column[c] for c in train_cams),
                 held_out_cameras=tuple(column[c] for c in held_out), shapes={"A": shape},
                 vertex_colors={"A": grey}, sequences=sequences, images=images, regions=regions,
                 background=np.ones(3, np.float32), kind="capture",
                 static_offsets=static_offsets)
