"""FLAME model files, read safely and written (GaussianAvatars' teeth: `teeth`).

`load_flame` reads the FLAME 2020 `generic_model.pkl` / FLAME 2023 `flame2023.pkl` pickles
(shapedirs holds 300 identity + 100 expression columns; J_regressor may be a scipy sparse matrix;
arrays may be chumpy objects) through a restricted unpickler that rebuilds only numpy arrays, scipy
sparse matrices and chumpy arrays -- neither chumpy nor scipy is imported, and a pickle can never
run code -- and our own `.npz`. `save_flame` writes either layout (by the file's suffix).
`load_flame_masks` reads FLAME's `FLAME_masks.pkl` (region name -> vertex indices) and
`face_regions_from_masks` turns it into our per-face region labels. Nothing licence-gated ships
with gae_jax.
"""

from __future__ import annotations

import io
import os
import pickle

import jax.numpy as jnp
import numpy as np

from gae_jax.model.flame import FlameModel
from gae_jax.model.head import REGION_ID
from gae_jax.util.fileio import atomic_write_bytes, write_npz

FLAME_IDENTITY_COMPONENTS = 300  # columns of the pickle's shapedirs before the expression ones
# FLAME_masks.pkl names -> our regions (names equal to one of ours map to themselves).
FLAME_MASK_REGIONS = {"lips": "lips", "left_eyeball": "sclera", "right_eyeball": "sclera",
                      "scalp": "hair"}

class FlameFileError(ValueError):
    """A FLAME file is unreadable, unsafe, or missing / mis-shaping a field."""


class _ArrayState:
    """Holds the pickled state of a chumpy array or a scipy sparse matrix, nothing else."""

    state: dict = {}

    def __init__(self, *args, **kwargs):
        self.state = {}

    def __setstate__(self, state):
        self.state = state if isinstance(state, dict) else {"args": state}


class _ChumpyArray(_ArrayState):
    kind = "chumpy"


class _SparseMatrix(_ArrayState):
    kind = "sparse"


_NUMPY_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.numeric", "_frombuffer"),
}


class _RestrictedUnpickler(pickle.Unpickler):
    """Rebuilds numpy arrays, scipy sparse matrices and chumpy arrays; refuses everything else."""

    def find_class(self, module, name):
        if (module, name) in _NUMPY_ALLOWED:
            if module.startswith("numpy.core") and hasattr(np, "_core"):
                module = "numpy._core" + module[len("numpy.core"):]  # numpy 2 moved it
            return super().find_class(module, name)
        if (module, name) == ("_codecs", "encode"):  # how protocol-2 pickles store bytes
            return _latin1_encode
        if (module, name) in {("copyreg", "_reconstructor"), ("copy_reg", "_reconstructor")}:
            return _reconstruct_stub
        if (module, name) in {("builtins", "object"), ("__builtin__", "object")}:
            return object
        if module.startswith("scipy.sparse") and name in ("csc_matrix", "csr_matrix",
                                                          "coo_matrix"):
            return type(name, (_SparseMatrix,), {"format": name[:3]})
        if module.split(".")[0] == "chumpy":
            return _ChumpyArray
        raise FlameFileError(f"refusing to unpickle {module}.{name}: a FLAME file only holds "
                             "numpy, scipy.sparse and chumpy arrays")


def _latin1_encode(text, encoding="latin1"):
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise FlameFileError("refusing an unexpected _codecs.encode call")
    return text.encode("latin1")


def _reconstruct_stub(cls, base, state):
    if not (isinstance(cls, type) and issubclass(cls, _ArrayState)):
        raise FlameFileError(f"refusing to reconstruct {cls!r}")
    return cls()


def _to_array(value, key: str, path: str) -> np.ndarray:
    """numpy, chumpy-like or sparse-like value -> dense numpy array."""
    if isinstance(value, np.ndarray):
        return value
    if isinstance(value, _ChumpyArray):
        for field in ("x", "r", "a"):
            if field in value.state:
                return _to_array(value.state[field], key, path)
        raise FlameFileError(f"{path}: chumpy array '{key}' holds no data ('x')")
    if isinstance(value, _SparseMatrix):
        st = value.state
        shape = st.get("_shape", st.get("shape"))
        if value.format == "coo":
            dense = np.zeros(shape)
            np.add.at(dense, (np.asarray(st["row"]), np.asarray(st["col"])),
                      np.asarray(st["data"]))
            return dense
        data, indices, indptr = (np.asarray(st[k]) for k in ("data", "indices", "indptr"))
        dense = np.zeros(shape, dtype=data.dtype)
        major = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
        if value.format == "csc":
            np.add.at(dense, (indices, major), data)
        else:
            np.add.at(dense, (major, indices), data)
        return dense
    if isinstance(value, (list, tuple, int, float)):
        return np.asarray(value)
    raise FlameFileError(f"{path}: field '{key}' has unsupported type {type(value).__name__}")


def _read_pickle(path: str) -> dict:
    with open(path, "rb") as f:
        data = f.read()
    try:
        obj = _RestrictedUnpickler(io.BytesIO(data), encoding="latin1").load()
    except FlameFileError as exc:
        raise FlameFileError(f"{path}: {exc}") from None
    except Exception as exc:  # truncated or corrupt files
        raise FlameFileError(f"{path}: not a readable FLAME pickle ({exc})") from exc
    if not isinstance(obj, dict):
        raise FlameFileError(f"{path}: expected a dict of arrays, got {type(obj).__name__}")
    return obj


def _read_npz(path: str) -> dict:
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception as exc:
        raise FlameFileError(f"{path}: not a readable .npz ({exc})") from exc


def _require(raw: dict, key: str, path: str, ndim: int) -> np.ndarray:
    if key not in raw:
        raise FlameFileError(f"{path}: missing field '{key}'")
    arr = _to_array(raw[key], key, path)
    if arr.ndim != ndim:
        raise FlameFileError(f"{path}: field '{key}' must have {ndim} dimensions, got shape "
                             f"{arr.shape}")
    if arr.dtype.kind in "fc" and not np.all(np.isfinite(arr)):
        raise FlameFileError(f"{path}: field '{key}' contains NaN or infinite values")
    return arr


def _build(v_template, shapedirs, exprdirs, posedirs, j_regressor, weights, faces, parents,
           path: str, dtype) -> FlameModel:
    v = v_template.shape[0]
    j = len(parents)
    checks = {
        "v_template": (v_template.shape, (v, 3)),
        "shapedirs": (shapedirs.shape[:2], (v, 3)),
        "exprdirs": (exprdirs.shape[:2], (v, 3)),
        "posedirs": (posedirs.shape, (v, 3, (j - 1) * 9)),
        "J_regressor": (j_regressor.shape, (j, v)),
        "weights": (weights.shape, (v, j)),
        "f": (faces.shape[1:], (3,)),
    }
    for key, (got, want) in checks.items():
        if tuple(got) != tuple(want):
            raise FlameFileError(f"{path}: field '{key}' has shape {tuple(got)}, expected {want}")
    if parents[0] != -1 or any(not 0 <= p < i for i, p in enumerate(parents) if i > 0):
        raise FlameFileError(f"{path}: kinematic tree {parents} is not a tree rooted at joint 0")
    if faces.size and (faces.min() < 0 or faces.max() >= v):
        raise FlameFileError(f"{path}: field 'f' indexes vertices outside 0..{v - 1}")
    return FlameModel(
        v_template=jnp.asarray(v_template, dtype), shapedirs=jnp.asarray(shapedirs, dtype),
        exprdirs=jnp.asarray(exprdirs, dtype), posedirs=jnp.asarray(posedirs, dtype),
        j_regressor=jnp.asarray(j_regressor, dtype), lbs_weights=jnp.asarray(weights, dtype),
        faces=jnp.asarray(faces, jnp.int32), parents=tuple(int(p) for p in parents))


def load_flame(path: str, n_shape: int = 300, n_expr: int = 100, dtype=jnp.float32) -> FlameModel:
    """Reads a FLAME `.pkl` (2020 / 2023) or a gae_jax `.npz`.

    Args:
      n_shape, n_expr: how many identity / expression components to keep (at most what the file
        has). In a pickle the expression basis is columns 300.. of `shapedirs`.
    Raises:
      FlameFileError naming the file and field for unsafe, unreadable or malformed files.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FlameFileError(f"{path}: no such file")
    if path.endswith(".npz"):
        raw = _read_npz(path)
        shapedirs = _require(raw, "shapedirs", path, 3)
        exprdirs = _require(raw, "exprdirs", path, 3)
        parents = tuple(int(p) for p in _require(raw, "parents", path, 1))
    else:
        raw = _read_pickle(path)
        all_dirs = _require(raw, "shapedirs", path, 3)
        if all_dirs.shape[-1] > FLAME_IDENTITY_COMPONENTS:
            shapedirs = all_dirs[..., :FLAME_IDENTITY_COMPONENTS]
            exprdirs = all_dirs[..., FLAME_IDENTITY_COMPONENTS:]
        else:
            shapedirs, exprdirs = all_dirs, all_dirs[..., :0]
        kintree = _require(raw, "kintree_table", path, 2)
        parents = (-1,) + tuple(int(p) for p in kintree[0, 1:])
    if n_shape > shapedirs.shape[-1] or n_expr > exprdirs.shape[-1]:
        raise FlameFileError(
            f"{path}: asked for {n_shape} shape / {n_expr} expression components, the file has "
            f"{shapedirs.shape[-1]} / {exprdirs.shape[-1]}")
    return _build(_require(raw, "v_template", path, 2), shapedirs[..., :n_shape],
                  exprdirs[..., :n_expr], _require(raw, "posedirs", path, 3),
                  _require(raw, "J_regressor", path, 2), _require(raw, "weights", path, 2),
                  _require(raw, "f", path, 2).astype(np.int64), parents, path, dtype)


def save_flame(model: FlameModel, path: str) -> None:
    """Writes a model atomically: FLAME's own pickle layout for `.pkl` (identity directions
    zero-padded to 300 columns, then the expression ones; `kintree_table`; protocol 2, plain
    numpy arrays), gae_jax `.npz` otherwise. Both are readable by `load_flame`."""
    arrays = dict(v_template=np.asarray(model.v_template), posedirs=np.asarray(model.posedirs),
                  J_regressor=np.asarray(model.j_regressor),
                  weights=np.asarray(model.lbs_weights), f=np.asarray(model.faces))
    if os.fspath(path).endswith(".pkl"):
        identity = np.asarray(model.shapedirs)
        if identity.shape[-1] > FLAME_IDENTITY_COMPONENTS:
            raise ValueError(f"{path}: FLAME's layout holds at most {FLAME_IDENTITY_COMPONENTS} "
                             f"identity directions, the model has {identity.shape[-1]}")
        pad = np.zeros(identity.shape[:2] + (FLAME_IDENTITY_COMPONENTS - identity.shape[-1],),
                       identity.dtype)
        parents = np.asarray(model.parents, np.int64)
        arrays.update(
            shapedirs=np.concatenate([identity, pad, np.asarray(model.exprdirs)], -1),
            kintree_table=np.stack([np.where(parents < 0, 2 ** 32 - 1, parents),
                                    np.arange(len(parents))]),
            f=arrays["f"].astype(np.uint32))
        atomic_write_bytes(path, pickle.dumps(arrays, protocol=2))
        return
    write_npz(path, dict(shapedirs=np.asarray(model.shapedirs),
                         exprdirs=np.asarray(model.exprdirs),
                         parents=np.asarray(model.parents), **arrays))


def load_flame_masks(path: str) -> dict:
    """FLAME_masks.pkl (or a `.npz` of the same): region name -> (K,) int vertex indices."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FlameFileError(f"{path}: no such file")
    if path.endswith(".npz"):
        raw = _read_npz(path)
    else:
        raw = _read_pickle(path)
    masks = {}
    for name, value in raw.items():
        idx = np.asarray(_to_array(value, name, path))
        if idx.ndim != 1 or idx.dtype.kind not in "iu":
            raise FlameFileError(f"{path}: mask '{name}' must be a 1-D integer index array, "
                                 f"got {idx.dtype} {idx.shape}")
        masks[str(name)] = idx.astype(np.int64)
    return masks


def face_regions_from_masks(faces, masks: dict, num_vertices: int) -> np.ndarray:
    """(F,) int32 region labels: a face takes the region of the smallest known mask holding all
    three of its vertices (`FLAME_MASK_REGIONS`, or a mask named like one of our regions), and
    'skin' otherwise. Unknown mask names are ignored."""
    faces = np.asarray(faces)
    regions = np.full(len(faces), REGION_ID["skin"], np.int32)
    known = [(name, FLAME_MASK_REGIONS.get(name, name)) for name in masks]
    known = [(n, r) for n, r in known if r in REGION_ID]
    for name, region in sorted(known, key=lambda nr: -len(masks[nr[0]])):
        idx = masks[name]
        if idx.size and (idx.min() < 0 or idx.max() >= num_vertices):
            raise FlameFileError(f"mask '{name}' indexes vertices outside 0..{num_vertices - 1}")
        inside = np.zeros(num_vertices, bool)
        inside[idx] = True
        regions[inside[faces].all(axis=1)] = REGION_ID[region]
    return regions
