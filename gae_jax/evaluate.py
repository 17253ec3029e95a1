"""Re-score a run folder of `python -m gae_jax.train`, reading nothing but the folder.

    python -m gae_jax.evaluate RUN_DIR [--clip-folder DIR]

Reads RUN_DIR/metrics.json (the blend and tile capacity the edit used),
RUN_DIR/evaluation_set.npz (posed meshes, cameras, truth and region labels per protocol),
RUN_DIR/original_avatar/point_cloud.ply and RUN_DIR/edited_avatar/point_cloud.ply, and writes
RUN_DIR/evaluation.json and evaluation.md (the same numbers as metrics.json's evaluation).
"""

from __future__ import annotations

import argparse
import sys

from gae_jax import cli
from gae_jax.evaluation import clip_score, report, score
from gae_jax.run import folder


def run(run_dir: str, clip_folder: str = "") -> dict:
    """The evaluation of a run folder; writes evaluation.json and evaluation.md into it."""
    run_record = folder.read(run_dir)
    evalset = run_record.evaluation_set()
    avatars = run_record.avatars(evalset.face_regions)
    results = score.evaluate_avatars(evalset, avatars["edited"], avatars["original"],
                                     run_record.tile_capacity, run_record.blend, clip_folder)
    folder.write_evaluation(run_dir, results, report.summary_table(results))
    return results


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m gae_jax.evaluate",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", help="folder written by python -m gae_jax.train")
    p.add_argument("--clip-folder", default="", help="local CLIP folder for CLIP-S / CLIP-C")
    cli.add_compile_cache_flag(p)
    args = p.parse_args(argv)
    cli.prepare_process(args.compile_cache)
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
