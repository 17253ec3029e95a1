"""Re-score a run folder of `python -m gae_jax.train`, reading nothing but the folder.

    python -m gae_jax.evaluate RUN_DIR [--clip-folder DIR]

Reads RUN_DIR/metrics.json (the blend and tile capacity the edit used),
RUN_DIR/evaluation_set.npz (posed meshes, cameras, truth and region labels per protocol),
RUN_DIR/original_avatar/point_cloud.ply and RUN_DIR/edited_avatar/point_cloud.ply, and writes
RUN_DIR/evaluation.json and evaluation.md (the same numbers as metrics.json's evaluation).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from gae_jax import cli
from gae_jax.edit.config import EditConfig, StepConfig
from gae_jax.evaluation import clip_score, report, score, truth
from gae_jax.model import avatar_io
from gae_jax.util.fileio import atomic_write_bytes


def run(run_dir: str, clip_folder: str = "") -> dict:
    """The evaluation of a run folder; writes evaluation.json and evaluation.md into it."""
    metrics_path = os.path.join(run_dir, "metrics.json")
    if not os.path.isfile(metrics_path):
        raise FileNotFoundError(f"{metrics_path} not found; is {run_dir!r} a run folder of "
                                "python -m gae_jax.train?")
    try:
        with open(metrics_path) as f:
            saved = json.load(f)
        config, capacity = EditConfig(**saved["config"]), int(saved["tile_capacity"])
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"{metrics_path}: not a metrics file of this version ({e})") from e
    evalset = truth.load(os.path.join(run_dir, truth.FILE_NAME))
    avatars = {}
    for name in ("original_avatar", "edited_avatar"):
        avatars[name] = avatar_io.load_bound_avatar(
            os.path.join(run_dir, name, "point_cloud.ply"), evalset.face_regions)
    if avatars["edited_avatar"].num != avatars["original_avatar"].num:
        raise ValueError(f"{run_dir}: the edited avatar has {avatars['edited_avatar'].num} "
                         f"Gaussians, the original {avatars['original_avatar'].num}")
    results = score.evaluate_avatars(evalset, avatars["edited_avatar"],
                                     avatars["original_avatar"], capacity,
                                     StepConfig.of(config).blend, clip_folder)
    atomic_write_bytes(os.path.join(run_dir, "evaluation.json"),
                       json.dumps(results, indent=1).encode())
    atomic_write_bytes(os.path.join(run_dir, "evaluation.md"),
                       (report.summary_table(results) + "\n").encode())
    return results


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m gae_jax.evaluate",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", help="folder written by python -m gae_jax.train")
    p.add_argument("--clip-folder", default="", help="local CLIP folder for CLIP-S / CLIP-C")
    cli.add_compile_cache_flag(p)
    args = p.parse_args(argv)
    cli.use_compile_cache(args.compile_cache)
    out = {}

    def body():
        if args.clip_folder:
            clip_score.check_folder(args.clip_folder)
        out["results"] = run(args.run_dir, args.clip_folder)
        return 0

    if cli.main_guard(body):
        return 2
    print(report.summary_table(out["results"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
