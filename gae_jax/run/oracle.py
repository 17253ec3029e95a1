"""Oracles, for studies only (`benchmarks/`; never a CLI choice, and nothing else in the
package imports them): they read the ideal edit.

`OracleEditor`: the ray-cast ideal edit of each sampled view and frame, i.e. a perfect,
consistent 2D editor.

Fed to the same render-edit-aggregate loop (`edit.edit_avatar(..., editor=OracleEditor(...))`),
it measures the ceiling of the loop itself: what aggregation reaches when every 2D edit is right.
It reads the ground truth, which is why it is named an oracle.

`recoloured`: an avatar's region recoloured in closed form by the ideal albedo's ratio to the
unedited one: a perfect colour edit of the avatar's geometry (the colour-only ceiling).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from gae_jax import instructions
from gae_jax.evaluation import truth
from gae_jax.model import avatar as av, head
from gae_jax.scene import synthetic


class OracleEditor:
    """`edit(render, original, prompt, key, context)` -> the ideal edit at `context["view"]`
    = (camera, sequence, frame); every camera of a frame is ray-cast once and kept."""

    def __init__(self, scene, prompt: str):
        if scene.kind != "synthetic":
            raise ValueError("the oracle editor needs a synthetic scene (its ideal edit)")
        instruction, self.ideal = truth.ideal_of(scene, prompt)
        if instruction is None:
            raise ValueError(f"{prompt!r} has no ideal edit (a style); no oracle")
        self.scene, self.prompt = scene, prompt
        self.frames: dict = {}

    def edit(self, render, original, prompt, key, context=None):
        if prompt != self.prompt:
            raise ValueError(f"the oracle was built for {self.prompt!r}, asked {prompt!r}")
        cam, name, t = context["view"]
        if (name, t) not in self.frames:
            s = self.scene
            images, _ = synthetic.render_frame(
                s.model, s.face_regions, self.ideal.values, s.shapes["A"], s.sequences[name], t,
                s.intrinsics, s.w2c, s.width, s.background, supersample=s.supersample,
                shader=self.ideal.shader)
            self.frames[(name, t)] = images
        return self.frames[(name, t)][cam].astype(np.float32) / 255.0


def recoloured(scene, avatar: av.Avatar, prompt: str) -> av.Avatar:
    """`avatar` with the prompt's region's colours times the ideal-to-unedited albedo ratio of
    their face (mean over its vertices; for stripes, the stripe colour's ratio where the
    Gaussian's rest-pose height is on a stripe, as the ideal decides per ray); plain RGB."""
    instruction, ideal = truth.ideal_albedo(scene, prompt)
    faces = np.asarray(scene.model.faces)
    if instruction.stripes:
        ideal = np.broadcast_to(np.asarray(instruction.colour), ideal.shape)
    ratio = (ideal / np.maximum(scene.albedo["A"], 1e-3))[faces[np.asarray(avatar.binding)]]
    ratio = ratio.mean(axis=1)
    inside = np.asarray(avatar.regions) == head.REGION_ID[instruction.region]
    if instruction.stripes:
        rest = av.deform(avatar, scene.model.v_template, scene.model.faces).means
        inside &= instructions.stripe_on(np.asarray(rest)[:, 1])
    colors = np.asarray(avatar.colors).copy()
    colors[inside] = np.clip(colors[inside] * ratio[inside], 0.0, 1.0)
    return avatar.with_params(dict(avatar.trainable(), colors=jnp.asarray(colors)))
