"""What one slider move costs in the viewer: FLAME pose + `deform` + render of a run folder's
edited avatar, at several image heights, after the first call of each size has compiled.

    python benchmarks/viewer.py [--run runs/edit] [--sizes 128 256 512] [--repeats 20]
                                [--out benchmarks/results/viewer]

Each move takes the next frame of the held-out sequence (`mix`, or the run's first sequence)
into the sliders, so the mesh really changes between moves. Reported per size: the compile
time of the first call, the median and 90th percentile of a move in image mode (the default:
pose + render + copy to the host), the side-by-side mode (two renders at half width), and the
splats mode (pose + covariances to the host, rendered by the browser). Prints JSON and writes
`<out>.json`.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from gae_jax.util.fileio import atomic_write_bytes
from gae_jax.viewer import frames, pose, source


def timed(fn, repeats: int) -> dict:
    first = time.perf_counter()
    fn(0)
    compile_s = time.perf_counter() - first
    seconds = []
    for i in range(1, repeats + 1):
        start = time.perf_counter()
        fn(i)
        seconds.append(time.perf_counter() - start)
    ms = 1000 * np.asarray(seconds)
    return dict(first_call_s=round(compile_s, 2), median_ms=round(float(np.median(ms)), 1),
                p90_ms=round(float(np.percentile(ms, 90)), 1))


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default="runs/edit", help="run folder of python -m gae_jax.train")
    p.add_argument("--sizes", type=int, nargs="+", default=[128, 256, 512])
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--out", default="benchmarks/results/viewer")
    args = p.parse_args(argv)

    v = source.from_run(args.run)
    name = "mix" if "mix" in v.sequences else next(iter(v.sequences))
    seq = v.sequences[name]
    avatar, original = v.avatars["edited"], v.avatars["original"]
    front = frames.front_camera(v.w2c)

    def params(i):
        values = pose.values_of_frame(seq, i % seq.num_frames)
        return pose.params_of_values(values, v.shapes[seq.identity], v.model.num_expr)

    results = dict(run=args.run, gaussians=int(avatar.num), sequence=name, repeats=args.repeats,
                   sizes={})
    for size in args.sizes:
        position, wxyz, fov = frames.view_of_camera(v.intrinsics[front], v.w2c[front], v.height)
        camera = frames.camera_of_view(position, wxyz, fov, 1.0, size)
        wide = frames.camera_of_view(position, wxyz, fov, 2.0, size)
        half = frames.side_by_side(wide)
        capacity = {}

        def image(i, cam=camera, which=avatar, key="image"):
            img, capacity[key] = frames.render(v.model, which, params(i), cam, v.background,
                                               v.blend, capacity.get(key))
            return img

        def both(i):
            return np.concatenate([image(i, half, original, "half"),
                                   image(i, half, avatar, "half")], axis=1)

        results["sizes"][str(size)] = dict(
            image=timed(image, args.repeats), side_by_side=timed(both, args.repeats),
            splats=timed(lambda i: frames.splat_arrays(v.model, avatar, params(i)),
                         args.repeats),
            tile_capacity=capacity["image"])
        print(json.dumps({str(size): results["sizes"][str(size)]}), flush=True)
    atomic_write_bytes(args.out + ".json", json.dumps(results, indent=1).encode())
    print(json.dumps(results, indent=1))
    return results


if __name__ == "__main__":
    main()
