"""Why the default edit uses standard blending and L1 alone: blend x SSIM weight, for the built-in
editor (three seeds) and the oracle editor, on the default lips edit.

    python benchmarks/loss_blend.py [--iterations 100] [--out benchmarks/results/loss_blend]

Rows: blend standard / WABE on the gradient x ssim_weight 0 (L1) / 1 (the paper's L1 + SSIM),
each with the semantic editor (noise 0.3) at seeds 0, 1, 2 and with the oracle editor (the
ray-cast ideal 2D edit of every sampled view, `oracle.py`); and the oracle with no edit region
for both blends, where every Gaussian may move and the targets equal the training images outside
the lips: what each blend's gradient does to a head that is already right. Reported per row, mean
over the three protocols: PSNR against the ideal of the lips, teeth, rest and whole image.
Writes `<out>.json` (resumable) and `<out>.md`.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from gae_jax.edit.config import preset
from gae_jax.run.bench import (Bench, default_scene_and_avatar, fmt, mean_over_protocols,
                               write_report)
from gae_jax.run.oracle import OracleEditor

PROMPT = "turn the lips blue"
BLENDS = ("standard", "wabe_grad")
SSIM = (0.0, 1.0)
SEEDS = (0, 1, 2)
COLUMNS = ("edited", "teeth", "rest", "whole")


def rows() -> dict:
    """{row name: (EditConfig overrides, oracle?)}."""
    out = {}
    for blend in BLENDS:
        for w in SSIM:
            for seed in SEEDS:
                out[f"{blend}/ssim{w:g}/seed{seed}"] = (dict(blend=blend, ssim_weight=w,
                                                            seed=seed), False)
            out[f"{blend}/ssim{w:g}/oracle"] = (dict(blend=blend, ssim_weight=w), True)
        out[f"{blend}/ssim0/oracle/region_none"] = (dict(blend=blend, region="none"), True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--iterations", type=int, default=100)
    p.add_argument("--out", default="benchmarks/results/loss_blend")
    args = p.parse_args(argv)
    scene, original = default_scene_and_avatar()
    oracle = OracleEditor(scene, PROMPT)
    bench = Bench(args.out + ".json")
    scores = {}
    for name, (overrides, use_oracle) in rows().items():
        config = preset("fast", prompt=PROMPT, iterations=args.iterations, checkpoint_every=0,
                        **overrides)
        record = bench.run(name, config, scene, original, editor=oracle if use_oracle else None)
        scores[name] = [mean_over_protocols(record, "psnr", c) for c in COLUMNS]
    lines = ["# Blend x loss on the default lips edit", "",
             f"PSNR dB against the ideal, mean over the three protocols; {args.iterations} "
             "iterations; semantic editor noise 0.3 (mean and range over seeds 0-2) or the "
             "oracle editor. Command: `python benchmarks/loss_blend.py`.", "",
             "| blend | loss | editor | lips | teeth | rest | whole |", "|---" * 7 + "|"]
    for blend in BLENDS:
        for w in SSIM:
            loss = "L1" if w == 0 else "L1 + SSIM"
            seeds = np.array([scores[f"{blend}/ssim{w:g}/seed{s}"] for s in SEEDS], float)
            cells = [f"{m:.2f} ({lo:.2f}-{hi:.2f})" for m, lo, hi in
                     zip(seeds.mean(0), seeds.min(0), seeds.max(0))]
            lines.append(f"| {blend} | {loss} | semantic | " + " | ".join(cells) + " |")
            lines.append(f"| {blend} | {loss} | oracle | " + " | ".join(
                fmt(v) for v in scores[f"{blend}/ssim{w:g}/oracle"]) + " |")
        lines.append(f"| {blend} | L1 | oracle, no region | " + " | ".join(
            fmt(v) for v in scores[f"{blend}/ssim0/oracle/region_none"]) + " |")
    bench.save(iterations=args.iterations)
    write_report(args.out + ".md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
