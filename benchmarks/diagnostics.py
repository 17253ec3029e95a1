"""The diagnostic runs behind the README's findings on the edit before region-aware editing (the
`previous` preset, the default until then), in one resumable script.

    python benchmarks/diagnostics.py [--out benchmarks/results/diagnostics]

  * forward WABE on a layered avatar: the untouched reconstruction's PSNR against the truth on
    the held-out camera, rendered with standard blending and with the paper's WABE (beta 6), and
    its median opacity;
  * Adam's epsilon: the `previous` edit at adam_eps 1e-4 (its value) and 1e-15 (the usual one);
  * where the collateral damage comes from: the default at editor noise 0, the same with
    geometry frozen (colour-only edit), and the editor returning the original image outside the
    edited region (`--editor-keeps original`) at noise 0.3 and 0.
Edits: 100 iterations on the 128 px default scene, scored like `python -m gae_jax.train`
(PSNR against the ideal edit, novel view and mean over the protocols). Writes `<out>.json`
(every number; resumable) and `<out>.md`.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from gae_jax.edit.config import preset
from gae_jax.evaluation.score import psnr_against_capture
from gae_jax.render import wabe
from gae_jax.run.bench import Bench, mean_over_protocols, score_of
from gae_jax.run.original import original_avatar
from gae_jax.scene import synthetic
from gae_jax.scene.types import training_frames

EDITS = {
    "default": {},
    "adam_eps_1e-15": dict(adam_eps=1e-15),
    "noise_0": dict(editor_noise=0.0),
    "noise_0_colour_only": dict(editor_noise=0.0, lr_geometry=0.0, lr_means=0.0),
    "keeps_original": dict(editor_keeps="original"),
    "keeps_original_noise_0": dict(editor_keeps="original", editor_noise=0.0),
}
COLUMNS = (("edited", "lips"), ("teeth", "teeth"), ("rest", "rest"), ("whole", "whole"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="benchmarks/results/diagnostics")
    p.add_argument("--iterations", type=int, default=100)
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    bench = Bench(args.out + ".json")
    scene = synthetic.make_synthetic_scene(size=128, progress=False)
    base = preset("previous", checkpoint_every=0, iterations=args.iterations)
    original = original_avatar(scene, base.reconstruct_iterations, progress=False)
    pairs = training_frames(scene)[::4]
    opacity = 1 / (1 + np.exp(-np.asarray(original.opacity_logits)))
    blending = dict(median_opacity=round(float(np.median(opacity)), 3), **{
        name: round(psnr_against_capture(original, scene, pairs, scene.held_out_cameras,
                                         blend=blend), 2)
        for name, blend in (("standard", wabe.standard()), ("wabe_beta_6", wabe.wabe(6.0)))})
    for name, knobs in EDITS.items():
        bench.run(name, preset("previous", checkpoint_every=0, iterations=args.iterations,
                               **knobs),
                  scene, original, extra=dict(knobs=knobs))
    bench.save(blending=blending)
    lines = ["# Diagnostics of the default edit", "",
             f"Untouched reconstruction ({base.reconstruct_iterations} steps), held-out camera, "
             f"PSNR against the truth: standard blending {blending['standard']} dB, forward "
             f"WABE (beta 6) {blending['wabe_beta_6']} dB; median opacity "
             f"{blending['median_opacity']}.", "",
             "PSNR dB against the ideal edit, novel view (mean over the three protocols):", "",
             "| edit | " + " | ".join(c for _, c in COLUMNS) + " |",
             "|---" * (len(COLUMNS) + 1) + "|"]
    for name, record in bench.results.items():
        cells = []
        for region, _ in COLUMNS:
            nv = score_of(record, "novel_view", "psnr", region)
            mean = mean_over_protocols(record, "psnr", region)
            cells.append(f"{nv:.2f} ({mean:.2f})" if nv is not None else "-")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    with open(args.out + ".md", "w") as f:
        f.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
