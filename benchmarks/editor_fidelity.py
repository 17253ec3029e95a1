"""How far the built-in editor's targets are from a perfect editor's, where in the region.

    python benchmarks/editor_fidelity.py [--only PROMPT ...] [--views 12]
                                         [--out benchmarks/results/editor_fidelity]

For every colour instruction of the suite (`instructions.py`, with its `EXTRA`), the loop's
composited 2D targets of the built-in editor -- noise-free, and at the CLI's noise with one key
per view -- are compared with the oracle's (the ideal edit of the same view: an oracle probe,
never a method) on the training views the loop draws from, rendered from the unedited avatar:
PSNR dB over the region's interior (labels whose 3 x 3 neighbourhood is the region), its outline
(the region's other pixels: a mix of the region and its neighbour), and the ring up to 2 px
outside it, with the outline's share of the squared error over the three. An editor whose
target is off where the loop reads it leaves the default short of the oracle whatever the loop
does. Writes `<out>.json` and `<out>.md`.
"""

from __future__ import annotations

import argparse
import json
import sys

import cv2
import jax
import numpy as np

from gae_jax import instructions as words
from gae_jax.edit import edit
from gae_jax.edit.config import preset
from gae_jax.model import head
from gae_jax.run.bench import default_scene_and_avatar, write_report
from gae_jax.run.oracle import OracleEditor
from gae_jax.util.fileio import atomic_write_bytes

import instructions as suite  # the suite's instructions, a script beside this one

PARTS = ("interior", "outline", "ring")
EXACT = 99.0  # dB shown for targets equal to 8 bits


def views(sampler, scene, count: int) -> list:
    """`count` (camera, frame row) training views spread over those the loop draws from: the
    views showing the region (`sampler.showing`) or every camera and frame."""
    if sampler.showing is not None:
        pool = [(int(c), int(r)) for c, r in sampler.showing]
    else:
        pool = [(int(c), r) for r in range(len(sampler.pairs)) for c in scene.train_cameras]
    pick = np.linspace(0, len(pool) - 1, min(count, len(pool))).round().astype(int)
    return [pool[i] for i in pick]


def parts(labels: np.ndarray, region_id: int) -> dict:
    """(H, W) bool masks of the region's interior, outline and the ring 2 px outside it."""
    region = (labels == region_id).astype(np.uint8)
    interior = cv2.erode(region, np.ones((3, 3), np.uint8)).astype(bool)
    ring = cv2.dilate(region, np.ones((5, 5), np.uint8)).astype(bool) & ~region.astype(bool)
    return dict(interior=interior, outline=region.astype(bool) & ~interior, ring=ring)


def fidelity(scene, original, prompt: str, count: int) -> dict:
    """{editor: {part: (squared error sum, pixels)}} of the noise-free and the default-noise
    built-in targets against the oracle's on `count` training views."""
    instruction = words.parse(prompt)
    region_id = head.REGION_ID[instruction.region]
    oracle = None
    out = {}
    for name, noise in (("noise-free", 0.0), ("default noise", preset("fast").editor_noise)):
        setup = edit.setup(preset("fast", prompt=prompt, checkpoint_every=0,
                                  editor_noise=noise), scene, original)
        builtin = edit.make_sampler(setup)
        if oracle is None:
            oracle = edit.make_sampler(setup, OracleEditor(scene, prompt))
        params = setup.original.trainable()
        sums = {k: [0.0, 0] for k in PARTS}
        for n, (cam, row) in enumerate(views(builtin, scene, count)):
            key = jax.random.fold_in(jax.random.PRNGKey(0), n)
            ours = builtin.edit(params, cam, row, key).astype(np.float64) / 255.0
            ideal = oracle.edit(params, cam, row, key).astype(np.float64) / 255.0
            error = ((ours - ideal) ** 2).sum(-1)
            for k, m in parts(builtin.labels(cam, row), region_id).items():
                sums[k][0] += float(error[m].sum())
                sums[k][1] += int(m.sum())
        out[name] = sums
    return out


def psnr(se: float, pixels: int) -> float | None:
    """PSNR dB of a squared-error sum over `pixels` RGB pixels in [0, 1], at most `EXACT`."""
    if pixels == 0:
        return None
    return round(min(EXACT, 10 * np.log10(3 * pixels / max(se, 1e-12))), 2)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="+", default=None, help="prompts (default: every colour "
                   "instruction of the suite and its extras)")
    p.add_argument("--views", type=int, default=12)
    p.add_argument("--out", default="benchmarks/results/editor_fidelity")
    args = p.parse_args(argv)
    prompts = [q for q, _ in suite.SUITE] + list(suite.EXTRA)
    if args.only:
        unknown = [q for q in args.only if q not in prompts]
        if unknown:
            p.error(f"--only: not a colour instruction of the suite: {unknown}")
        prompts = [q for q in prompts if q in args.only]
    scene, original = default_scene_and_avatar("makehuman")
    rows = []
    for prompt in prompts:
        sums = fidelity(scene, original, prompt, args.views)
        row = dict(prompt=prompt)
        for name, parts_ in sums.items():
            total = sum(se for se, _ in parts_.values())
            row[name] = dict({k: psnr(*v) for k, v in parts_.items()},
                             outline_share=round(parts_["outline"][0] / max(total, 1e-12), 2),
                             pixels={k: v[1] for k, v in parts_.items()})
        rows.append(row)
        print(json.dumps(row), flush=True)
    atomic_write_bytes(args.out + ".json", json.dumps(dict(views=args.views, rows=rows),
                                                      indent=1).encode())

    def cell(v):
        return "-" if v is None else f"{v:.2f}"

    lines = ["| instruction | pixels: interior / outline / ring | interior | outline | 2-px ring "
             "| outline's share | interior (default noise) | outline (default noise) | ring "
             "(default noise) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        a, b = r["noise-free"], r["default noise"]
        count = " / ".join(str(a["pixels"][k]) for k in PARTS)
        lines.append(f"| {r['prompt']} | {count} | {cell(a['interior'])} | "
                     f"{cell(a['outline'])} | {cell(a['ring'])} | {a['outline_share']:.2f} | "
                     f"{cell(b['interior'])} | {cell(b['outline'])} | {cell(b['ring'])} |")
    command = "python benchmarks/editor_fidelity.py" + (
        f" --views {args.views}" if args.views != 12 else "")
    write_report(args.out + ".md", "\n".join([
        "# The built-in editor's targets against a perfect editor's (128 px MakeHuman head)", "",
        f"Command: `{command}`. PSNR dB of the loop's composited 2D target against the oracle's "
        f"(the ideal edit of the same view) over {args.views} training views the loop draws "
        "from, rendered from the unedited avatar: the region's interior, its outline (pixels "
        "mixing the region and a neighbour) and the ring up to 2 px outside it; the outline's "
        "share of the squared error over the three (noise-free editor); then the same at the "
        "CLI's editor noise, one key per view.", ""] + lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
