"""Image conversions shared by every stage."""

from __future__ import annotations

import numpy as np


def to_uint8(image) -> np.ndarray:
    """[0, 1] values -> uint8, clipped and rounded to the nearest level. Floats are scaled in
    their own precision (float32 stays float32, so cached 8-bit images do not change with
    the caller); anything else as float64."""
    x = np.asarray(image)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    return (np.clip(x, 0, 1) * 255 + 0.5).astype(np.uint8)
