"""The docs' picture of the GAN against a two-answer editor: "turn the lips blue" with the
built-in editor picking a dark or a light blue per call (`--editor-modes 2`), edited with the
GAN off and at adversarial weight 1, side by side.

    python tools/gan_modes_grid.py [--out docs/grid_gan_colour_modes.png] [--rows 1 3 4]

Runs the two edits (the default job's settings otherwise, into runs/gan_modes/) and cuts the
columns out of their grids: untouched, one call's 2D edit, ours with the GAN off, ours at
weight 1.
"""

from __future__ import annotations

import argparse
import os

import cv2
import numpy as np

from gae_jax.edit.config import preset
from gae_jax.run import folder, job, outputs
from gae_jax.run.gan_scenario import COLOUR_PROMPT, MODES, adversarial
from gae_jax.util.fileio import atomic_write_bytes, encode_png

COLUMNS = ("untouched", "one call's 2D edit", "ours, GAN off", "ours, GAN weight 1")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="docs/grid_gan_colour_modes.png")
    p.add_argument("--runs", default="runs/gan_modes")
    p.add_argument("--rows", type=int, nargs="+", default=[1, 3, 4])
    args = p.parse_args(argv)
    cells = {}
    for weight in (0, 1):
        run_dir = os.path.join(args.runs, f"weight{weight}")
        if not os.path.isfile(folder.path(run_dir, "grid")):
            config = preset("fast", prompt=COLOUR_PROMPT, editor_modes=MODES,
                            **adversarial(weight))
            job.run(config, run_dir, video=False, progress=False)
        grid = cv2.imread(folder.path(run_dir, "grid"))[..., ::-1]
        cells[weight] = outputs.grid_cells(grid)[args.rows]
    picture = np.concatenate([cells[0][:, 0], cells[0][:, 1], cells[0][:, 2], cells[1][:, 2]],
                             axis=2)  # (rows, 2H, 4 * 2W, 3)
    width = picture.shape[2] // len(COLUMNS)
    title = outputs.label(picture.shape[2], f'"{COLOUR_PROMPT}", editor picking a dark or a '
                          f"light blue per call (--editor-modes {MODES})", outputs.GRID_TEXT)
    header = np.concatenate([outputs.label(width, c, outputs.GRID_TEXT) for c in COLUMNS], axis=1)
    atomic_write_bytes(args.out, encode_png(np.concatenate([title, header, *picture], axis=0)))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
