"""Reconstruction quality against time and Gaussian count on the default scene.

    python benchmarks/reconstruct.py [--variants default it100 it200 it800 size64 densify ...]
                                     [--out benchmarks/results/reconstruct]

Variants `makehuman` and `makehuman_it600` fit the MakeHuman head's scene (`--head makehuman`);
`it600` is the edit's reconstruction (`EditConfig.reconstruct_iterations`).

For each variant (one process each, run one after another so they share the machine's state):
fit identity A's avatar on the training split, then score it against the ray-cast ground truth:
  * held_out_camera_psnr: the held-out camera (8) on every 4th training frame (novel view);
  * held_out_sequence_psnr: the held-out sequence `mix` (every 2nd frame) from every 3rd training
    camera (self-reenactment);
and report wall time (fit incl. compilation), steps/s, Gaussian count. Prints one JSON object per
variant and writes `<out>.json` and `<out>.png` (PSNR against time, marker size ~ Gaussians).
Targets (issue 4): >= 30 dB held-out camera, >= 28 dB held-out sequence, < 180 s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

VARIANTS = {
    "default": {},
    "it100": dict(iterations=100),
    "it200": dict(iterations=200),
    "it800": dict(iterations=800),
    "size64": dict(size=64),
    "densify": dict(densify_every=100, densify_from=100),
    "lr_means_2e-3": dict(lr_means=2e-3, lr_means_final=2e-5),
    "it600": dict(iterations=600),
    "makehuman": dict(head="makehuman"),
    "makehuman_it600": dict(head="makehuman", iterations=600),
}


def run_variant(name: str) -> dict:
    from gae_jax.evaluation.score import psnr_against_capture
    from gae_jax.fit.config import ReconstructConfig
    from gae_jax.fit.fit import fit
    from gae_jax.scene import synthetic
    from gae_jax.scene.types import training_frames

    options = dict(VARIANTS[name])
    size = options.pop("size", 128)
    head_kind = options.pop("head", "procedural")
    scene = synthetic.make_synthetic_scene(size=size, progress=False, head_kind=head_kind)
    config = ReconstructConfig(**options)
    start = time.perf_counter()
    avatar, history = fit(scene, config)
    seconds = time.perf_counter() - start
    frames = training_frames(scene)[::4]
    mix = [("mix", t) for t in range(0, scene.sequences["mix"].num_frames, 2)]
    return dict(
        variant=name, size=size, head=head_kind, config=options, seconds=round(seconds, 1),
        steps_per_second=round(config.iterations / seconds, 2),
        gaussians=int(avatar.num),
        train_psnr_last50=round(sum(h["psnr"] for h in history[-50:]) / 50, 2),
        held_out_camera_psnr=round(psnr_against_capture(avatar, scene, frames,
                                                    scene.held_out_cameras), 2),
        held_out_sequence_psnr=round(psnr_against_capture(avatar, scene, mix,
                                                      scene.train_cameras[::3]), 2),
        overflow_tiles_last=history[-1]["overflow_tiles"])


def chart(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for r in results:
        for key, marker in (("held_out_camera_psnr", "o"), ("held_out_sequence_psnr", "s")):
            ax.scatter(r["seconds"], r[key], s=r["gaussians"] / 60, marker=marker,
                       alpha=0.6, color="C0" if marker == "o" else "C1")
        ax.annotate(r["variant"], (r["seconds"], r["held_out_camera_psnr"]), fontsize=8,
                    xytext=(4, 4), textcoords="offset points")
    ax.axhline(30, color="C0", lw=0.8, ls="--")
    ax.axhline(28, color="C1", lw=0.8, ls="--")
    ax.axvline(180, color="grey", lw=0.8, ls=":")
    ax.scatter([], [], color="C0", label="held-out camera (target 30 dB)")
    ax.scatter([], [], color="C1", marker="s", label="held-out sequence (target 28 dB)")
    ax.set_xlabel("fit wall time, s (incl. compilation; 2-core CPU)")
    ax.set_ylabel("PSNR vs ray-cast truth, dB")
    ax.set_title("Reconstruction: quality against time (marker area ~ Gaussians)")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--out", default="benchmarks/results/reconstruct")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_variant(args.one)))
        return
    results = []
    for name in args.variants:
        proc = subprocess.run([sys.executable, __file__, "--one", name], capture_output=True,
                              text=True)
        if proc.returncode != 0:
            result = dict(variant=name, error=proc.stderr.strip().splitlines()[-1:])
        else:
            result = json.loads(proc.stdout.strip().splitlines()[-1])
        print(json.dumps(result), flush=True)
        results.append(result)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    from gae_jax.util.fileio import atomic_write_bytes

    atomic_write_bytes(args.out + ".json", json.dumps(results, indent=1).encode())
    chart([r for r in results if "error" not in r], args.out + ".png")


if __name__ == "__main__":
    main()
