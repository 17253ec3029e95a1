"""What one edit iteration costs at 128 / 256 / 512 px (target: <= 1 s at 512).

    python benchmarks/edit_resolution.py [--sizes 128 256 512] [--iterations 8]
                                         [--head makehuman|procedural] [--kernel auto|jax]
                                         [--variants full max256 no_gan]
                                         [--out benchmarks/results/edit_resolution.json]

The scene of `--head` (the CLI's default head by default) has its cameras and training images
scaled to each size (intrinsics x s, images resized bilinearly, region labels by nearest
neighbour) and the default edit (README's main command: semantic editor, lips region) runs on
the cached default reconstruction. Variants of the step, all timed in one process with their
iterations interleaved (so the machine's drift hits them alike):
  * full: the default config (the discriminator judges the whole pair);
  * maxN: `gan_max_side=N` (the pairs resized to at most N px);
  * no_gan: `adversarial=False`.
Per size and variant, after two warm-up iterations (compilation), the median over
`--iterations` of
  * host: `EditSampler.batch` (the preview render on device, the 2D edit and the region
    composite on the host);
  * step: the jitted, donated edit step (render, losses, backward, Adam), blocked on;
  * iteration: their sum.
Prints and writes one JSON object.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import time


def variant_overrides(name: str) -> dict:
    """EditConfig overrides of a variant name (see the module docstring)."""
    if name == "full":
        return {}
    if name == "no_gan":
        return dict(adversarial=False)
    if name.startswith("max") and name[3:].isdigit():
        return dict(gan_max_side=int(name[3:]))
    raise ValueError(f"unknown variant {name!r}: full, no_gan or maxN")


def scaled_scene(scene, size: int):
    """`scene` with cameras and images at size x size (the scene is square)."""
    import cv2
    import numpy as np

    s = size / scene.width
    intrinsics = np.asarray(scene.intrinsics, np.float64) * s
    resize = lambda a, interp: np.stack([  # noqa: E731  (C, T, H, W[, 3]) per image
        np.stack([cv2.resize(a[c, t], (size, size), interpolation=interp)
                  for t in range(a.shape[1])]) for c in range(a.shape[0])])
    train = set(scene.sequences_of("train"))
    images = {n: resize(v, cv2.INTER_LINEAR) for n, v in scene.images.items() if n in train}
    regions = {n: resize(v.astype(np.int16), cv2.INTER_NEAREST).astype(v.dtype)
               for n, v in scene.regions.items() if n in train}
    return dataclasses.replace(scene, intrinsics=intrinsics.astype(scene.intrinsics.dtype),
                               width=size, height=size, images=images, regions=regions,
                               region_samples={})  # centre labels only at the new size


def time_size(scene, original, size: int, iterations: int, variants: list) -> list:
    """One record per variant at `size`, their iterations interleaved."""
    import jax
    import jax.numpy as jnp

    from gae_jax.edit import edit
    from gae_jax.edit.config import EditConfig
    from gae_jax.edit.sampler import put_batch

    sized = scaled_scene(scene, size)
    runs = []
    for name in variants:
        session = edit.setup(EditConfig(**variant_overrides(name)), sized, original)
        runs.append(dict(name=name, session=session, state=edit.fresh_state(session),
                         sampler=edit.make_sampler(session), host=[], step=[]))
    key = jax.random.PRNGKey(0)
    for i in range(iterations + 2):
        for run in runs:
            session, sampler = run["session"], run["sampler"]
            start = time.perf_counter()
            batch = put_batch(sampler.batch(run["state"].params, i, key), None)
            editable = jnp.asarray(sampler.editable())
            middle = time.perf_counter()
            run["state"], metrics = session.step(run["state"], session.rig, batch, editable)
            jax.block_until_ready(metrics)
            end = time.perf_counter()
            if i >= 2:
                run["host"].append(middle - start)
                run["step"].append(end - middle)
    return [dict(size=size, variant=run["name"], host_s=round(statistics.median(run["host"]), 3),
                 step_s=round(statistics.median(run["step"]), 3),
                 iteration_s=round(statistics.median(
                     [a + b for a, b in zip(run["host"], run["step"])]), 3),
                 tile_capacity=int(run["session"].rig.tile_capacity)) for run in runs]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", type=int, default=[128, 256, 512])
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--head", choices=("makehuman", "procedural"), default="makehuman")
    parser.add_argument("--variants", nargs="+", default=["full", "max256", "no_gan"],
                        help="step variants timed side by side: full, no_gan, maxN")
    parser.add_argument("--out", default="benchmarks/results/edit_resolution.json")
    parser.add_argument("--kernel", default="auto", choices=["auto", "jax"],
                        help="the renderer's compositor and depth sort: the C++ kernels where "
                             "built (auto) or pure JAX")
    args = parser.parse_args()
    for name in args.variants:
        variant_overrides(name)
    from gae_jax.render import splat

    # Benchmark-only: every render of this process takes the chosen path.
    splat.render.__kwdefaults__["kernel"] = args.kernel
    from gae_jax.run.bench import default_scene_and_avatar
    from gae_jax.util.fileio import atomic_write_bytes

    scene, original = default_scene_and_avatar(args.head)
    results = []
    for size in args.sizes:
        for record in time_size(scene, original, size, args.iterations, args.variants):
            results.append(record)
            print(json.dumps(record), flush=True)
    result = dict(target_512_s=1.0, kernel=args.kernel, head=args.head,
                  gaussians=int(original.num), variants=args.variants, results=results)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    atomic_write_bytes(args.out, json.dumps(result, indent=1).encode())
    print(json.dumps(result))


if __name__ == "__main__":
    main()
