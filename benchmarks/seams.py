"""Whose Gaussians cover a preserved group's pixels, and in what colour: the seam behind a
preserved loss of the instruction suite.

    python benchmarks/seams.py [--prompt "make the skin light blue"]
                               [--protocol self_reenactment] [--group mouth]
                               [--out benchmarks/results/seams]

Reads the avatars `instructions.py` keeps (its seed-0 default and its oracle edit; run the suite
first). Over the protocol's frames, each Gaussian's blending weight summed over the pixels the
truth labels as the group (the VJP of the render against the group's mask, as the `auto`
region's tracing does) gives each region's share of those pixels, and the weighted mean colour
of the edited region's Gaussians there: for the untouched avatar, the default edit and the
oracle edit, beside the truth's mean colour of the group. Writes `<out>.json` and `<out>.md`
(one row per prompt, protocol and group: a rerun adds or replaces its row).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import jax.numpy as jnp
import numpy as np

from gae_jax.edit import region as edit_region
from gae_jax.evaluation import truth
from gae_jax.model import avatar_io, head
from gae_jax.run.bench import default_scene_and_avatar, write_report
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import posed_vertices, training_frames
from gae_jax.util.fileio import atomic_write_bytes

import instructions as suite  # the suite's avatars, a script beside this one

SHOWN = 0.01  # regions with less of the group's weight are left out of the shares


def group_weights(avatar, rig, frames, group_id: int) -> np.ndarray:
    """(N,) each Gaussian's blending weight summed over the frames' pixels labelled
    `group_id` by the truth."""
    trace = edit_region.make_tracer()
    weights = np.zeros(avatar.num)
    for p in range(len(frames.pairs)):
        for k, cam in enumerate(frames.cameras):
            mask = frames.regions[p, k] == group_id
            if mask.any():
                weights += np.asarray(trace(avatar.trainable(), rig, jnp.int32(cam),
                                            jnp.int32(p), jnp.asarray(mask, jnp.float32)))[:, 0]
    return weights


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--prompt", default="make the skin light blue")
    p.add_argument("--protocol", default="self_reenactment")
    p.add_argument("--group", default="mouth", choices=sorted(head.REGION_ID))
    p.add_argument("--out", default="benchmarks/results/seams")
    args = p.parse_args(argv)
    scene, original = default_scene_and_avatar("makehuman")
    evalset = truth.build(scene, args.prompt, frames=4)
    if args.protocol not in evalset.protocols:
        p.error(f"--protocol: one of {sorted(evalset.protocols)}")
    frames, _ = evalset.protocols[args.protocol]
    rig = rigs.with_vertices(rigs.put_rig(scene, original, posed_vertices(
        scene, training_frames(scene))), frames.vertices)
    group_id = head.REGION_ID[args.group]
    in_group = frames.regions == group_id
    row = dict(prompt=args.prompt, protocol=args.protocol, group=args.group,
               pixels=int(in_group.sum()),
               truth_colour=np.round(frames.truth[in_group].mean(0) / 255.0, 3).tolist())
    labels = np.asarray(original.regions)
    edited_id = head.REGION_ID[evalset.edited_region]
    names = {v: k for k, v in head.REGION_ID.items()}
    for who in ("untouched", "default", "oracle"):
        avatar = original
        if who != "untouched":
            path = suite.avatar_path(f"{who}/{args.prompt}", scene.width)
            if not os.path.isfile(path):
                p.error(f"{path}: missing, run benchmarks/instructions.py first")
            avatar = avatar_io.load_bound_avatar(path, scene.face_regions)
        w = group_weights(avatar, rig, frames, group_id)
        total = max(w.sum(), 1e-12)
        mine = labels == edited_id
        row[who] = dict(
            shares={names[r]: round(float(w[labels == r].sum() / total), 3)
                    for r in np.unique(labels) if w[labels == r].sum() > SHOWN * total},
            edited_region_colour=np.round((w[mine, None] * np.asarray(avatar.colors)[mine]).sum(0)
                                          / max(w[mine].sum(), 1e-12), 3).tolist())
    path = args.out + ".json"
    rows = []
    if os.path.isfile(path):
        with open(path) as f:
            rows = json.load(f)
    rows = [r for r in rows if (r["prompt"], r["protocol"], r["group"]) !=
            (args.prompt, args.protocol, args.group)] + [row]
    atomic_write_bytes(path, json.dumps(rows, indent=1).encode())
    lines = ["| instruction | protocol | group (pixels) | truth colour | shares of the group's "
             "weight (untouched) | edited region's colour there: untouched / default / oracle |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['prompt']} | {r['protocol']} | {r['group']} ({r['pixels']}) | "
                     f"{r['truth_colour']} | "
                     + ", ".join(f"{k} {v}" for k, v in r["untouched"]["shares"].items())
                     + " | " + " / ".join(str(r[w]["edited_region_colour"])
                                          for w in ("untouched", "default", "oracle")) + " |")
    write_report(args.out + ".md", "\n".join([
        "# Whose Gaussians cover a preserved group", "",
        "Command: `python benchmarks/seams.py --prompt PROMPT --protocol P --group G` (after "
        "`python benchmarks/instructions.py`). Per row: the truth's mean colour of the group's "
        "pixels over the protocol's frames; each region's share of the blending weight on those "
        "pixels (untouched avatar); the weighted mean colour of the edited region's Gaussians "
        "there in the untouched avatar, the default edit and the oracle edit.", ""] + lines)
        + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
