"""How the renderer's time scales with pixels and Gaussians per tile.

    python benchmarks/render_scaling.py [--sizes 64 128 256 512 1024]
                                        [--gaussians 2000 20000 100000 500000] [--repeats 5]
                                        [--out benchmarks/results/render_scaling]

Every (Gaussians, size) of the grid runs `benchmarks/render.py --one` in its own process (the
specified random scene, the C++ compositor, the `fast` compiler options, no torch reference):
forward and forward+backward milliseconds (median after warm-up), the compositor alone, the
walked (pixel, Gaussian) pairs (tiles x 256 x the longest tile list: the work the compositor
does, pixels x Gaussians per tile) and the machine's exp bound measured in the same process.
A configuration that fails (memory, say) is recorded with its error. Writes `<out>.json`
(every row, atomically after each) and `<out>.png`: milliseconds against walked pairs, log-log,
one line per Gaussian count.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from gae_jax.run.bench import save_figure
from gae_jax.util.fileio import atomic_write_bytes

RENDER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "render.py")


def run(num: int, size: int, repeats: int) -> dict:
    """One grid point through `render.py --one`, or {"error": ...}."""
    cmd = [sys.executable, RENDER, "--one", f"{num}x{size}", "--repeats", str(repeats),
           "--options", "fast", "--no-jax", "--no-reference"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        lines = (done.stderr.strip().splitlines() or ["no output"])
        return dict(gaussians=num, width=size, height=size, error=lines[-1][:300])
    return json.loads(done.stdout.strip().splitlines()[-1])


def chart(rows: list, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, num in enumerate(sorted({r["gaussians"] for r in rows})):
        ok = sorted((r for r in rows if r["gaussians"] == num and "error" not in r),
                    key=lambda r: r["width"])
        if not ok:
            continue
        for axis, field in zip(axes, ("forward_ms", "forward_backward_ms")):
            axis.loglog([r["walked_pairs"] for r in ok], [r[field] for r in ok], "o-",
                        color=f"C{i}", label=f"{num:,} Gaussians")
            for r in ok:
                axis.annotate(f"{r['width']}", (r["walked_pairs"], r[field]), fontsize=6,
                              xytext=(3, -8), textcoords="offset points")
    for axis, title in zip(axes, ("forward", "forward + backward")):
        axis.set_xlabel("walked (pixel, Gaussian) pairs: tiles x 256 x longest tile list")
        axis.set_ylabel("ms (median)")
        axis.set_title(f"{title}; labels: image side in px", fontsize=9)
        axis.grid(True, which="both", lw=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Renderer time against the compositor's work (C++ kernels, fast options, "
                 "2 CPU cores)", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256, 512, 1024])
    parser.add_argument("--gaussians", type=int, nargs="+",
                        default=[2000, 20000, 100000, 500000])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="benchmarks/results/render_scaling")
    args = parser.parse_args(argv)
    rows = []
    for num in args.gaussians:
        for size in args.sizes:
            rows.append(run(num, size, args.repeats))
            print(json.dumps(rows[-1]), flush=True)
            atomic_write_bytes(args.out + ".json", json.dumps(dict(rows=rows), indent=1).encode())
    chart(rows, args.out + ".png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
