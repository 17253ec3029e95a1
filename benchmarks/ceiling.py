"""Where the loop's ceiling on the lips comes from: the oracle editor (ideal 2D edits) under
variants of the default edit, and the error split into the lips' interior and their rim.

    python benchmarks/ceiling.py [--variants default ...] [--out benchmarks/results/ceiling]

Variants (all with `oracle.OracleEditor`, "turn the lips blue", 128 px default scene):
  default, 300 iterations, batch 4, geometry rates x10, and every lips Gaussian split twice
  before the edit (`avatar.densify`). For each: PSNR of the lips, teeth and whole image
  against the ideal edit (mean over the protocols), and on the novel view the lips' PSNR over
  their interior (lips pixels whose 3x3 neighbourhood is all lips) and over their one-pixel rim,
  the rim split by what it borders (`rim_mouth`: a mouth or teeth pixel in its 3x3
  neighbourhood; `rim_skin`: the rest), with each part's share of the lips' squared error,
  beside the untouched avatar's on the same pixels against the *unedited* truth (red lips: the
  reconstruction's own edge error at a lower contrast). Writes `<out>.json` and `<out>.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import cv2
import jax
import numpy as np

from gae_jax.edit.config import preset
from gae_jax.evaluation import metrics, protocols, score, truth
from gae_jax.model import avatar as av, head
from gae_jax.run.bench import Bench, default_scene_and_avatar, mean_over_protocols, write_report
from gae_jax.run.oracle import OracleEditor
from gae_jax.scene import rig as rigs

PROMPT = "turn the lips blue"
VARIANTS = {"default": {}, "iterations_300": dict(iterations=300), "batch_4": dict(batch=4),
            "geometry_x10": dict(lr_geometry=1e-2, lr_means=1e-3), "split_lips_twice": {}}


def split_region(avatar: av.Avatar, name: str, times: int) -> av.Avatar:
    for k in range(times):
        chosen = np.asarray(avatar.regions) == head.REGION_ID[name]
        avatar = av.densify(avatar, np.zeros_like(chosen), chosen, jax.random.PRNGKey(k))
    return avatar


def rim_and_interior(scene, edited, original, blend, tile_capacity) -> dict:
    """Novel-view lips PSNR over interior and rim pixels: ours vs the ideal, the untouched
    avatar vs the unedited truth."""
    pf = protocols.protocol_frames(scene, "novel_view", frames=4)
    evalset = truth.build(scene, PROMPT, frames=4)
    frames = evalset.protocols["novel_view"][0]
    plain = truth.frames_truth(scene, pf, scene.albedo["A"])
    render = rigs.make_view_renderer(blend)
    ours = score.render_frames(render, edited, evalset, frames, tile_capacity)
    before = score.render_frames(render, original, evalset, frames, tile_capacity)
    lips = frames.regions == head.REGION_ID["lips"]
    mouth = np.isin(frames.regions, [head.REGION_ID["mouth"], head.REGION_ID["teeth"]])
    kernel = np.ones((3, 3), np.uint8)

    def per_image(masks, op):
        return np.stack([[op(m.astype(np.uint8), kernel) > 0 for m in f] for f in masks])

    inner = per_image(lips, cv2.erode)
    rim = lips & ~inner
    near_mouth = per_image(mouth, cv2.dilate)
    parts = (("interior", inner), ("rim", rim), ("rim_mouth", rim & near_mouth),
             ("rim_skin", rim & ~near_mouth))
    ours_se = ((ours - frames.truth / 255.0) ** 2).mean(-1)
    out = {}
    for name, mask in parts:
        for who, image, reference in (("ours_vs_ideal", ours, frames.truth),
                                      ("untouched_vs_unedited", before, plain.truth)):
            out[f"{name}_{who}"] = round(metrics.pooled_psnr(image, reference / 255.0, mask), 2)
        out[f"{name}_pixels"] = int(mask.sum())
        out[f"{name}_error_share"] = round(float(ours_se[mask].sum() / ours_se[lips].sum()), 3)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="benchmarks/results/ceiling")
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    bench = Bench(args.out + ".json")
    scene, original = default_scene_and_avatar()
    oracle = OracleEditor(scene, PROMPT)
    for name in args.variants:
        knobs = VARIANTS[name]
        start = split_region(original, "lips", 2) if name == "split_lips_twice" else original
        config = preset("fast", prompt=PROMPT, checkpoint_every=0, **knobs)
        extra = {}

        def measure(edited, start=start, config=config, extra=extra):
            session, _ = bench.setup(config, scene, start)
            extra.update(rim_and_interior(scene, edited, start, session.step_config.blend,
                                          session.rig.tile_capacity))

        bench.run(name, config, scene, start, editor=oracle, on_edited=measure, extra=extra)
    lines = ["# The oracle's ceiling on the lips", "",
             "PSNR dB; lips / teeth / whole: mean over the protocols against the ideal edit; "
             "interior / rim: novel view, ours against the ideal (the untouched avatar against "
             "the unedited truth in brackets).", "",
             "| variant | lips | teeth | whole | interior | rim | rim by the mouth (share of the "
             "lips' error) | rim by the skin | s |", "|---" * 9 + "|"]
    for name, r in bench.results.items():
        cells = [mean_over_protocols(r, "psnr", k) for k in ("edited", "teeth", "whole")]
        lines.append(f"| {name} | " + " | ".join(f"{c:.2f}" for c in cells) +
                     f" | {r.get('interior_ours_vs_ideal')} ({r.get('interior_untouched_vs_unedited')})"
                     f" | {r.get('rim_ours_vs_ideal')} ({r.get('rim_untouched_vs_unedited')})"
                     f" | {r.get('rim_mouth_ours_vs_ideal')} "
                     f"({r.get('rim_mouth_untouched_vs_unedited')}; "
                     f"{r.get('rim_mouth_error_share')})"
                     f" | {r.get('rim_skin_ours_vs_ideal')} "
                     f"({r.get('rim_skin_untouched_vs_unedited')})"
                     f" | {r['edit_seconds']:.0f} |")
    write_report(args.out + ".md", "\n".join(lines) + "\n")
    print(json.dumps({k: {m: v for m, v in r.items() if m.startswith(("interior", "rim"))}
                      for k, r in bench.results.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
