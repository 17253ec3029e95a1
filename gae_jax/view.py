"""Interactive viewer: drive an edited avatar with expression, jaw, eye and head sliders in the
browser, before and after the edit.

    python -m gae_jax.view RUN_DIR [--port 8080] [--size 256] [--display image|splats]
    python -m gae_jax.view --avatar DIR [--head procedural|makehuman | --flame-model FILE]

Serves a page (viser; its client ships in the wheel, nothing is fetched) on http://HOST:PORT.
Every slider move, camera move or sequence frame costs one FLAME pose + `deform` + render of our
jitted renderer, streamed to the page as the background image (`--display image`, the
default): the picture is exactly what the edit trained and was scored on (its blending, SH
colours, our tile compositor). `--display splats` sends the posed Gaussians to viser's own
splat renderer instead (smooth orbiting on a slow machine, but RGB from the SH's constant term
and standard blending only). Screenshots (the button) are PNGs in RUN_DIR/screenshots/
(`--screenshots DIR`).
"""

from __future__ import annotations

import argparse
import sys
import time

from gae_jax import cli
from gae_jax.model import head
from gae_jax.run import folder
from gae_jax.viewer import source
from gae_jax.viewer.app import DISPLAYS, Viewer


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gae_jax.view",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", nargs="?", default="", help="run folder of python -m gae_jax.train")
    p.add_argument("--avatar", default="", help="view a GaussianAvatars folder (point_cloud.ply "
                   "+ flame_param.npz) instead of a run folder")
    p.add_argument("--head", default=head.DEFAULT_KIND, choices=head.HEAD_KINDS,
                   help="--avatar: the built-in head it is bound to")
    p.add_argument("--flame-model", default="", help="--avatar: the FLAME file it is bound to")
    p.add_argument("--flame-masks", default="", help="--avatar: FLAME_masks.pkl for its regions")
    p.add_argument("--blend", default="standard", choices=("standard", "wabe", "wabe_grad"),
                   help="--avatar: the blending it was trained with (a run folder knows)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every "
                   "interface)")
    p.add_argument("--port", type=int, default=8080, help="port (0: a free one)")
    p.add_argument("--size", type=int, default=256, help="rendered image height in pixels")
    p.add_argument("--display", default="image", choices=DISPLAYS,
                   help="image: our renderer's pictures (exact); splats: viser's renderer")
    p.add_argument("--screenshots", default="", help="folder for screenshots (default: "
                   "RUN_DIR/screenshots, or ./screenshots with --avatar)")
    cli.add_compile_cache_flag(p)
    return p


def start(args: argparse.Namespace) -> Viewer:
    """The viewer the parsed flags ask for; ValueError / FileNotFoundError on bad input."""
    if bool(args.run_dir) == bool(args.avatar):
        raise ValueError("give a run folder or --avatar DIR (one of them)")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port {args.port}: must be in 0..65535")
    if args.run_dir:
        viewable = source.from_run(args.run_dir)
        shots = args.screenshots or folder.path(args.run_dir, "screenshots")
    else:
        viewable = source.from_avatar(args.avatar, args.head, args.flame_model,
                                      args.flame_masks, args.blend)
        shots = args.screenshots or "screenshots"
    return Viewer(viewable, args.host, args.port, args.size, args.display, shots)


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    cli.prepare_process(args.compile_cache)
    out = {}

    def body():
        out["viewer"] = start(args)
        return 0

    if cli.main_guard(body):
        return 2
    viewer = out["viewer"]
    print(f"gae_jax.view: http://{args.host}:{viewer.port}  (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
