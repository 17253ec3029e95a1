"""The oracle editor (benchmarks only, never a CLI choice): the ray-cast ideal edit of each
sampled view and frame, i.e. a perfect, consistent 2D editor.

Fed to the same render-edit-aggregate loop (`edit.edit_avatar(..., editor=OracleEditor(...))`),
it measures the ceiling of the loop itself: what aggregation reaches when every 2D edit is right.
It reads the ground truth, which is why it lives here and is named an oracle.
"""

from __future__ import annotations

import numpy as np

from gae_jax.evaluation import truth
from gae_jax.scene import synthetic


class OracleEditor:
    """`edit(render, original, prompt, key, context)` -> the ideal edit at `context["view"]`
    = (camera, sequence, frame); every camera of a frame is ray-cast once and kept."""

    def __init__(self, scene, prompt: str):
        if scene.kind != "synthetic":
            raise ValueError("the oracle editor needs a synthetic scene (its ideal edit)")
        instruction, albedo = truth.ideal_albedo(scene, prompt)
        if instruction is None:
            raise ValueError(f"{prompt!r} has no ideal edit (a style); no oracle")
        self.scene, self.prompt = scene, prompt
        self.colours = synthetic.shaded_colors(scene.model, albedo, scene.shapes["A"])
        self.frames: dict = {}

    def edit(self, render, original, prompt, key, context=None):
        if prompt != self.prompt:
            raise ValueError(f"the oracle was built for {self.prompt!r}, asked {prompt!r}")
        cam, name, t = context["view"]
        if (name, t) not in self.frames:
            s = self.scene
            images, _ = synthetic.render_frame(
                s.model, s.face_regions, self.colours, s.shapes["A"], s.sequences[name], t,
                s.intrinsics, s.w2c, s.width, s.background, supersample=s.supersample)
            self.frames[(name, t)] = images
        return self.frames[(name, t)][cam].astype(np.float32) / 255.0
