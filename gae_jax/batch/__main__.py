"""Many edits from one manifest, in this process or on a Ray cluster.

    python -m gae_jax.batch JOBS.toml --out DIR [--ray [ADDRESS]] [--cpus-per-job 1]
                            [--gpus-per-job 0] [--workers N] [--list]

Each job writes an ordinary run folder DIR/<job> (readable by `python -m gae_jax.evaluate`
and `python -m gae_jax.view`); DIR/summary.json, summary.md and summary.png gather every job's
scores. A finished job is not run again; an interrupted one resumes from its checkpoint. The
manifest's format: `gae_jax/batch/manifest.py`.
"""

from __future__ import annotations

import argparse
import os
import sys

from gae_jax import cli
from gae_jax.batch import cluster, local, manifest, summary


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gae_jax.batch",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("manifest", help="the jobs (TOML; see gae_jax/batch/manifest.py)")
    p.add_argument("--out", required=True, help="folder of the jobs' run folders and summary")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="run on Ray: a cluster's address, or none to start a local Ray")
    p.add_argument("--cpus-per-job", type=float, default=1.0, help="Ray: CPUs each job holds")
    p.add_argument("--gpus-per-job", type=float, default=0.0, help="Ray: GPUs each job holds")
    p.add_argument("--workers", type=int, default=0,
                   help="Ray: worker actors (0: as many as the resources allow)")
    p.add_argument("--list", action="store_true", help="list the jobs and their folders, run "
                   "nothing")
    cli.add_compile_cache_flag(p)
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    cli.prepare_process(args.compile_cache)
    state = {}

    def prepare():
        if args.cpus_per_job <= 0 or args.gpus_per_job < 0 or args.workers < 0:
            raise ValueError("--cpus-per-job must be > 0, --gpus-per-job and --workers >= 0")
        state["jobs"] = manifest.read(args.manifest)
        if args.ray is not None:
            cluster.import_ray()
        os.makedirs(args.out, exist_ok=True)
        return 0

    if cli.main_guard(prepare):
        return 2
    jobs = state["jobs"]
    if args.list:
        for job in jobs:
            print(f"{job.name}\t{os.path.join(args.out, job.name)}")
        return 0
    meta = dict(command="python -m gae_jax.batch " + " ".join(argv or sys.argv[1:]),
                jobs=len(jobs), engine="ray" if args.ray is not None else "local")
    if args.ray is None:
        rows = local.run(jobs, args.out, meta)
    else:
        rows = cluster.run(jobs, args.out, meta, "" if args.ray == "local" else args.ray,
                           args.cpus_per_job, args.gpus_per_job, args.workers)
    print(summary.table([r for r in rows if "error" not in r]))
    failed = [r for r in rows if "error" in r]
    for r in failed:
        print(f"error: job {r['name']!r}: {r['error']}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
