"""A scene's motions as one `.npz`: every sequence's FLAME parameters and every identity's shape
(and static offset, when it has one).

A run folder of `python -m gae_jax.train` carries it as `motion.npz`, so that a viewer can play
the scene's sequences (training, held-out, cross-identity) without the scene. Arrays:
`shape/<identity>` (S,), `static_offset/<identity>` (V, 3) when the identity has one,
`sequence/<name>/<field>` (T, ...) for the `types.Sequence` fields
expr (T, E), rotation, neck, jaw, translation (T, 3) and eyes (T, 6); `meta` is JSON of each
sequence's identity and split, in the scene's order.
"""

from __future__ import annotations

import json

import numpy as np

from gae_jax.scene.types import SPLITS, Sequence
from gae_jax.util.fileio import write_npz

FILE_NAME = "motion.npz"
FIELDS = dict(expr=None, rotation=3, neck=3, jaw=3, eyes=6, translation=3)


def save(path: str, sequences: dict, shapes: dict, static_offsets: dict | None = None) -> None:
    """Writes name -> `Sequence`, identity -> (S,) shape and identity -> (V, 3) static offset
    atomically."""
    arrays = {f"shape/{k}": np.asarray(v, np.float32) for k, v in shapes.items()}
    arrays.update({f"static_offset/{k}": np.asarray(v, np.float32)
                   for k, v in (static_offsets or {}).items()})
    meta = []
    for name, seq in sequences.items():
        meta.append(dict(name=name, identity=seq.identity, split=seq.split))
        arrays.update({f"sequence/{name}/{f}": np.asarray(getattr(seq, f), np.float32)
                       for f in FIELDS})
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    write_npz(path, arrays, compressed=True)


def load(path: str, num_expr: int, num_shape: int) -> tuple[dict, dict, dict]:
    """(name -> Sequence, identity -> (S,) shape, identity -> (V, 3) static offset) of `save`'s
    file, checked against a model with `num_expr` expression and `num_shape` shape components;
    ValueError naming the file and what is wrong when it is unreadable or does not fit."""
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {k: np.asarray(f[k]) for k in f.files}
        meta = json.loads(bytes(data["meta"]).decode())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such file") from None
    except Exception as e:  # truncated zip, bad CRC or JSON, missing meta
        raise ValueError(f"{path}: not a readable motion file ({type(e).__name__}: {e})") \
            from None
    shapes = {k[len("shape/"):]: v for k, v in data.items() if k.startswith("shape/")}
    for identity, shape in shapes.items():
        if shape.shape != (num_shape,):
            raise ValueError(f"{path}: identity {identity}'s shape has {shape.shape}, the model "
                             f"takes ({num_shape},)")
    sequences = {}
    for entry in meta:
        name = entry["name"]
        if entry["split"] not in SPLITS or entry["identity"] not in shapes:
            raise ValueError(f"{path}: sequence {name!r} has split {entry['split']!r} and "
                             f"identity {entry['identity']!r} (known: {sorted(shapes)})")
        fields = {}
        for field, width in FIELDS.items():
            key = f"sequence/{name}/{field}"
            if key not in data:
                raise ValueError(f"{path}: missing {key}")
            fields[field] = data[key].astype(np.float64)
        frames = fields["expr"].shape[0]
        for field, width in FIELDS.items():
            want = (frames, num_expr if width is None else width)
            if fields[field].shape != want:
                raise ValueError(f"{path}: {name}/{field} has shape {fields[field].shape}, "
                                 f"expected {want}")
            if not np.all(np.isfinite(fields[field])):
                raise ValueError(f"{path}: {name}/{field} holds NaN or infinite values")
        sequences[name] = Sequence(name=name, identity=entry["identity"], split=entry["split"],
                                   **fields)
    offsets = {k[len("static_offset/"):]: v for k, v in data.items()
               if k.startswith("static_offset/")}
    return sequences, shapes, offsets
