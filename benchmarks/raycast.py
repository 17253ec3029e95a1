"""How fast the ground truth is ray cast (rays per second).

    python benchmarks/raycast.py [--head makehuman] [--out benchmarks/results/raycast.json]

Builds the default scene of `--head` into an empty cache folder (every frame of every sequence
from every camera, `supersample` 2: four colour rays per pixel plus the centre ray for labels
and depth) and reports the wall time, frames and rays per second, which caster built it, and, on
one frame in the same process, the C++ caster's and embree's own rates on the same rays
(`raycast_kernel.first_hits` and `EmbreeScene.run` alone, both cores) for the ceiling the
Python around them leaves. Prints and writes one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor


def main(argv=None) -> dict:
    import numpy as np

    from gae_jax.model import flame, head
    from gae_jax.scene import raycast, raycast_kernel, synthetic
    from gae_jax.util.fileio import atomic_write_bytes

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--head", choices=head.HEAD_KINDS, default=head.DEFAULT_KIND)
    parser.add_argument("--out", default="benchmarks/results/raycast.json")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    scene = synthetic.make_synthetic_scene(head_kind=args.head, progress=False,
                                           cache_dir=tempfile.mkdtemp(prefix="raycast-bench-"))
    build_s = time.perf_counter() - start
    frames = sum(s.num_frames for s in scene.sequences.values())
    cameras = scene.intrinsics.shape[0]
    cameras_of_rig = synthetic.rig_cameras(scene.intrinsics, scene.w2c, scene.width)
    casts = len(raycast.ray_sets(cameras_of_rig[:1], scene.supersample)[0])  # rays per pixel
    rays = frames * cameras * scene.width * scene.height * casts

    name = next(iter(scene.sequences))
    verts = np.asarray(flame.lbs(scene.model, scene.sequences[name].params(scene.shapes["A"], 0)))
    embree = raycast.embree_scene(verts, np.asarray(scene.model.faces))
    batches = [raycast.camera_rays(c, (0.25, 0.25)) for c in cameras_of_rig]
    batches32 = [tuple(x.astype(np.float32) for x in b) for b in batches]
    faces = np.asarray(scene.model.faces, np.int64)

    def rate(cast, rays_of):
        """Rays per second of `cast` over every camera's rays, `casts` times, both cores."""
        with ThreadPoolExecutor(os.cpu_count() or 1) as pool:
            list(pool.map(cast, rays_of))
            start = time.perf_counter()
            for _ in range(casts):
                list(pool.map(cast, rays_of))
            return round(casts * cameras * scene.width * scene.height
                         / (time.perf_counter() - start))

    kernel_rate = (rate(lambda b: raycast_kernel.first_hits(verts, faces, *b), batches)
                   if raycast_kernel.available() else None)
    embree_rate = rate(lambda b: embree.run(*b, output=1), batches32)
    result = dict(head=args.head, size=scene.width, cameras=cameras, frames=frames,
                  rays_per_pixel=casts, rays=rays, build_s=round(build_s, 1),
                  frames_per_s=round(frames / build_s, 2),
                  rays_per_s=round(rays / build_s),
                  caster="C++" if raycast_kernel.available() else "embree",
                  kernel_alone_rays_per_s=kernel_rate,
                  embree_alone_rays_per_s=embree_rate,
                  cores=os.cpu_count())
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    atomic_write_bytes(args.out, json.dumps(result, indent=1).encode())
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
