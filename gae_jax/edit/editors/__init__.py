"""2D editors behind one protocol, run outside jit.

    editor.edit(render, original, prompt, key, context) -> edited image

render, original: (H, W, 3) float in [0, 1] (numpy or jax); key: a jax PRNG key (all randomness);
context: a dict of what the caller knows about the render (`regions` (H, W) int region labels
rendered from the avatar, -1 background; `canonical` (H, W, 3) head-space positions; `view`
(camera, sequence name, frame) of the render; ...). The
result is a float32 numpy image of the same size.

  * `semantic` (default, no weights): recolours / patterns named regions, with a calibrated
    inconsistency model (`noise`).
  * `style`: OpenCV stylisers (oil painting, pencil sketch, stylisation, cartoon).
  * `ip2p`: InstructPix2Pix from a local diffusers folder (optional extra `gae-jax[ip2p]`).
"""

from __future__ import annotations

from gae_jax.edit.editors.base import Editor, as_image  # noqa: F401 (the package API)

EDITORS = ("semantic", "style", "ip2p")


def make_editor(name: str, **options) -> Editor:
    """The editor called `name` (one of `EDITORS`) with its options."""
    if name == "semantic":
        from gae_jax.edit.editors.semantic import SemanticEditor

        return SemanticEditor(**options)
    if name == "style":
        from gae_jax.edit.editors.style import StyleEditor

        return StyleEditor(**options)
    if name == "ip2p":
        from gae_jax.edit.editors.ip2p import InstructPix2PixEditor

        return InstructPix2PixEditor(**options)
    raise ValueError(f"unknown editor {name!r}; choose one of {EDITORS}")
