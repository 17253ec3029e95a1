"""The README's main command from an empty cache, then again with the caches it left, with the
compilation time of every jitted program it compiled.

    python benchmarks/cold_start.py [--head procedural makehuman] [--out benchmarks/results/cold_start]

Per head, three runs of `python -m gae_jax.train --no-video` one after another, each in its own
process with `GAE_JAX_CACHE` pointing at a fresh folder for the first:
  * cold: nothing cached (scene ray casting, reconstruction, every compilation);
  * warm: the same folder again (scene, avatar and compiled programs all cached there);
  * warm_no_compile_cache: the same data caches with `--compile-cache off` (what a second run
    cost before the persistent compilation cache).
Reported: wall time, the job's own timings (`metrics.json`), and JAX's compile log
(`JAX_LOG_COMPILES`): seconds per compiled program, largest first. Prints JSON per run and
writes `<out>.json` (the rows of heads not run this time are kept).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time

from gae_jax.run.bench import machine
from gae_jax.util.fileio import atomic_write_bytes

COMPILED = re.compile(r"Finished XLA compilation of (.+?) in ([0-9.e+-]+) sec")


def run_job(cache: str, head: str, compile_cache: bool) -> dict:
    out = tempfile.mkdtemp(prefix="cold-start-run-")
    env = dict(os.environ, GAE_JAX_CACHE=cache, JAX_LOG_COMPILES="1")
    env.pop("GAE_JAX_COMPILE_CACHE", None)
    cmd = [sys.executable, "-m", "gae_jax.train", "--out", out, "--no-video", "--overwrite",
           "--head", head] + ([] if compile_cache else ["--compile-cache", "off"])
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    compiles = collections.Counter()
    for name, seconds in COMPILED.findall(proc.stderr):
        compiles[name] += float(seconds)
    with open(os.path.join(out, "metrics.json")) as f:
        metrics = json.load(f)
    return dict(wall_s=round(wall, 1), timings=metrics["timings"],
                compile_s=round(sum(compiles.values()), 1),
                programs=len(compiles),
                largest_compiles={k: round(v, 1) for k, v in compiles.most_common(6)})


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--head", nargs="+", default=["makehuman"],
                   help="heads to run (default: the shipped one)")
    p.add_argument("--out", default="benchmarks/results/cold_start")
    args = p.parse_args(argv)
    path = args.out + ".json"
    results = {}
    for head in args.head:
        cache = tempfile.mkdtemp(prefix=f"cold-start-{head}-")
        results[head] = {"machine": machine()}
        for name, compile_cache in (("cold", True), ("warm", True),
                                    ("warm_no_compile_cache", False)):
            results[head][name] = run_job(cache, head, compile_cache)
            print(json.dumps({head: {name: results[head][name]}}), flush=True)
    # The heads not run this time keep their earlier rows.
    recorded = json.load(open(path)) if os.path.isfile(path) else {}
    atomic_write_bytes(path, json.dumps({**recorded, **results}, indent=1).encode())
    return results


if __name__ == "__main__":
    main()
