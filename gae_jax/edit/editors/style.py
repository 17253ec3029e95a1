"""OpenCV stylisers as a 2D editor: "make it an oil painting", "a pencil sketch", "cartoon",
"stylise it / watercolour". A real 2D editor: each call sees one image, so results differ across
views and time; the key additionally jitters the filter parameters and a slight colour cast, as a diffusion
editor's seed would.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from gae_jax.edit.editors.base import as_image
from gae_jax.instructions import parse_style
from gae_jax.util.image import to_uint8

@dataclasses.dataclass(frozen=True)
class StyleEditor:
    """`jitter` in [0, 1] scales the per-call randomness of the filter parameters."""

    jitter: float = 1.0

    def __post_init__(self):
        if not 0.0 <= self.jitter <= 1.0:
            raise ValueError(f"jitter must be in [0, 1], got {self.jitter}")

    def edit(self, render, original, prompt: str, key, context: dict | None = None):
        import cv2

        style = parse_style(prompt)
        image = as_image(render, "render")
        u = 0.5 + self.jitter * (np.asarray(jax.random.uniform(key, (6,))) - 0.5)
        bgr = to_uint8(image[..., ::-1])
        if style == "oil":
            out = cv2.xphoto.oilPainting(bgr, 2 + int(3 * u[0]), 1 + int(2 * u[1]))
        elif style == "sketch":
            _, out = cv2.pencilSketch(bgr, sigma_s=20 + 40 * u[0], sigma_r=0.05 + 0.1 * u[1],
                                      shade_factor=0.03 + 0.05 * u[2])
        elif style == "cartoon":
            smooth = cv2.bilateralFilter(bgr, 5, 40 + 60 * u[0], 5 + 5 * u[1])
            gray = cv2.medianBlur(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), 3)
            edges = cv2.adaptiveThreshold(gray, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                          cv2.THRESH_BINARY, 7, 3 + int(4 * u[2]))
            levels = 6
            smooth = (smooth // (256 // levels)) * (256 // levels) + 128 // levels
            out = np.where(edges[..., None] > 0, smooth, 0).astype(np.uint8)
        else:
            out = cv2.stylization(bgr, sigma_s=30 + 50 * u[0], sigma_r=0.3 + 0.3 * u[1])
        # Per-call colour cast, as a diffusion editor's seed gives (none at u = 0.5).
        tint = 1.0 + 0.1 * (u[3:] - 0.5)
        return np.clip(out[..., ::-1].astype(np.float32) / 255.0 * tint, 0, 1).astype(np.float32)
