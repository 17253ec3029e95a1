"""What one edit iteration costs at 128 / 256 / 512 px (issue 17: <= 1 s at 512).

    python benchmarks/edit_resolution.py [--sizes 128 256 512] [--iterations 8]
                                         [--kernel auto|jax] [--adversarial true|false]
                                         [--gan-max-side N]
                                         [--out benchmarks/results/edit_resolution.json]

The default scene's cameras and training images are scaled to each size (intrinsics x s, images
resized bilinearly, region labels by nearest neighbour) and the default edit (README's main
command: semantic editor, lips region) runs on the default reconstruction. Per size, after two
warm-up iterations (compilation), the median over `--iterations` of
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
                               width=size, height=size, images=images, regions=regions)


def time_size(scene, original, size: int, iterations: int, adversarial: bool = True,
              gan_max_side: int = 0) -> dict:
    import jax
    import jax.numpy as jnp

    from gae_jax.edit import edit
    from gae_jax.edit.config import EditConfig
    from gae_jax.edit.sampler import put_batch

    config = EditConfig(adversarial=adversarial, gan_max_side=gan_max_side)
    session = edit.setup(config, scaled_scene(scene, size), original)
    state = edit.fresh_state(session)
    sampler = edit.make_sampler(session)
    key = jax.random.PRNGKey(0)
    host, step = [], []
    for i in range(iterations + 2):
        start = time.perf_counter()
        batch = put_batch(sampler.batch(state.params, i, key), None)
        editable = jnp.asarray(sampler.editable())
        middle = time.perf_counter()
        state, metrics = session.step(state, session.rig, batch, editable)
        jax.block_until_ready(metrics)
        end = time.perf_counter()
        if i >= 2:
            host.append(middle - start)
            step.append(end - middle)
    return dict(size=size, host_s=round(statistics.median(host), 3),
                step_s=round(statistics.median(step), 3),
                iteration_s=round(statistics.median([a + b for a, b in zip(host, step)]), 3),
                tile_capacity=int(session.rig.tile_capacity))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", nargs="+", type=int, default=[128, 256, 512])
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--out", default="benchmarks/results/edit_resolution.json")
    parser.add_argument("--adversarial", default="true", choices=["true", "false"],
                        help="the temporal GAN in the step (the default edit has it)")
    parser.add_argument("--gan-max-side", type=int, default=0,
                        help="longest side of the discriminator's pairs (EditConfig."
                             "gan_max_side; 0 = the render's own)")
    parser.add_argument("--kernel", default="auto", choices=["auto", "jax"],
                        help="the renderer's compositor and depth sort: the C++ kernels where "
                             "built (auto) or pure JAX")
    args = parser.parse_args()
    from gae_jax.render import splat

    # Benchmark-only: every render of this process takes the chosen path.
    splat.render.__kwdefaults__["kernel"] = args.kernel
    from gae_jax import train
    from gae_jax.edit.config import EditConfig
    from gae_jax.scene import synthetic
    from gae_jax.util.fileio import atomic_write_bytes

    scene = synthetic.make_synthetic_scene(progress=False)
    original = train.original_avatar(scene, EditConfig().reconstruct_iterations, progress=False)
    results = []
    for size in args.sizes:
        results.append(time_size(scene, original, size, args.iterations,
                                 args.adversarial == "true", args.gan_max_side))
        print(json.dumps(results[-1]), flush=True)
    result = dict(target_512_s=1.0, kernel=args.kernel, adversarial=args.adversarial == "true",
                  gan_max_side=args.gan_max_side, results=results)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    atomic_write_bytes(args.out, json.dumps(result, indent=1).encode())
    print(json.dumps(result))


if __name__ == "__main__":
    main()
