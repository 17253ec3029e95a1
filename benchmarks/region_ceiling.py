"""Region-consistent reconstruction: the colour-only ceiling of every region before and after
the reconstruction learns where regions end (an oracle study: it reads the ideal edit).

    python benchmarks/region_ceiling.py [--weights 0 0.05 0.1 0.2] [--centre 0.1]
                                        [--unseen 0.1 0.3 1.0]
                                        [--variant per_face=2 --variant densify_every=100]
                                        [--seeds 0 1 2] [--size 128]
                                        [--out benchmarks/results/region_ceiling]

For each region-loss weight (`ReconstructConfig.region_weight`; 0 is colour alone), and for the
weights of `--centre` with each pixel supervised by its centre label alone instead of its rays'
(`label_samples` false), the default 600-step reconstruction of the MakeHuman head is fitted
(and cached as the train job caches it), and for the weights of `--unseen` the default region
weight 0.1 with the region loss also in views no camera took (`unseen_weight`; the other
variants fit none), and for each `--variant` the default reconstruction (weight 0.1, unseen
0.1) with other `ReconstructConfig` settings; each at every reconstruction seed of `--seeds`
(default 0 alone: one fit's seams move by up to a dB with its seed), then scored:
  * the reconstruction itself against the unedited truth (mean over the three protocols: whole
    image and each region), which must stay within 0.2 dB of colour alone;
  * for every colour instruction of the suite (`instructions.SUITE`), the region's Gaussians
    recoloured in closed form (`oracle.recoloured`): the edited region's PSNR against the ideal
    edit and the worst loss of a preserved group below the untouched avatar (a perfect colour
    edit that still paints the neighbours' pixels shows here).
Writes `<out>.json` (a rerun skips recorded weights) and `<out>.md`, whose last table gives
each variant fitted at two seeds or more as its mean over them, beside its seeds' range.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np
from instructions import SUITE, summary

from gae_jax.edit.config import preset
from gae_jax.evaluation import metrics, score, truth
from gae_jax.fit.config import ReconstructConfig
from gae_jax.model import head
from gae_jax.run.bench import fmt, write_report
from gae_jax.run.oracle import recoloured
from gae_jax.run.original import original_avatar
from gae_jax.scene import rig as rigs, synthetic
from gae_jax.scene.types import posed_vertices, training_frames
from gae_jax.util.fileio import atomic_write_bytes

PRESERVED_LOSS_TARGET = 0.3  # dB: a ceiling is clean when no preserved group loses more
STYLE = "make it an oil painting"  # no ideal: its evaluation set holds the unedited truth
# What --variant may set: the study fixes the iteration count.
RECONSTRUCT_FIELDS = {f.name for f in dataclasses.fields(ReconstructConfig)} - {"iterations"}


def reconstruction_scores(unedited, avatar, capacity) -> dict:
    """The avatar against the unedited truth: whole image and each region, PSNR with squared
    errors pooled over each protocol's frames, then the mean over the protocols."""
    render = rigs.make_view_renderer()
    per = {}
    for name, (frames, _) in unedited.protocols.items():
        ours = score.render_frames(render, avatar, unedited, frames, capacity)
        per[name] = {"whole": metrics.pooled_psnr(ours, frames.truth / 255.0)}
        for region in head.REGIONS:
            per[name][region] = metrics.pooled_psnr(
                ours, frames.truth / 255.0, frames.regions == head.REGION_ID[region])
    out = {}
    for key in ("whole",) + head.REGIONS:
        values = [v[key] for v in per.values() if v[key] is not None]
        out[key] = round(float(np.mean(values)), 3) if values else None
    return out


def variant_name(weight: float, centre: bool, unseen: float = 0.0, settings=()) -> str:
    return (f"{weight}" + (" centre" if centre else "") + (f" unseen {unseen}" if unseen else "")
            + "".join(f" {k}={v}" for k, v in settings))


def seed_of(name: str) -> tuple[str, int]:
    """(the variant's name without its seed, the reconstruction seed): "0.1 unseen 0.1 seed=2"
    -> ("0.1 unseen 0.1", 2); a name without a seed is seed 0's (the default job's)."""
    words = name.split()
    seeds = [w for w in words if w.startswith("seed=")]
    base = " ".join(w for w in words if not w.startswith("seed="))
    return base, int(seeds[0].split("=")[1]) if seeds else 0


def seed_means(results: dict, prompts) -> str:
    """A Markdown table of every variant recorded at two seeds or more: per row its mean over
    the seeds and their range (the reconstruction's whole image; each ceiling's edited region
    and worst preserved loss), and how many ceilings are clean at each seed. Empty without
    such a variant."""
    groups: dict = {}
    for name in results:
        base, seed = seed_of(name)
        groups.setdefault(base, {})[seed] = results[name]
    groups = {b: dict(sorted(g.items())) for b, g in groups.items() if len(g) >= 2}
    if not groups:
        return ""
    bases = sorted(groups, key=lambda b: (float(b.split()[0]), b))

    def cell(values, digits=2):
        values = [v for v in values if v is not None]
        if not values:
            return "-"
        return (f"{fmt(float(np.mean(values)), digits)} ({fmt(min(values), digits)}.."
                f"{fmt(max(values), digits)})")

    lines = ["## Mean over reconstruction seeds", "",
             "Variants fitted at two seeds or more (`--seeds`): mean over the seeds (their "
             "range). Read a variant's change against the default's seed range: one fit's "
             "seams move with its seed.", "",
             "| | " + " | ".join(f"{b} (seeds {', '.join(map(str, groups[b]))})"
                                 for b in bases) + " |",
             "|---" * (len(bases) + 1) + "|",
             "| reconstruction, whole | " + " | ".join(
                 cell([r["reconstruction"].get("whole") for r in groups[b].values()])
                 for b in bases) + " |",
             f"| clean ceilings (worst <= {PRESERVED_LOSS_TARGET}), per seed | " + " | ".join(
                 " / ".join(str(sum(c["worst_loss"] <= PRESERVED_LOSS_TARGET
                                    for c in r["ceilings"].values()))
                            for r in groups[b].values()) for b in bases) + " |"]
    for prompt in prompts:
        rows = {b: [r["ceilings"].get(prompt) for r in groups[b].values()] for b in bases}
        lines.append(f"| ceiling: {prompt} | " + " | ".join(
            f"{cell([c['edited'] for c in rows[b] if c])}, worst "
            f"{cell([c['worst_loss'] for c in rows[b] if c])}" for b in bases) + " |")
    return "\n".join(lines) + "\n"


def parse_settings(text: str) -> tuple:
    """"per_face=2,densify_every=100" -> (("per_face", 2), ("densify_every", 100))."""
    settings = []
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep or key.strip() not in RECONSTRUCT_FIELDS:
            raise argparse.ArgumentTypeError(
                f"{item!r}: expected NAME=VALUE with NAME a ReconstructConfig field")
        try:
            settings.append((key.strip(), json.loads(value)))
        except json.JSONDecodeError:
            raise argparse.ArgumentTypeError(f"{item!r}: the value is not a number or bool")
    return tuple(settings)


def command_flags(results: dict) -> str:
    """The flags that fit every recorded variant: a `--variant` for each one built on the
    default reconstruction (its settings, a seed included), and `--seeds` for the seeds the
    others were fitted at (the flag fits every variant at those, a superset)."""
    default = variant_name(0.1, False, 0.1) + " "
    flags = "".join(" --variant " + ",".join(w[len(default):].split())
                    for w in sorted(results) if w.startswith(default) and "=" in w)
    seeds = sorted({seed_of(w)[1] for w in results if not w.startswith(default)})
    return flags + (f" --seeds {' '.join(map(str, seeds))}" if seeds not in ([], [0]) else "")


def markdown(results: dict, prompts) -> str:
    weights = sorted(results, key=lambda w: (float(w.split()[0]), w))
    extra = command_flags(results)
    lines = ["# Region-consistent reconstruction: the colour-only ceiling per region", "",
             f"Command: `python benchmarks/region_ceiling.py{extra}`. The default reconstruction "
             "(600 steps, 128 px MakeHuman head) at each region-loss weight; PSNR dB, mean over "
             "the three protocols. Reconstruction: the untouched avatar against the unedited "
             "truth. Ceiling: the region's Gaussians recoloured in closed form, against the "
             "ideal edit; worst loss: the largest drop of a preserved group below the "
             "untouched avatar, in any protocol. \"centre\": the region loss reads each "
             "pixel's centre label alone instead of its 2 x 2 rays' labels. \"unseen W\": "
             "the same loss also in views no camera took, at weight W (the default "
             "reconstruction is weight 0.1 unseen 0.1; the other columns fit no such views). "
             "NAME=VALUE: the default reconstruction with that `ReconstructConfig` setting "
             "changed (`--variant`).",
             "",
             "| | " + " | ".join(f"weight {w}" for w in weights) + " |",
             "|---" * (len(weights) + 1) + "|"]
    lines.append("| Gaussians | " + " | ".join(str(results[w]["gaussians"]) for w in weights)
                 + " |")
    for region in ("whole",) + head.REGIONS:
        lines.append(f"| reconstruction, {region} | " + " | ".join(
            fmt(results[w]["reconstruction"].get(region)) for w in weights) + " |")
    for prompt in prompts:
        cells = []
        for w in weights:
            c = results[w]["ceilings"].get(prompt)
            cells.append("-" if c is None else
                         f"{fmt(c['edited'])} (worst {fmt(c['worst_loss'])})")
        lines.append(f"| ceiling: {prompt} | " + " | ".join(cells) + " |")
    means = seed_means(results, prompts)
    return "\n".join(lines) + "\n" + ("\n" + means if means else "")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", type=float, nargs="*", default=[0.0, 0.05, 0.1, 0.2])
    p.add_argument("--centre", type=float, nargs="*", default=[0.1],
                   help="weights also fitted on each pixel's centre label alone")
    p.add_argument("--unseen", type=float, nargs="*", default=[0.1, 0.3, 1.0],
                   help="unseen-view label weights also fitted at region weight 0.1")
    p.add_argument("--variant", type=parse_settings, action="append", default=[],
                   help="NAME=VALUE[,NAME=VALUE]: the default reconstruction with other "
                        "ReconstructConfig settings (repeatable)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0],
                   help="reconstruction seeds each variant is fitted at (0: the default "
                        "job's); the report gives each variant's mean over them")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--out", default="benchmarks/results/region_ceiling")
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    path = args.out + ".json"
    results = json.load(open(path)) if os.path.isfile(path) else {}
    scene = synthetic.make_synthetic_scene(size=args.size, progress=True, head_kind="makehuman")
    prompts = [q for q, kind in SUITE]
    unedited = truth.build(scene, STYLE)
    evalsets = {q: truth.build(scene, q) for q in prompts}
    iterations = preset("fast").reconstruct_iterations
    variants = ([(w, False, 0.0, ()) for w in args.weights]
                + [(w, True, 0.0, ()) for w in args.centre]
                + [(0.1, False, u, ()) for u in args.unseen]
                + [(0.1, False, 0.1, v) for v in args.variant])
    variants = [(w, centre, unseen, settings + ((("seed", s),) if s else ()))
                for w, centre, unseen, settings in variants
                for s in (args.seeds if "seed" not in dict(settings) else [0])]
    for w, centre, unseen, settings in variants:
        name = variant_name(w, centre, unseen, settings)
        if name in results:
            continue
        start = time.perf_counter()
        avatar = original_avatar(scene, iterations, progress=True, **{
            "region_weight": w, "label_samples": not centre, "unseen_weight": unseen,
            **dict(settings)})
        seconds = time.perf_counter() - start
        capacity = rigs.put_rig(scene, avatar,
                                posed_vertices(scene, training_frames(scene))).tile_capacity
        ceilings = {}
        for q in prompts:
            ev = score.evaluate_avatars(evalsets[q], recoloured(scene, avatar, q), avatar,
                                        capacity)
            s = summary(dict(evaluation=ev))
            ceilings[q] = dict(edited=s["edited"], worst_loss=s["worst_loss"],
                               worst_at=s["worst_at"])
        results[name] = dict(fit_seconds=round(seconds, 1), tile_capacity=capacity,
                               gaussians=int(avatar.num),
                               reconstruction=reconstruction_scores(unedited, avatar, capacity),
                               ceilings=ceilings)
        atomic_write_bytes(path, json.dumps(results, indent=1).encode())
        print(json.dumps(dict(variant=name, reconstruction=results[name]["reconstruction"])),
              flush=True)
    write_report(args.out + ".md", markdown(results, prompts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
