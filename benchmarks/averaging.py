"""What releasing the average of the edit's iterates, and letting the rates decay further, are
worth against a noisy 2D editor.

    python benchmarks/averaging.py [--seed 0] [--out benchmarks/results/averaging]

The built-in editor at its default noise (0.3) errs from call to call: a colour a few percent
off, an outline a pixel wide or narrow, now and then half a region left unedited. The loop sees
one such edit per iteration, so its last iterate carries the last few calls' errors. Per
instruction (MakeHuman head, 128 px, 100 iterations, one seed) this runs the loop's schedules

  * `last, to 10 %`: the last iterate, rates decaying to a tenth (the loop before averaging);
  * `average, to 10 %`: the running average of the iterates (`--average-decay 0.9`);
  * `last, to 3 %`: the last iterate, rates decaying to 3 % (`--lr-final 0.03`);
  * `average, to 3 %`: both (the CLI's default);

each with the built-in editor (`default`) and with the ideal edit of every view (`oracle`:
what the schedule does when there is no noise to cancel), and the noise-free built-in editor
(`--editor-noise 0`) on the default schedule, the bound averaging reaches for. Scored as the
suite scores (`instructions.py`): edited region and worst preserved loss, mean of the three
protocols. Writes `<out>.json` (a rerun skips what is recorded) and `<out>.md`.
"""

from __future__ import annotations

import argparse
import sys

from gae_jax.edit.config import preset
from gae_jax.run.bench import Bench, default_scene_and_avatar, fmt, write_report
from gae_jax.run.oracle import OracleEditor

import instructions as suite  # the suite's scoring, a script beside this one

PROMPTS = ("turn the lips blue", "make the skin light blue", "make the hair blonde",
           "make the teeth black", "make the tongue light blue", "make the irises crimson")
SCHEDULES = {
    "last, to 10 %": dict(average_decay=0.0, lr_final=0.1),
    "average, to 10 %": dict(average_decay=0.9, lr_final=0.1),
    "last, to 3 %": dict(average_decay=0.0, lr_final=0.03),
    "average, to 3 % (default)": dict(average_decay=0.9, lr_final=0.03),
}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="benchmarks/results/averaging")
    args = p.parse_args(argv)
    bench = Bench(args.out + ".json")
    scene, original = default_scene_and_avatar("makehuman")
    rows = []
    for prompt in PROMPTS:
        bench.evalset(scene, prompt)
        cells = {}
        for name, schedule in SCHEDULES.items():
            config = preset("fast", prompt=prompt, checkpoint_every=0, seed=args.seed,
                            **schedule)
            for who in ("default", "oracle"):
                editor = OracleEditor(scene, prompt) if who == "oracle" else None
                record = bench.run(f"{who}/{name}/{prompt}", config, scene, original,
                                   editor=editor)
                cells[(who, name)] = suite.summary(record)
        config = preset("fast", prompt=prompt, checkpoint_every=0, seed=args.seed,
                        editor_noise=0.0)
        cells[("noise-free", "")] = suite.summary(bench.run(f"noise-free/{prompt}", config,
                                                            scene, original))
        rows.append((prompt, cells))
    bench.save(seed=args.seed)
    head = ["instruction", "who"] + list(SCHEDULES) + ["noise-free editor"]
    lines = ["| " + " | ".join(head) + " |", "|---" * len(head) + "|"]
    for prompt, cells in rows:
        for who in ("default", "oracle"):
            values = [f"{fmt(cells[(who, n)]['edited'])} ({fmt(cells[(who, n)]['worst_loss'])})"
                      for n in SCHEDULES]
            free = cells[("noise-free", "")]
            lines.append("| " + " | ".join(
                [prompt if who == "default" else "", who] + values
                + [f"{fmt(free['edited'])} ({fmt(free['worst_loss'])})" if who == "default"
                   else ""]) + " |")
    report = ["# Averaging the edit's iterates (128 px MakeHuman head, 100 iterations, seed "
              f"{args.seed})", "",
              "Command: `python benchmarks/averaging.py`. Edited region, PSNR dB against the "
              "ideal edit (mean of the three protocols), and in brackets the worst loss of a "
              "preserved group below the untouched avatar (any protocol).", "",
              "\n".join(lines)]
    write_report(args.out + ".md", "\n".join(report) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
