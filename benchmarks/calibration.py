"""What bringing every 2D edit to the run's consensus colour is worth against a noisy editor.

    python benchmarks/calibration.py [--seeds 0 1 2] [--out benchmarks/results/calibration]

The built-in editor at its default noise (0.3) answers each call in its own shade (a colour a
few percent off, a tone change): the loop sees one edit per iteration, so what it learns
carries the last calls' shades. `--edit-calibration true` (the default) moves each call's edit to
the per-channel median colour of the run's calls so far (`gae_jax.edit.calibration`). Per
instruction (MakeHuman head, 128 px, 100 iterations, every region the head has, light and dark
colours; stripes are not calibrated) this runs the CLI's defaults with and without it over the same seeds, and the
oracle loop (the ideal edit of every view: no shade to correct) with and without it, scored as
the suite scores (`instructions.py`): edited region and worst preserved loss, mean of the three
protocols. Writes `<out>.json` (a rerun skips what is recorded), `<out>.md` and `<out>.png`.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from gae_jax.edit.config import preset
from gae_jax.run.bench import (Bench, default_scene_and_avatar, fmt, paired_change, save_figure,
                               write_report)
from gae_jax.run.oracle import OracleEditor

import instructions as suite  # the suite's scoring, a script beside this one

PROMPTS = ("turn the lips blue", "turn the lips navy blue", "make the skin light blue",
           "make the skin pale", "make the hair blonde", "make the hair black",
           "make the eyebrows white", "make the whites of the eyes yellow",
           "make the eyebrows black", "make the irises crimson", "make the teeth black",
           "make the tongue light blue")
ARMS = {"calibrated": True, "uncalibrated": False}


def chart(rows, seeds, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 4.8))
    x = np.arange(len(rows))
    changes = [r["changes"] for r in rows]
    mean = np.array([np.mean(c) for c in changes])
    ax.bar(x, mean, 0.55, color=np.where(mean >= 0, "tab:blue", "tab:red"),
           label=f"default loop, mean over seeds {', '.join(map(str, seeds))}")
    for i, c in enumerate(changes):
        ax.plot([i] * len(c), c, "k.", ms=5, label="one seed" if i == 0 else None)
    ax.plot(x, [r["oracle_change"] for r in rows], "gx", ms=8, mew=2,
            label="oracle loop (seed 0)")
    ax.axhline(0, color="k", lw=0.8)
    ax.set_ylabel("edited region: calibrated - uncalibrated, dB")
    ax.set_xticks(x, [r["prompt"] for r in rows], rotation=40, ha="right", fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Each 2D edit brought to the calls' consensus colour (128 px, 100 iterations)",
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--out", default="benchmarks/results/calibration")
    args = p.parse_args(argv)
    bench = Bench(args.out + ".json")
    scene, original = default_scene_and_avatar("makehuman")
    rows = []
    for prompt in PROMPTS:
        bench.evalset(scene, prompt)
        got = {}
        for arm, on in ARMS.items():
            for s in args.seeds:
                config = preset("fast", prompt=prompt, checkpoint_every=0, seed=s,
                                edit_calibration=on)
                got[(arm, s)] = suite.summary(bench.run(f"{arm}/{prompt}/seed{s}", config,
                                                        scene, original))
            config = preset("fast", prompt=prompt, checkpoint_every=0, edit_calibration=on)
            got[(arm, "oracle")] = suite.summary(bench.run(
                f"oracle {arm}/{prompt}", config, scene, original,
                editor=OracleEditor(scene, prompt)))
        on = [got[("calibrated", s)]["edited"] for s in args.seeds]
        off = [got[("uncalibrated", s)]["edited"] for s in args.seeds]
        changes, spread = paired_change(on, off)
        rows.append(dict(
            prompt=prompt, on=on, off=off, changes=changes, spread=spread,
            oracle=got[("calibrated", "oracle")]["edited"],
            oracle_change=(got[("calibrated", "oracle")]["edited"]
                           - got[("uncalibrated", "oracle")]["edited"]),
            worst_on=max(got[("calibrated", s)]["worst_loss"] for s in args.seeds),
            worst_off=max(got[("uncalibrated", s)]["worst_loss"] for s in args.seeds)))
    bench.save(seeds=args.seeds)
    lines = ["| instruction | calibrated (seeds) | uncalibrated (seeds) | change per seed | "
             "mean change | seed spread | oracle (calibrated) | oracle change | "
             "calibrated - oracle | uncalibrated - oracle | worst preserved loss on / off |",
             "|---" * 11 + "|"]
    for r in rows:
        lines.append(
            f"| {r['prompt']} | {np.mean(r['on']):.2f} ({min(r['on']):.2f}-{max(r['on']):.2f}) "
            f"| {np.mean(r['off']):.2f} ({min(r['off']):.2f}-{max(r['off']):.2f}) | "
            f"{', '.join(f'{c:+.2f}' for c in r['changes'])} | {np.mean(r['changes']):+.2f} | "
            f"{r['spread']:.2f} | {fmt(r['oracle'])} | {r['oracle_change']:+.2f} | "
            f"{np.mean(r['on']) - r['oracle']:+.2f} | {np.mean(r['off']) - r['oracle']:+.2f} | "
            f"{fmt(r['worst_on'])} / {fmt(r['worst_off'])} |")
    command = "python benchmarks/calibration.py" + (
        f" --seeds {' '.join(map(str, args.seeds))}" if args.seeds != [0, 1, 2] else "")
    write_report(args.out + ".md", "\n".join([
        "# Each 2D edit brought to the calls' consensus colour (128 px MakeHuman head, 100 "
        "iterations)", "",
        f"Command: `{command}`. Edited region, PSNR dB against the ideal edit (mean of the "
        "three protocols), the CLI's defaults with `--edit-calibration` on and off over the "
        "same seeds (paired: the same keys, the same editor calls until the targets differ); "
        "the oracle loop with it on and off (seed 0); the worst loss of a preserved group "
        "below the untouched avatar (any protocol, any seed). Chart: "
        f"`{args.out.split('/')[-1]}.png`.", "", "\n".join(lines)]) + "\n")
    chart(rows, args.seeds, args.out + ".png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
