"""Renderer demo: renders a seeded random Gaussian scene and writes a PNG.

    python -m gae_jax.demo --out runs/demo

Placeholder for the main job until the edit loop lands: it exercises the whole renderer (project,
bin, composite, custom VJP) on the CPU and reports timings.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax import splat, wabe
from gae_jax.camera import make_camera
from gae_jax.compile import fast_jit
from gae_jax.io import atomic_write_bytes


def random_frustum_scene(num: int, width: int, height: int, seed: int = 0,
                         fov_degrees: float = 60.0):
    """The renderer benchmark's seeded scene, as (Gaussians, Camera).

    Camera at the origin looking down +z, 60 degree field of view, centred principal point;
    depth uniform in [2, 6]; x, y uniform within 1.1x the frustum at that depth; random normal
    quaternions; scales log-uniform in [0.01, 0.08] per axis, times (2000 / N)^(1/3) when
    N > 2000; opacity uniform in [0.05, 0.99]; colours uniform in [0, 1].
    """
    rng = np.random.default_rng(seed)
    camera = make_camera(np.eye(4), width, height, fov_degrees=fov_degrees)
    tan_x = 0.5 * width / float(camera.intrinsics[0])
    tan_y = 0.5 * height / float(camera.intrinsics[1])
    z = rng.uniform(2.0, 6.0, num)
    means = np.stack([rng.uniform(-1.1, 1.1, num) * tan_x * z,
                      rng.uniform(-1.1, 1.1, num) * tan_y * z, z], -1)
    quats = rng.normal(size=(num, 4))
    scales = np.exp(rng.uniform(np.log(0.01), np.log(0.08), (num, 3)))
    if num > 2000:
        scales *= (2000.0 / num) ** (1.0 / 3.0)
    g = splat.Gaussians(jnp.asarray(means, jnp.float32), jnp.asarray(quats, jnp.float32),
                        jnp.asarray(scales, jnp.float32),
                        jnp.asarray(rng.uniform(0.05, 0.99, num), jnp.float32),
                        jnp.asarray(rng.uniform(0.0, 1.0, (num, 3)), jnp.float32))
    return g, camera


def encode_png(image: np.ndarray) -> bytes:
    """(H, W, 3) float image in [0, 1] -> PNG bytes."""
    import cv2

    rgb = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    ok, buf = cv2.imencode(".png", rgb[..., ::-1])
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/demo", help="output folder")
    parser.add_argument("--num", type=int, default=20000, help="number of Gaussians")
    parser.add_argument("--size", type=int, default=256, help="image width and height")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.num < 1 or args.size < 1:
        parser.error("--num and --size must be positive")

    g, camera = random_frustum_scene(args.num, args.size, args.size, args.seed)
    render = fast_jit(lambda g, b: splat.render(g, camera, background=b, tile_capacity=512))
    background = jnp.ones(3, jnp.float32)
    start = time.perf_counter()
    out = jax.block_until_ready(render(g, background))
    first = time.perf_counter() - start
    start = time.perf_counter()
    out = jax.block_until_ready(render(g, background))
    second = time.perf_counter() - start

    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "render.png")
    atomic_write_bytes(path, encode_png(np.asarray(out.image)))
    report = dict(image=path, gaussians=args.num, size=args.size,
                  compile_and_run_s=round(first, 3), run_s=round(second, 4),
                  overflow_tiles=int(out.stats.overflow_tiles),
                  blend_modes=[b.mode for b in (wabe.standard(), wabe.wabe(), wabe.wabe_grad())])
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
