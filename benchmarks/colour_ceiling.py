"""What a colour-only edit can reach on a reconstruction, and whether density at the region's
edge raises it (an oracle study: it reads the ideal edit, so it lives here).

    python benchmarks/colour_ceiling.py [--variants ...] [--out benchmarks/results/colour_ceiling]

For each reconstruction variant, the lips' Gaussians are recoloured in closed form: each colour
times the ratio of the ideal albedo to the unedited one, averaged over its face's vertices (the
ideal edit recolours albedo and keeps shading, so this is what a perfect colour edit on this
geometry looks like). Scored like an edit (lips, teeth, whole image; mean over the three
protocols, against the ideal), beside the untouched avatar against the unedited truth.
Variants:
  * `it600`: the default reconstruction (600 steps), the avatar the edits start from;
  * `it1200`: twice the steps;
  * `per_face_2`: two Gaussians per face from the start, 600 steps;
  * `lips_x4`: four Gaussians per lips face, one elsewhere, 600 steps;
  * `continued_300`: `it600` fitted 300 more steps (the control of the next one);
  * `rim_split_300`: `it600` with every lips Gaussian on the region's outline (a face with an
    edge no other lips face shares) split in two, then fitted 300 more steps: densification at the region's boundary with the
    reconstruction's rates and the unedited images, the best case for densifying during an edit.
Writes `<out>.json` after each variant (a rerun skips recorded ones) and `<out>.md`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import jax
import numpy as np

from gae_jax.edit.config import preset
from gae_jax.evaluation import protocols, score, truth
from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.fit import fit, initial_avatar
from gae_jax.model import avatar as av, regions
from gae_jax.run.bench import fmt, write_report
from gae_jax.run.oracle import recoloured
from gae_jax.run.original import original_avatar
from gae_jax.scene import rig as rigs, synthetic
from gae_jax.scene.types import posed_vertices, training_frames
from gae_jax.util.fileio import atomic_write_bytes

PROMPT = "turn the lips blue"
REGION = "lips"
VARIANTS = ("it600", "it1200", "per_face_2", "lips_x4", "continued_300", "rim_split_300")


def region_faces(scene, name: str) -> np.ndarray:
    return regions.region_faces(scene.face_regions, name)


def rim_faces(scene, name: str) -> np.ndarray:
    return regions.rim_faces(scene.model.faces, scene.face_regions, name)


def denser_in_region(scene, config: ReconstructConfig, name: str, per_face: int, key):
    """The default initial avatar with `per_face` Gaussians on each face of region `name`."""
    one = initial_avatar(scene, config, key)
    many = initial_avatar(scene, dataclasses.replace(config, per_face=per_face), key)
    inside = region_faces(scene, name)
    keep_one = np.flatnonzero(~inside[np.asarray(one.binding)])
    keep_many = np.flatnonzero(inside[np.asarray(many.binding)])
    return av.concat(av.take(one, keep_one), av.take(many, keep_many))


def reconstruction(name: str, scene, base: av.Avatar):
    """(avatar, fit seconds or None for the cached default) of a variant."""
    steps = preset("fast").reconstruct_iterations
    config = ReconstructConfig(iterations=steps)
    start = time.perf_counter()
    if name == "it600":
        return base, None
    if name == "it1200":
        fitted, _ = fit(scene, dataclasses.replace(config, iterations=2 * steps))
    elif name == "per_face_2":
        fitted, _ = fit(scene, dataclasses.replace(config, per_face=2))
    elif name == "lips_x4":
        fitted, _ = fit(scene, config, initial=denser_in_region(
            scene, config, REGION, 4, jax.random.PRNGKey(0)))
    else:
        more = dataclasses.replace(config, iterations=steps // 2)
        initial = base
        if name == "rim_split_300":
            split = rim_faces(scene, REGION)[np.asarray(base.binding)]
            initial = av.densify(base, np.zeros(base.num, bool), split, jax.random.PRNGKey(0))
        fitted, _ = fit(scene, more, initial=initial)
    return fitted, round(time.perf_counter() - start, 1)


def mean_psnr(evaluation: dict, who: str, region: str) -> float:
    return round(float(np.mean([evaluation[p][who]["psnr"][region]
                                for p in protocols.PROTOCOLS])), 2)


def markdown(results: dict) -> str:
    lines = ["# The colour-only ceiling on the lips", "",
             "Lips recoloured in closed form (the ideal albedo's ratio) on each reconstruction; "
             "PSNR dB mean over the three protocols against the ideal edit, and the untouched "
             "avatar against the unedited truth. Command: `python benchmarks/colour_ceiling.py`.",
             "", "| reconstruction | Gaussians | fit s | lips, recoloured | teeth | whole | "
             "untouched lips (unedited truth) | untouched whole |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['gaussians']} | {r['fit_seconds'] or '-'} | "
                     f"{fmt(r['lips'])} | {fmt(r['teeth'])} | {fmt(r['whole'])} | "
                     f"{fmt(r['untouched_lips'])} | {fmt(r['untouched_whole'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--out", default="benchmarks/results/colour_ceiling")
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    path = args.out + ".json"
    results = json.load(open(path)) if os.path.isfile(path) else {}
    scene = synthetic.make_synthetic_scene(size=128, progress=False)
    base = original_avatar(scene, preset("fast").reconstruct_iterations, progress=False)
    edited_truth = truth.build(scene, PROMPT)
    # A style has no ideal, so its evaluation set holds the unedited truth; scored on the lips.
    unedited_truth = dataclasses.replace(truth.build(scene, "make it an oil painting"),
                                         edited_region=edited_truth.edited_region)
    for name in args.variants:
        if name in results:
            continue
        avatar, seconds = reconstruction(name, scene, base)
        capacity = rigs.put_rig(scene, avatar,
                                posed_vertices(scene, training_frames(scene))).tile_capacity
        ours = score.evaluate_avatars(edited_truth, recoloured(scene, avatar, PROMPT), avatar, capacity)
        plain = score.evaluate_avatars(unedited_truth, avatar, avatar, capacity)
        results[name] = dict(
            gaussians=int(avatar.num), fit_seconds=seconds, tile_capacity=capacity,
            lips=mean_psnr(ours, "ours", "edited"), teeth=mean_psnr(ours, "ours", "teeth"),
            whole=mean_psnr(ours, "ours", "whole"),
            lips_per_protocol=[ours[p]["ours"]["psnr"]["edited"] for p in protocols.PROTOCOLS],
            untouched_lips=mean_psnr(plain, "original_avatar", "edited"),
            untouched_whole=mean_psnr(plain, "original_avatar", "whole"))
        atomic_write_bytes(path, json.dumps(results, indent=1).encode())
        print(json.dumps(dict(variant=name, **results[name])), flush=True)
    write_report(args.out + ".md", markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
