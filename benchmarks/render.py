"""Renderer speed and memory: forward and forward+backward on the specified random scene.

    python benchmarks/render.py [--configs 2000x128 50000x256 50000x512] [--repeats 7]
                                [--no-jax] [--no-reference]

Prints one JSON object per configuration (and a summary list at the end): median (and minimum)
milliseconds after warm-up with the C++ compositor (`gae_jax.render.cpu_kernel`, the default on
CPU) and, in the same process, with the pure-JAX one (`jax_*`, `kernel_speedup_*`; skipped with
`--no-jax`, as `benchmarks/render_scaling.py` does), (pixel,
Gaussian) pairs per second against two exp bounds measured in the same process: the walked
pairs (tiles x 256 x the longest list) against cores / numpy's time per float32 exp
(`*_share_of_exp_bound`, the issue's first definition), and the pairs the forward resolves
(`walk_count`: every pixel of each tile at every Gaussian the walk reaches before it terminates,
no padding) against the kernel's own exp on every core (`cpu_kernel.exp_rate`,
`*_share_of_kernel_exp_bound`); `composite_exp_utilisation` counts only the pairs the kernel
evaluates (the rows each Gaussian reaches), i.e. how busy its exp is. Also: overflowed tiles,
tile capacity and peak RSS, and the same
scene timed in the same process with `gae_jax/render/tile_reference.py` (a
plain torch transcription of the standard tile algorithm, autograd for the backward; best of 3)
with our speed-up over it (our best time against its best time). Each configuration runs in its
own process so that peak RSS is its own (the reference's torch tensors count in it). The tile capacity
is the smallest multiple of 32 that holds every tile's list (so the image is exact; overflow is
reported and must be 0).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

from gae_jax.render import walk_count

REFERENCE_REPEATS = 3  # the tile reference is slow; its best of 3 is its time
KERNELS = ("auto", "jax")  # the C++ compositor where built, and the pure-JAX one


def reference_ms(g, camera, weights) -> tuple:
    """(forward, forward + backward) best-of milliseconds of `tile_reference` (torch, float32,
    every core) on the same scene and camera, in this process."""
    import numpy as np
    import torch

    from gae_jax.render import tile_reference

    torch.set_num_threads(os.cpu_count() or 1)
    t = {k: torch.tensor(np.asarray(getattr(g, k), np.float32))
         for k in ("means", "quats", "scales", "opacities", "colors")}
    intr = torch.tensor(np.asarray(camera.intrinsics, np.float32))
    w2c = torch.tensor(np.asarray(camera.w2c, np.float32))
    bg = torch.zeros(3)
    w = torch.tensor(np.asarray(weights, np.float32))

    def forward():
        with torch.no_grad():
            tile_reference.render(t["means"], t["quats"], t["scales"], t["opacities"],
                                  t["colors"], intr, w2c, camera.width, camera.height, bg)

    def forward_backward():
        leaves = {k: v.clone().requires_grad_(True) for k, v in t.items()}
        image = tile_reference.render(leaves["means"], leaves["quats"], leaves["scales"],
                                      leaves["opacities"], leaves["colors"], intr, w2c,
                                      camera.width, camera.height, bg)
        (image * w).sum().backward()

    def best(fn):
        times = []
        for _ in range(REFERENCE_REPEATS):
            start = time.perf_counter()
            fn()
            times.append(time.perf_counter() - start)
        return 1e3 * min(times)

    return best(forward), best(forward_backward)


def run_one(num: int, size: int, repeats: int, blend_name: str, unroll: int,
            options: str, reference: bool, pure_jax: bool = True) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from gae_jax.render import cpu_kernel, splat, wabe
    from gae_jax.util.compile import compiler_options
    from gae_jax.demo import random_frustum_scene
    from gae_jax.render.projection import project
    from gae_jax.render.tiles import bin_gaussians

    blend = wabe.named(blend_name)
    g, camera = random_frustum_scene(num, size, size, seed=0)
    p = project(g.means, g.quats, g.scales, g.opacities, camera)
    probe = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, size, size, 1)
    max_count = int(probe.counts.max())
    capacity = max(32, -(-max_count // 32) * 32)

    opts = compiler_options() if options == "fast" else None
    weights = jax.random.uniform(jax.random.PRNGKey(0), (size, size, 3))

    def timings_ms(fn):
        jax.block_until_ready(fn(g))
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            jax.block_until_ready(fn(g))
            times.append(time.perf_counter() - start)
        return 1e3 * float(np.median(times)), 1e3 * float(np.min(times))

    kernels = KERNELS if pure_jax else KERNELS[:1]
    timed = {"jax": (None,) * 4}
    for kernel in kernels:
        def image(g, kernel=kernel):
            return splat.render(g, camera, blend=blend, tile_capacity=capacity, unroll=unroll,
                                kernel=kernel)

        forward = jax.jit(lambda g, image=image: image(g).image, compiler_options=opts)
        grad = jax.jit(jax.grad(lambda g, image=image: jnp.sum(image(g).image * weights)),
                       compiler_options=opts)
        timed[kernel] = timings_ms(forward) + timings_ms(grad)
    # The compositor alone (the tile lists fixed): what the exp bound speaks to.
    from gae_jax.render import composite as comp

    bins = bin_gaussians(p.means2d, p.extents, p.depths, p.visible, size, size, capacity)
    packed = jnp.concatenate([p.means2d, p.conics, p.opacities[:, None], p.depths[:, None],
                              jnp.asarray(g.colors)], axis=-1)
    packed = jnp.where(p.visible[:, None], packed, 0.0)
    composite_ms = {"jax": None}
    for kernel in kernels:
        cfg = comp.CompositeConfig(blend=blend, alpha_clamp=0.99, tiles_x=bins.tiles_x,
                                   tiles_y=bins.tiles_y, unroll=unroll, kernel=kernel)
        only = jax.jit(lambda x, cfg=cfg: comp.composite(cfg, bins.table, bins.kept, x)[0],
                       compiler_options=opts)
        composite_ms[kernel] = timings_ms(lambda _, only=only: only(packed))[1]
    # Binning alone (depth order, rectangles, tile lists): the C++ walk against lax.sort.
    binning_ms = {"jax": None}
    for kernel in kernels:
        lists = jax.jit(lambda m, e, d, v, kernel=kernel: bin_gaussians(
            m, e, d, v, size, size, capacity, kernel=kernel).table, compiler_options=opts)
        binning_ms[kernel] = timings_ms(
            lambda _, lists=lists: lists(p.means2d, p.extents, p.depths, p.visible))[1]
    (fwd_ms, fwd_min, fwd_bwd_ms, fwd_bwd_min) = timed["auto"]
    (jax_fwd_ms, jax_fwd_min, jax_fwd_bwd_ms, jax_fwd_bwd_min) = timed["jax"]
    # Machine-speed probe: this VM's speed drifts by up to 2x over an hour, so each result carries
    # the time numpy needs per float32 exp, measured in the same process.
    exp_input = np.random.default_rng(0).uniform(-5, 0, 4_000_000).astype(np.float32)
    np.exp(exp_input)
    start = time.perf_counter()
    for _ in range(5):
        np.exp(exp_input)
    numpy_exp_ns = (time.perf_counter() - start) / (5 * exp_input.size) * 1e9
    # The stricter bound: the kernel's own exp, at its SIMD width, on every core; and the pairs
    # the forward resolves (early termination, no padding) and evaluates (the rows a Gaussian
    # reaches), not the padded walk.
    kernel_exp_per_s = cpu_kernel.exp_rate() if cpu_kernel.available() else None
    walk = walk_count.replay(bins.table, bins.kept, packed, bins.tiles_x)
    reached, evaluated = walk["reached_pairs"], walk["evaluated_pairs"]
    ref = reference_ms(g, camera, weights) if reference else None
    cores = os.cpu_count() or 1
    out = jax.jit(lambda g: splat.render(g, camera, blend=blend, tile_capacity=capacity))(g)
    pairs = int(jnp.sum(probe.counts)) * 256  # pixel-Gaussian pairs the tile lists imply
    walked = int(out.stats.num_slots) * 256 * int(probe.counts.shape[0])
    return dict(
        gaussians=num, width=size, height=size, blend=blend_name, unroll=unroll,
        compiler_options=opts or {},
        tile_capacity=capacity, max_tile_count=max_count,
        overflow_tiles=int(out.stats.overflow_tiles), dropped_pairs=int(out.stats.dropped_pairs),
        forward_ms=round(fwd_ms, 2), forward_backward_ms=round(fwd_bwd_ms, 2),
        forward_min_ms=round(fwd_min, 2), forward_backward_min_ms=round(fwd_bwd_min, 2),
        kernel=cpu_kernel.available(),
        **({} if jax_fwd_ms is None else dict(
            jax_forward_ms=round(jax_fwd_ms, 2), jax_forward_backward_ms=round(jax_fwd_bwd_ms, 2),
            kernel_speedup_forward=round(jax_fwd_min / fwd_min, 2),
            kernel_speedup_forward_backward=round(jax_fwd_bwd_min / fwd_bwd_min, 2),
            jax_composite_min_ms=round(composite_ms["jax"], 2),
            jax_binning_min_ms=round(binning_ms["jax"], 2))),
        tile_pairs_per_s_forward=round(pairs / (fwd_ms * 1e-3)),
        walked_pairs_per_s_forward=round(walked / (fwd_ms * 1e-3)),
        exp_bound_per_s=round(cores / (numpy_exp_ns * 1e-9)),
        composite_min_ms=round(composite_ms["auto"], 2), walked_pairs=walked,
        binning_min_ms=round(binning_ms["auto"], 2),
        composite_share_of_exp_bound=round(
            walked / (composite_ms["auto"] * 1e-3) / (cores / (numpy_exp_ns * 1e-9)), 3),
        forward_share_of_exp_bound=round(walked / (fwd_ms * 1e-3) / (cores / (numpy_exp_ns * 1e-9)),
                                         3),
        numpy_exp_ns=round(numpy_exp_ns, 3),
        reached_pairs=reached, evaluated_pairs=evaluated,
        reached_pairs_per_s_forward=round(reached / (fwd_ms * 1e-3)),
        **({} if kernel_exp_per_s is None else dict(
            kernel_exp_per_s=round(kernel_exp_per_s),
            forward_share_of_kernel_exp_bound=round(
                reached / (fwd_ms * 1e-3) / kernel_exp_per_s, 3),
            composite_share_of_kernel_exp_bound=round(
                reached / (composite_ms["auto"] * 1e-3) / kernel_exp_per_s, 3),
            composite_exp_utilisation=round(
                evaluated / (composite_ms["auto"] * 1e-3) / kernel_exp_per_s, 3))),
        peak_rss_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        devices=str(jax.devices()), jax_version=jax.__version__,
        **({} if ref is None else dict(
            reference_forward_ms=round(ref[0], 1), reference_forward_backward_ms=round(ref[1], 1),
            speedup_vs_reference_forward=round(ref[0] / fwd_min, 2),
            speedup_vs_reference_forward_backward=round(ref[1] / fwd_bwd_min, 2))),
    )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", nargs="+", default=["2000x128", "50000x256", "50000x512"],
                        help="NUMxSIZE entries")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--blend", default="standard", choices=["standard", "wabe", "wabe_grad"])
    parser.add_argument("--unroll", type=int, default=8)
    parser.add_argument("--options", nargs="+", default=["fast", "default"],
                        choices=["fast", "default"],
                        help="fast: gae_jax.util.compile.compiler_options(); default: plain jax.jit. "
                             "Both run, interleaved per configuration, by default.")
    parser.add_argument("--no-reference", action="store_true",
                        help="skip timing gae_jax/render/tile_reference.py (torch) in the same process")
    parser.add_argument("--no-jax", action="store_true",
                        help="time only the default compositor (the C++ kernel where built), "
                             "not the pure-JAX one beside it")
    parser.add_argument("--one", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.one:
        num, size = (int(v) for v in args.one.split("x"))
        print(json.dumps(run_one(num, size, args.repeats, args.blend, args.unroll,
                                 args.options[0], not args.no_reference, not args.no_jax)))
        return
    results = []
    for config in args.configs:
        for options in args.options:
            cmd = [sys.executable, os.path.abspath(__file__), "--one", config, "--repeats",
                   str(args.repeats), "--blend", args.blend, "--unroll", str(args.unroll),
                   "--options", options] + (["--no-reference"] if args.no_reference else []) + (
                       ["--no-jax"] if args.no_jax else [])
            line = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            result = json.loads(line.strip().splitlines()[-1])
            result["options"] = options
            print(json.dumps(result), flush=True)
            results.append(result)
    print(json.dumps(dict(results=results), indent=1))


if __name__ == "__main__":
    main()
