"""How much of a region's edit is held back by Gaussians the loop barely moved (an oracle probe).

    python benchmarks/lagging.py [--prompts PROMPT ...] [--out benchmarks/results/lagging]

Reads the avatars `instructions.py` keeps (its seed-0 default and its oracle edit per
instruction; run the suite first). Per edited avatar, each of the region's Gaussians' colour
move is compared with the move the colour-only ceiling makes (`oracle.recoloured`: the ideal
albedo's ratio): the share it has made. Then the Gaussians below a share (0.1, 0.5) are given
the ceiling's colour and the avatar is scored again. This reads the ideal, so it is a probe of
where a loss sits, never a method: a large gain means the loop stopped before rarely seen
Gaussians arrived.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import jax.numpy as jnp
import numpy as np

from gae_jax.evaluation import score, truth
from gae_jax.model import avatar_io, head
from gae_jax.run.bench import default_scene_and_avatar, fmt, write_report
from gae_jax.run.oracle import recoloured
from gae_jax.scene import rig as rigs
from gae_jax.scene.types import posed_vertices, training_frames
from gae_jax.util.fileio import atomic_write_bytes

import instructions as suite  # the suite's avatars and scoring, a script beside this one

PROMPTS = ("make the teeth black", "make the teeth yellow", "turn the lips blue",
           "make the tongue light blue")
SHARES = (0.1, 0.5)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--prompts", nargs="+", default=list(PROMPTS))
    p.add_argument("--out", default="benchmarks/results/lagging")
    args = p.parse_args(argv)
    scene, original = default_scene_and_avatar("makehuman")
    capacity = rigs.put_rig(scene, original,
                            posed_vertices(scene, training_frames(scene))).tile_capacity
    records, lines = [], ["| instruction | who | region Gaussians | share moved (10/25/50 %) | "
                          "as edited | " + " | ".join(f"below {s}: count, dB" for s in SHARES)
                          + " |", "|---" * (5 + len(SHARES)) + "|"]
    for prompt in args.prompts:
        evalset = truth.build(scene, prompt, frames=4)
        ceiling = recoloured(scene, original, prompt)
        region = np.asarray(original.regions) == head.REGION_ID[evalset.edited_region]
        for who in ("default", "oracle"):
            path = suite.avatar_path(f"{who}/{prompt}", scene.width)
            if not os.path.isfile(path):
                print(f"{path}: missing, run benchmarks/instructions.py first", file=sys.stderr)
                continue
            edited = avatar_io.load_bound_avatar(path, scene.face_regions)
            moved = np.abs(np.asarray(edited.colors) - np.asarray(original.colors)).max(-1)
            needed = np.abs(np.asarray(ceiling.colors) - np.asarray(original.colors)).max(-1)
            share = moved / np.maximum(needed, 1e-3)

            def edited_db(avatar):
                return suite.summary(dict(evaluation=score.evaluate_avatars(
                    evalset, avatar, original, capacity)))["edited"]

            row = dict(prompt=prompt, who=who, gaussians=int(region.sum()),
                       share_quantiles=[round(float(q), 2) for q in
                                        np.quantile(share[region], [0.1, 0.25, 0.5])],
                       as_edited=edited_db(edited), below={})
            for limit in SHARES:
                lagging = region & (share < limit)
                colors = np.where(lagging[:, None], np.asarray(ceiling.colors),
                                  np.asarray(edited.colors))
                probe = edited.with_params(dict(edited.trainable(), colors=jnp.asarray(colors)))
                row["below"][str(limit)] = dict(count=int(lagging.sum()), edited=edited_db(probe))
            records.append(row)
            lines.append("| " + " | ".join(
                [prompt, who, str(row["gaussians"]), " / ".join(map(str, row["share_quantiles"])),
                 fmt(row["as_edited"])] + [f"{row['below'][str(s)]['count']}, "
                                           f"{fmt(row['below'][str(s)]['edited'])}"
                                           for s in SHARES]) + " |")
    atomic_write_bytes(args.out + ".json", json.dumps(records, indent=1).encode())
    write_report(args.out + ".md", "\n".join([
        "# Gaussians the loop barely moved (an oracle probe)", "",
        "Command: `python benchmarks/lagging.py` (after `python benchmarks/instructions.py`). "
        "Per edit: the region's Gaussians, the share of the ceiling's colour move they made "
        "(10th / 25th / 50th percentile), the edited region's PSNR dB (mean of the three "
        "protocols) as edited, and after giving the Gaussians below a share the ceiling's "
        "colour (how many, and the PSNR).", ""] + lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
