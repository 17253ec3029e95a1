"""Demo of a built-in head as Gaussians bound to its triangles, rendered.

    python -m gae_jax.demo --out runs/demo [--head procedural|makehuman]

Builds the built-in FLAME-format head, puts Gaussians on its triangles (GaussianAvatars binding),
poses it (neutral, jaw open, blink, head turn) with FLAME skinning, renders each pose with the
splatting renderer and writes `head.png` plus a JSON report with timings. It is the main job until
the edit loop lands. `random_frustum_scene` is the renderer benchmark's scene.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax import cli
from gae_jax.model import avatar, flame, head
from gae_jax.render import splat, wabe
from gae_jax.render.camera import look_at_w2c, make_camera
from gae_jax.util.compile import fast_jit
from gae_jax.util.fileio import atomic_write_bytes, encode_png


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


def head_poses(model, assets=None, kind: str = "procedural"):
    """Named poses that show the head's joints and expressions."""
    if kind == "makehuman":
        def units(**c):
            return head.expression(model, assets.expr_names, **c)

        return {
            "neutral": head.params(model),
            "jaw_open": head.params(model, expr=units(jawOpen=0.8)),
            "blink_smile": head.params(model, expr=units(eyeBlinkLeft=1.0, eyeBlinkRight=1.0,
                                                         mouthSmileLeft=1.0,
                                                         mouthSmileRight=1.0)),
            "turn_tongue": head.params(model, rotation=(0.0, 0.5, 0.0),
                                       expr=units(jawOpen=0.5, tongueOut=1.0)),
        }
    return {
        "neutral": head.params(model),
        "jaw_open": head.params(model, jaw_open=0.3),
        "blink_smile": head.params(model, expr=head.expression(model, blink_left=1.0,
                                                                blink_right=1.0, smile=1.0)),
        "turn": head.params(model, rotation=(0.0, 0.5, 0.0), jaw_open=0.15),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/demo", help="output folder")
    parser.add_argument("--size", type=int, default=256, help="image width and height")
    parser.add_argument("--per-face", type=int, default=1, help="Gaussians per triangle")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--head", default=head.DEFAULT_KIND, choices=head.HEAD_KINDS,
                        help="the built-in head")
    cli.add_compile_cache_flag(parser)
    args = parser.parse_args(argv)
    cli.prepare_process(args.compile_cache)
    if args.size < 16 or args.per_face < 1:
        parser.error("--size must be >= 16 and --per-face >= 1")

    model, assets = head.make_head(args.head)
    gaussians_on_mesh = avatar.init_from_mesh(
        model.v_template, model.faces, assets.vertex_colors, assets.face_regions,
        per_face=args.per_face, sh_degree=None, key=jax.random.PRNGKey(args.seed), opacity=0.95,
        normal_scale=0.1)
    distance = {"procedural": 0.55, "makehuman": 0.64}[args.head]  # the MakeHuman head is taller
    camera = make_camera(look_at_w2c([0.0, 0.0, distance], [0.0, -0.01, 0.0], up=(0, 1, 0)),
                         args.size, args.size, fov_degrees=28.0)

    poses = head_poses(model, assets, args.head)
    load = jax.jit(lambda p: splat.tile_load(
        avatar.deform(gaussians_on_mesh, flame.lbs(model, p), model.faces), camera))
    # Sized from the busiest tile over the poses: a small image puts many Gaussians in a tile.
    capacity = max(int(load(p)) for p in poses.values())

    @fast_jit
    def render(params):
        verts = flame.lbs(model, params)
        g = avatar.deform(gaussians_on_mesh, verts, model.faces)
        return splat.render(g, camera, background=jnp.ones(3), tile_capacity=capacity)

    images, timings, overflow = [], {}, 0
    for name, params in poses.items():
        start = time.perf_counter()
        out = jax.block_until_ready(render(params))
        timings[name] = round(time.perf_counter() - start, 4)
        overflow += int(out.stats.overflow_tiles)
        images.append(np.asarray(out.image))

    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "head.png")
    atomic_write_bytes(path, encode_png(np.concatenate(images, axis=1)))
    report = dict(image=path, gaussians=int(gaussians_on_mesh.num),
                  vertices=int(model.num_vertices), faces=int(model.faces.shape[0]),
                  size=args.size, seconds_per_pose=timings, overflow_tiles=overflow,
                  blend_modes=[b.mode for b in (wabe.standard(), wabe.wabe(), wabe.wabe_grad())])
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
