"""Reconstruction quality against time and Gaussian count on the default scene.

    python benchmarks/reconstruct.py [--variants default it100 it200 it800 size64 densify ...]
                                     [--out benchmarks/results/reconstruct]
    python benchmarks/reconstruct.py --truth-ceiling [--out benchmarks/results/truth_ceiling]

Variants `makehuman` and `makehuman_it600` fit the MakeHuman head's scene (`--head makehuman`);
`it600` is the edit's reconstruction (`EditConfig.reconstruct_iterations`); `gsplat_filter` is
it600 with 3DGS's 0.3 px^2 screen filter instead of ours (`ReconstructConfig.screen_filter`,
0.1).

For each variant (one process each, run one after another so they share the machine's state):
fit identity A's avatar on the training split, then score it against the ray-cast ground truth:
  * held_out_camera_psnr: the held-out camera (8) on every 4th training frame (novel view);
  * held_out_sequence_psnr: the held-out sequence `mix` (every 2nd frame) from every 3rd training
    camera (self-reenactment);
  * regions: PSNR per region group (whole, lips, teeth, mouth, iris, sclera, skin) pooled over
    the pixels the truth labels so, for novel_view (held-out camera, 8 training frames) and
    self_reenactment (held-out sequence, 8 frames, every 3rd training camera);
and report wall time (fit incl. compilation), steps/s, Gaussian count. Prints one JSON object per
variant and writes `<out>.json` and `<out>.png` (PSNR against time, marker size ~ Gaussians).
Targets: >= 30 dB held-out camera, >= 28 dB held-out sequence, < 180 s;
teeth >= 25 dB and eyes >= 30 dB where visible.

`--truth-ceiling` scores the scene's own truth instead: the same frames ray-cast with 1x1 and
2x2 rays per pixel (the scene ships 2x2) against a 6x6 build, per region group. A fit cannot
be measured more finely than its truth's own error.
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
    "gsplat_filter": dict(iterations=600, screen_filter=0.3),
}
REGION_GROUPS = {"whole": None, "lips": ("lips",), "teeth": ("teeth",), "mouth": ("mouth",),
                 "iris": ("iris", "pupil"), "sclera": ("sclera",), "skin": ("skin",)}


def region_psnr(predicted, truth, regions) -> dict:
    """{group: PSNR dB or None} pooling squared errors of (..., H, W, 3) images in [0, 1] over
    the pixels whose (..., H, W) label belongs to each `REGION_GROUPS` entry."""
    import numpy as np

    from gae_jax.evaluation.metrics import pooled_psnr
    from gae_jax.model import head

    out = {}
    for group, names in REGION_GROUPS.items():
        mask = (np.ones(regions.shape, bool) if names is None else
                np.isin(regions, [head.REGION_ID[n] for n in names if n in head.REGION_ID]))
        value = pooled_psnr(predicted, truth, mask)
        out[group] = None if value is None else round(value, 2)
    return out


def score_frames(scene):
    """{protocol: (pairs, cameras)}: the frames `region_scores` and the truth ceiling use."""
    from gae_jax.scene.types import training_frames

    train = training_frames(scene)
    mix = scene.sequences["mix"].num_frames
    return {"novel_view": (train[::max(1, len(train) // 8)][:8], list(scene.held_out_cameras)),
            "self_reenactment": ([("mix", t) for t in range(0, mix, max(1, mix // 8))][:8],
                                 list(scene.train_cameras[::3]))}


def region_scores(avatar, scene, screen_filter: float) -> dict:
    """{protocol: {group: PSNR}} of `avatar` rendered with `screen_filter` against the scene's
    truth (`score_frames`)."""
    import numpy as np

    from gae_jax.scene import rig as rigs
    from gae_jax.scene.types import posed_vertices

    out = {}
    for name, (pairs, cameras) in score_frames(scene).items():
        rig = rigs.put_rig(scene, avatar, posed_vertices(scene, pairs, "A"), 0,
                           capacity_cameras=cameras, screen_filter=screen_filter)
        images = np.asarray(rigs.render_views(rigs.make_view_renderer(), avatar.trainable(),
                                              rig, cameras))
        truth = np.stack([scene.images[n][cameras, t] for n, t in pairs]) / 255.0
        labels = np.stack([scene.regions[n][cameras, t] for n, t in pairs])
        out[name] = region_psnr(images, truth, labels)
    return out


def truth_ceiling(supersamples=(1, 2), reference=6) -> dict:
    """{f"{s}x{s}": {protocol: {group: PSNR}}}: the default scene's truth ray-cast with s x s
    rays per pixel against a `reference` x `reference` build of the same frames."""
    import numpy as np

    from gae_jax.scene import synthetic

    scene = synthetic.make_synthetic_scene(progress=False)
    colours = synthetic.shaded_colors(scene.model, scene.albedo["A"], scene.shapes["A"])

    def cast(pairs, cameras, supersample):
        images, labels = [], []
        for n, t in pairs:
            img, reg = synthetic.render_frame(
                scene.model, scene.face_regions, colours, scene.shapes["A"], scene.sequences[n],
                t, scene.intrinsics[cameras], scene.w2c[cameras], scene.width, scene.background,
                supersample=supersample)
            images.append(np.asarray(img, np.float64) / 255.0)
            labels.append(reg)
        return np.stack(images), np.stack(labels)

    out = {}
    for name, (pairs, cameras) in score_frames(scene).items():
        best, labels = cast(pairs, cameras, reference)
        for s in supersamples:
            image, _ = cast(pairs, cameras, s)
            out.setdefault(f"{s}x{s}", {})[name] = region_psnr(image, best, labels)
    return dict(reference=f"{reference}x{reference}", scores=out)


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
        variant=name, size=size, head=head_kind, config=options,
        cov2d_dilation=config.screen_filter, seconds=round(seconds, 1),
        steps_per_second=round(config.iterations / seconds, 2),
        gaussians=int(avatar.num),
        train_psnr_last50=round(sum(h["psnr"] for h in history[-50:]) / 50, 2),
        held_out_camera_psnr=round(psnr_against_capture(
            avatar, scene, frames, scene.held_out_cameras,
            screen_filter=config.screen_filter), 2),
        held_out_sequence_psnr=round(psnr_against_capture(
            avatar, scene, mix, scene.train_cameras[::3], screen_filter=config.screen_filter), 2),
        overflow_tiles_last=history[-1]["overflow_tiles"],
        regions=region_scores(avatar, scene, config.screen_filter)
        if head_kind == "procedural" else None)


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
    parser.add_argument("--out", help="output path without extension (default "
                        "benchmarks/results/reconstruct, or .../truth_ceiling)")
    parser.add_argument("--truth-ceiling", action="store_true",
                        help="score the scene's 1x1 and 2x2 truth against a 6x6 build instead")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args()
    from gae_jax.util.fileio import atomic_write_bytes

    if args.truth_ceiling:
        out = args.out or "benchmarks/results/truth_ceiling"
        result = truth_ceiling()
        print(json.dumps(result))
        os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
        atomic_write_bytes(out + ".json", json.dumps(result, indent=1).encode())
        return
    args.out = args.out or "benchmarks/results/reconstruct"
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
    atomic_write_bytes(args.out + ".json", json.dumps(results, indent=1).encode())
    chart([r for r in results if "error" not in r], args.out + ".png")


if __name__ == "__main__":
    main()
