"""The paper's Table 1 on our scene: methods x protocols, for occlusion and style edits.

    python benchmarks/ablation.py [--head makehuman] [--iterations 100]
                                  [--out benchmarks/results/ablation] [--clip-folder DIR]
                                  [--rows in2n wabe_grad ...]

On the 128 px scene of `--head` (the shipped MakeHuman head by default) and its default
reconstruction.

Rows (presets of `edit.config.PRESETS`, all at the same iteration count so time is comparable):
  in2n       Instruct-NeRF2NeRF: standard blending, no GAN, iterative dataset update, no region
  previous   the default before region-aware editing (no region, editor keeps the render, WABE on
             the gradient, L1 + SSIM, colour rate 1e-2, Adam eps 1e-4)
  no_region  the default without its edit region (every Gaussian may move)
  wabe_grad  ours with WABE on the gradient (the previous default)
  ssim       ours with the paper's L1 + SSIM (the previous default) instead of L1
  no_adv     ours without the adversarial loss
  paper      ours as the paper writes it: WABE in the forward pass, one lr 1e-2 for everything
  code       ours as the released code does it: gradient mask (front Gaussians, no mouth), pairs
  oracle     the default fed the ray-cast ideal edit of every sampled view (gae_jax/run/oracle.py):
             the ceiling of render-edit-aggregate with perfect 2D edits (semantic edits only)
  fast       ours (the default): the prompt's region, composited targets, standard blending, L1
Instructions: "turn the lips blue" (lips occlude the teeth), "give her red eyes" (eyelids occlude
the irises), "make it an oil painting" (style, OpenCV); the lips also at editor noise 0.7 (the eyes
too with --edits ... eyes_noisy). A style edit has no ideal 3D counterpart: its PSNR columns are
against the unedited truth (how much changed), its flicker is the temporal consistency. Scores
against the ideal edit (the ray-cast mesh with the edited albedo): PSNR of the edited region and
of the preserved regions, LPIPS and temporal flicker, per protocol; CLIP-S / CLIP-C with
--clip-folder. Writes `<out>.json` (every number) and `<out>.md` (tables); resumable.
"""

from __future__ import annotations

import argparse
import os
import sys

from gae_jax.edit.config import preset
from gae_jax.evaluation import protocols
from gae_jax.model import head
from gae_jax.run.bench import (Bench, default_scene_and_avatar, fmt, mean_over_protocols,
                               score_of as score, write_report)
from gae_jax.run.oracle import OracleEditor
from gae_jax.scene.types import training_frames

ROWS = ("in2n", "previous", "no_region", "wabe_grad", "ssim", "no_adv", "paper", "code", "oracle",
        "fast")
ORACLE_ROW = "oracle"
# IN2N replaces one dataset image per iteration: at 100 iterations it has edited 100 of the 1200
# training images. These rows give it one full pass over the dataset (lips only: ~8 minutes
# each): with the preset's rates (decaying to a tenth over 100 iterations, then constant) and
# with the decay stretched over the whole pass (so the last images are learned at full rate).
PASS_ROW = "in2n_pass"
SLOW_PASS_ROW = "in2n_pass_slow"
PASS_ROWS = (PASS_ROW, SLOW_PASS_ROW)
LABELS = {"in2n": "Instruct-NeRF2NeRF", "wabe_grad": "ours + WABE on the gradient",
          "ssim": "ours + SSIM (the paper's loss)",
          "no_adv": "ours w/o adversarial", "paper": "ours (paper: forward WABE)",
          "code": "ours (released code's mask)", "previous": "ours before regions (old default)",
          "no_region": "ours w/o edit region", "oracle": "oracle editor (ideal 2D edits)",
          "fast": "ours (default)",
          PASS_ROW: "Instruct-NeRF2NeRF, one dataset pass (1200 it.)",
          SLOW_PASS_ROW: "Instruct-NeRF2NeRF, one pass, rate decay over the pass"}
EDITS = (("lips", "turn the lips blue", "semantic", 0.3),
         ("lips_noisy", "turn the lips blue", "semantic", 0.7),
         ("eyes", "give her red eyes", "semantic", 0.3),
         ("eyes_noisy", "give her red eyes", "semantic", 0.7),
         ("oil", "make it an oil painting", "style", 0.0))
# The preserved region that lies behind (or in front of) the edit: where leakage shows.
GUARD = {"lips": "teeth", "eyes": "rest", "oil": "teeth"}


def variant_name(row: str, edit: str) -> str:
    return f"{row}/{edit}"


def table(results: dict, edit: str) -> str:
    guard = GUARD[edit.split("_")[0]]
    cols = []
    for p in protocols.PROTOCOLS:
        short = {"novel_view": "NV", "self_reenactment": "SR", "cross_identity": "CR"}[p]
        cols += [(p, "psnr", "edited", f"{short} edit"), (p, "psnr", guard, f"{short} {guard}"),
                 (p, "psnr", "whole", f"{short} whole")]
    head = ["method"] + [c[3] for c in cols] + ["LPIPS", "flicker", "CLIP-S", "CLIP-C", "s"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for row in ("original avatar",) + ROWS + PASS_ROWS:
        rec = results.get(variant_name(row if row != "original avatar" else ROWS[-1], edit))
        if rec is None or "evaluation" not in rec:
            if rec is not None:
                lines.append(f"| {LABELS.get(row, row)} | " + "non-finite |" * (len(head) - 1))
            continue
        who = "original_avatar" if row == "original avatar" else "ours"
        cells = [fmt(score(rec, p, m, r, who)) for p, m, r, _ in cols]
        cells.append(fmt(mean_over_protocols(rec, "lpips", "whole", who), 3))
        ev = rec["evaluation"]
        flick = [ev[p]["flicker"][who]["whole"] for p in protocols.PROTOCOLS]
        cells.append(fmt(sum(flick) / len(flick), 4))
        clips = [[ev[p].get(k) for p in protocols.PROTOCOLS] for k in ("clip_s", "clip_c")]
        cells += [fmt(sum(c) / len(c), 3) if who == "ours" and None not in c else "-"
                  for c in clips]
        cells.append("-" if who != "ours" else fmt(rec["edit_seconds"], 0))
        lines.append(f"| {LABELS.get(row, row)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary(results: dict, edits: list) -> str:
    """Rows methods, columns per edit: PSNR of the edited region / the guarded region / the whole
    image, each the mean over the three protocols (style edits: whole image and flicker)."""
    head = ["method"]
    for edit in edits:
        guard = GUARD[edit.split("_")[0]]
        head += ([f"{edit} flicker", f"{edit} whole vs unedited"] if edit == "oil" else
                 [f"{edit} edit", f"{edit} {guard}", f"{edit} whole"])
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for row in ("original avatar",) + ROWS + PASS_ROWS:
        who = "original_avatar" if row == "original avatar" else "ours"
        cells = []
        for edit in edits:
            rec = results.get(variant_name(row if row != "original avatar" else ROWS[-1], edit),
                              {})
            if edit == "oil":
                ev = rec.get("evaluation")
                flick = (sum(ev[p]["flicker"][who]["whole"] for p in protocols.PROTOCOLS) / 3
                         if ev else None)
                cells += [fmt(flick, 4), fmt(mean_over_protocols(rec, "psnr", "whole", who))]
            else:
                guard = GUARD[edit.split("_")[0]]
                cells += [fmt(mean_over_protocols(rec, "psnr", r, who))
                          for r in ("edited", guard, "whole")]
        lines.append(f"| {LABELS.get(row, row)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--head", choices=head.HEAD_KINDS, default=head.DEFAULT_KIND)
    p.add_argument("--iterations", type=int, default=100)
    p.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    p.add_argument("--edits", nargs="+", default=[e[0] for e in EDITS if e[0] != "eyes_noisy"],
                   choices=[e[0] for e in EDITS])
    p.add_argument("--pass-edits", nargs="*", default=["lips"], choices=[e[0] for e in EDITS],
                   help="edits that also get the in2n row with one full dataset pass")
    p.add_argument("--clip-folder", default="")
    p.add_argument("--out", default="benchmarks/results/ablation")
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    bench = Bench(args.out + ".json", clip_folder=args.clip_folder)
    scene, original = default_scene_and_avatar(args.head)
    for row in args.rows:  # one row's edits share a compiled step
        for edit, prompt, editor, noise in EDITS:
            if edit not in args.edits:
                continue
            oracle = None
            if row == ORACLE_ROW:
                if editor != "semantic":
                    continue
                oracle = OracleEditor(scene, prompt)
            config = preset("fast" if row == ORACLE_ROW else row, iterations=args.iterations,
                            prompt=prompt, editor=editor, editor_noise=noise,
                            checkpoint_every=0)
            bench.run(variant_name(row, edit), config, scene, original,
                      extra=dict(row=row, edit=edit), editor=oracle)
    if args.pass_edits:
        images = len(scene.train_cameras) * len(training_frames(scene))
        for edit, prompt, editor, noise in EDITS:
            if edit in args.pass_edits:
                for row, decay in ((PASS_ROW, {}), (SLOW_PASS_ROW, dict(lr_decay_steps=images))):
                    config = preset("in2n", iterations=images, prompt=prompt, editor=editor,
                                    editor_noise=noise, checkpoint_every=0, **decay)
                    bench.run(variant_name(row, edit), config, scene, original,
                              extra=dict(row=row, edit=edit))
    bench.save(iterations=args.iterations, head=args.head)
    sections = [f"# Ablation ({args.iterations} edit iterations, 128 px scene, {args.head} "
                f"head)\n", f"Command: `python benchmarks/ablation.py --head {args.head}`.\n",
                "NV novel view, SR self-reenactment, CR cross-identity; PSNR (dB) against the "
                "ideal edit; LPIPS and flicker averaged over the protocols; s = edit seconds "
                "(incl. compilation when a row's step is new).\n"]
    sections.append("## Summary: PSNR dB against the ideal edit, mean over the three protocols\n\n"
                    + summary(bench.results, args.edits) + "\n")
    for edit, prompt, _, noise in EDITS:
        if edit in args.edits:
            sections.append(f"## {prompt!r} (editor noise {noise})\n\n"
                            + table(bench.results, edit) + "\n")
    write_report(args.out + ".md", "\n".join(sections))
    return 0


if __name__ == "__main__":
    sys.exit(main())
