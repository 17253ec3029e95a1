"""What every 2D editor shares: the protocol and input checking."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Editor(Protocol):
    def edit(self, render, original, prompt: str, key, context: dict | None = None) -> np.ndarray:
        ...


def as_image(x, name: str = "image") -> np.ndarray:
    """(H, W, 3) float32 numpy copy of an image in [0, 1]; clear errors on bad input."""
    a = np.asarray(x, np.float32)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise ValueError(f"{name} must be (H, W, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} has non-finite values")
    return np.clip(a, 0.0, 1.0)
