"""Slider values <-> FLAME parameters.

Every dimension of a frame's FLAME parameters has one slider, so a sequence's frame loaded into
the sliders and read back is that frame exactly (`values_of_frame` then `params_of_values`):
one per expression direction (named by the model), jaw open / sideways / twist (axis-angle x, y,
z, radians), each eye's pitch / yaw / roll, neck and head pitch / yaw / roll, head position x /
y / z (metres). A slider's key names the parameter and index (`"jaw/0"`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from gae_jax.model.flame import FlameParams

AXES = ("pitch", "yaw", "roll")
# (group, field, index, label, default half-range). Angles in radians, positions in metres.
POSE_SLIDERS = (
    [("Jaw", "jaw", i, f"jaw {n}", r) for i, (n, r) in
     enumerate((("open", 0.6), ("sideways", 0.3), ("twist", 0.3)))]
    + [("Eyes", "eyes", 3 * s + i, f"{side} eye {a}", 0.5) for s, side in enumerate(("left", "right"))
       for i, a in enumerate(AXES)]
    + [("Head", "neck", i, f"neck {a}", 0.6) for i, a in enumerate(AXES)]
    + [("Head", "rotation", i, f"head {a}", 1.2) for i, a in enumerate(AXES)]
    + [("Head", "translation", i, f"head position {c}", 0.1) for i, c in enumerate("xyz")])
WIDTHS = dict(jaw=3, eyes=6, neck=3, rotation=3, translation=3)


@dataclasses.dataclass(frozen=True)
class Slider:
    """One slider: `key` "field/index", its folder, label and range."""

    key: str
    group: str
    label: str
    low: float
    high: float
    step: float


def _span(default: float, sequences: dict, field: str, index: int) -> float:
    """The default half-range, widened (to a round 0.1) to hold every sequence's value."""
    seen = [np.max(np.abs(getattr(s, field)[:, index])) for s in sequences.values()]
    return float(max([default] + [np.ceil(10 * v) / 10 for v in seen]))


def sliders(expr_names: tuple, sequences: dict, expression_range: float) -> list:
    """The sliders of a model with expression directions `expr_names`: expressions over
    [-expression_range, expression_range] (widened to the sequences' values), then the pose."""
    out = []
    for i, name in enumerate(expr_names):
        r = _span(expression_range, sequences, "expr", i)
        out.append(Slider(f"expr/{i}", "Expression", name, -r, r, 0.01))
    for group, field, index, label, default in POSE_SLIDERS:
        r = _span(default, sequences, field, index)
        step = 0.001 if field == "translation" else 0.01
        out.append(Slider(f"{field}/{index}", group, label, -r, r, step))
    return out


def neutral(num_expr: int) -> dict:
    """Slider values of the neutral pose: every key at 0."""
    keys = [f"expr/{i}" for i in range(num_expr)]
    keys += [f"{field}/{i}" for field, w in WIDTHS.items() for i in range(w)]
    return {k: 0.0 for k in keys}


def values_of_frame(sequence, frame: int) -> dict:
    """Slider values (key -> float) of frame `frame` of a `types.Sequence`."""
    values = {f"expr/{i}": float(v) for i, v in enumerate(sequence.expr[frame])}
    for field, width in WIDTHS.items():
        values.update({f"{field}/{i}": float(getattr(sequence, field)[frame, i])
                       for i in range(width)})
    return values


def params_of_values(values: dict, shape, num_expr: int, static_offset=None) -> FlameParams:
    """FlameParams of slider values (missing keys are 0) with identity `shape` (S,) and its
    optional (V, 3) `static_offset`."""
    def vector(field, width):
        return jnp.asarray([values.get(f"{field}/{i}", 0.0) for i in range(width)], jnp.float32)

    return FlameParams(shape=jnp.asarray(shape, jnp.float32), expr=vector("expr", num_expr),
                       rotation=vector("rotation", 3), neck=vector("neck", 3),
                       jaw=vector("jaw", 3), eyes=vector("eyes", 6),
                       translation=vector("translation", 3),
                       static_offset=None if static_offset is None else jnp.asarray(
                           static_offset, jnp.float32))
