"""The README's and docs' pictures of the default edit, from its run folder: the grid as it is,
and frames of the reenactment video side by side.

    python -m gae_jax.train --out runs/edit
    python tools/docs_pictures.py [--run runs/edit] [--out docs] [--frames 4]

Writes `docs/grid_default.png` and `docs/reenactment_default.png` (`--frames` frames spread
evenly over the video, each ours | untouched, in one row). The viewer's picture is
`tools/viewer_screenshot.py`'s.
"""

from __future__ import annotations

import argparse
import os
import shutil

import numpy as np

from gae_jax.run import folder
from gae_jax.util.fileio import atomic_write_bytes, encode_png


def video_row(path: str, frames: int) -> np.ndarray:
    """(H, frames * W, 3) uint8: `frames` frames spread evenly over the video at `path`."""
    import imageio.v2 as imageio

    with imageio.get_reader(path) as reader:
        video = [np.asarray(f) for f in reader]
    if not video:
        raise ValueError(f"{path}: no frames")
    picks = np.linspace(0, len(video) - 1, frames + 2)[1:-1].round().astype(int)
    return np.concatenate([video[i] for i in picks], axis=1)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default="runs/edit")
    p.add_argument("--out", default="docs")
    p.add_argument("--frames", type=int, default=4)
    args = p.parse_args(argv)
    grid, video = folder.path(args.run, "grid"), folder.path(args.run, "video")
    for needed in (grid, video):
        if not os.path.isfile(needed):
            raise SystemExit(f"error: {needed}: not found (run python -m gae_jax.train "
                             f"--out {args.run} first, with its video)")
    shutil.copyfile(grid, os.path.join(args.out, "grid_default.png"))
    atomic_write_bytes(os.path.join(args.out, "reenactment_default.png"),
                       encode_png(video_row(video, args.frames)))
    print(f"wrote {args.out}/grid_default.png and {args.out}/reenactment_default.png")


if __name__ == "__main__":
    main()
