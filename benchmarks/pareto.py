"""Speed against accuracy of the default edit: what costs time, what it buys.

    python benchmarks/pareto.py [--head makehuman] [--out benchmarks/results/pareto]

Sweeps, one knob at a time from the default (`fast` on the `--head` scene, by default the CLI's
MakeHuman head: 128 px, 100 iterations, every Gaussian of the reconstruction, tile capacity
sized from the busiest tile):
  * Gaussians: keep the most opaque 75 / 50 / 25 % of the reconstructed avatar;
  * resolution: edit at 64 / 96 px (own scene and reconstruction), evaluated at 128 px;
  * tile capacity: 0.5x / 0.75x of the busiest tile (overflowing tiles drop Gaussians);
  * iterations: 25 / 50 / 200.
Each variant's step is compiled before timing (`warmup_seconds`), so `edit_seconds` is the
steady-state cost. Quality: PSNR of the edited region (lips) and of the region it must not touch
(teeth), mean over the three protocols, against the ideal edit. Writes `<out>.json` and
`<out>.png` (both qualities against edit time, Pareto fronts marked) and prints the front.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

import numpy as np

from gae_jax.edit import edit
from gae_jax.edit.config import preset
from gae_jax.evaluation import score
from gae_jax.model import avatar as av, head
from gae_jax.run.original import original_avatar
from gae_jax.scene import rig as rigs, synthetic
from gae_jax.scene.types import posed_vertices, training_frames
from gae_jax.run.bench import Bench, mean_over_protocols, renderer_settings, same_settings, save_figure  # noqa: E501

VARIANTS = {
    "default": {},
    "gaussians_75": dict(keep=0.75), "gaussians_50": dict(keep=0.5),
    "gaussians_25": dict(keep=0.25),
    "size_64": dict(size=64), "size_96": dict(size=96),
    "capacity_0.5": dict(capacity=0.5), "capacity_0.75": dict(capacity=0.75),
    "iterations_25": dict(iterations=25), "iterations_50": dict(iterations=50),
    "iterations_200": dict(iterations=200),
}


def keep_most_opaque(avatar: av.Avatar, fraction: float, num_faces: int) -> av.Avatar:
    order = np.argsort(-np.asarray(avatar.opacity_logits))
    remove = np.ones(avatar.num, bool)
    remove[order[:int(round(fraction * avatar.num))]] = False
    return av.prune(avatar, remove, num_faces, keep_every_face=False)


def run_variant(bench: Bench, name: str, knobs: dict, base, scene128, head_kind: str):
    config = dataclasses.replace(base, iterations=knobs.get("iterations", base.iterations))
    recorded = bench.results.get(name)
    if recorded is not None and recorded.get("knobs") == knobs and same_settings(recorded, config):
        return recorded
    size = knobs.get("size", 128)
    scene = scene128 if size == 128 else synthetic.make_synthetic_scene(size=size, progress=False,
                                                                        head_kind=head_kind)
    original = original_avatar(scene, base.reconstruct_iterations, progress=False)
    if "keep" in knobs:
        original = keep_most_opaque(original, knobs["keep"], scene.model.faces.shape[0])
    session, _ = bench.setup(config, scene, original)
    auto_capacity = session.rig.tile_capacity
    if "capacity" in knobs:
        capacity = max(32, int(round(knobs["capacity"] * auto_capacity)))
        session = dataclasses.replace(session, rig=dataclasses.replace(session.rig,
                                                                       tile_capacity=capacity))
    edit.edit_avatar(dataclasses.replace(
        session, config=dataclasses.replace(config, iterations=1)))  # compiles
    start = time.perf_counter()
    edited, history = edit.edit_avatar(session)
    seconds = time.perf_counter() - start
    # Scored at 128 px whatever the edit's resolution: the avatar is 3D.
    judge_capacity = session.rig.tile_capacity if size == 128 else rigs.put_rig(
        scene128, original, posed_vertices(scene128, training_frames(scene128)[:1])).tile_capacity
    evaluation = score.evaluate_avatars(bench.evalset(scene128, config.prompt), edited,
                                        original, judge_capacity, session.step_config.blend)
    record = dict(knobs=knobs, config=dataclasses.asdict(config), renderer=renderer_settings(),
                  edit_seconds=round(seconds, 1), gaussians=int(edited.num),
                  tile_capacity=session.rig.tile_capacity, size=size,
                  iterations=config.iterations,
                  auto_tile_capacity=auto_capacity,
                  evaluation=evaluation)
    bench.results[name] = record
    bench.save()
    print(name, record["edit_seconds"], "s", flush=True)
    return record


def pareto_front(times, quality):
    """Indices of points no other point beats in both (less time, more quality)."""
    front = []
    for i, (t, q) in enumerate(zip(times, quality)):
        if not any((t2 <= t and q2 >= q) and (t2 < t or q2 > q)
                   for j, (t2, q2) in enumerate(zip(times, quality)) if j != i):
            front.append(i)
    return sorted(front, key=lambda i: times[i])


def label_groups(xs, ys, names, near_x: float = 0.15, near_y: float = 0.1) -> list:
    """[(x, y, "name\\nname")]: one label, a line per point, for each group of points within
    `near_x` / `near_y` of the axes' spans of the group's first point (the labels of points
    that close would print over each other); a group's lines run from its highest point down,
    and the label sits at the highest."""
    span = [max(max(v) - min(v), 1e-9) for v in (xs, ys)]
    groups: list = []
    for x, y, name in zip(xs, ys, names):
        for g in groups:
            if abs(x - g[0][0]) < near_x * span[0] and abs(y - g[0][1]) < near_y * span[1]:
                g.append((x, y, name))
                break
        else:
            groups.append([(x, y, name)])
    out = []
    for g in groups:
        g = sorted(g, key=lambda p: (-p[1], p[0]))
        out.append((g[0][0], g[0][1], "\n".join(p[2] for p in g)))
    return out


def plot(results: dict, path: str) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    times = [results[n]["edit_seconds"] for n in names]
    fronts = {}
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, region, label in ((axes[0], "edited", "lips (edited) PSNR dB"),
                              (axes[1], "teeth", "teeth (must not change) PSNR dB")):
        q = [mean_over_protocols(results[n], "psnr", region) for n in names]
        front = pareto_front(times, q)
        fronts[region] = [names[i] for i in front]
        ax.scatter(times, q, c=["tab:red" if n == "default" else "tab:blue" for n in names])
        ax.plot([times[i] for i in front], [q[i] for i in front], "k--", lw=1,
                label="Pareto front")
        for t, v, text in label_groups(times, q, names):
            ax.annotate(text, (t, v), fontsize=7, xytext=(4, 3), textcoords="offset points",
                        va="top" if "\n" in text else "bottom")
        ax.set_xlabel("edit wall time, s (compiled, 2-core CPU)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(loc="lower right")
    fig.suptitle("Speed against accuracy: 'turn the lips blue', mean over 3 protocols")
    fig.tight_layout()
    save_figure(fig, path)
    return fronts


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--out", default="benchmarks/results/pareto")
    p.add_argument("--iterations", type=int, default=100, help="edit iterations of the default")
    p.add_argument("--head", choices=head.HEAD_KINDS, default=head.DEFAULT_KIND)
    args = p.parse_args(argv)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    bench = Bench(args.out + ".json")
    base = preset("fast", checkpoint_every=0, iterations=args.iterations)
    scene128 = synthetic.make_synthetic_scene(size=128, progress=False, head_kind=args.head)
    for name in args.variants:
        run_variant(bench, name, VARIANTS[name], base, scene128, args.head)
    fronts = plot(bench.results, args.out + ".png")
    bench.save(fronts=fronts, head=args.head)
    for name, r in bench.results.items():
        print(f"{name:16s} {r['edit_seconds']:7.1f} s  lips "
              f"{mean_over_protocols(r, 'psnr', 'edited')}  teeth "
              f"{mean_over_protocols(r, 'psnr', 'teeth')}  whole "
              f"{mean_over_protocols(r, 'psnr', 'whole')}")
    print("Pareto fronts:", fronts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
