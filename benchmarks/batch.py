"""What a batch saves: 8 default jobs (4 instructions x 2 seeds) through one `python -m
gae_jax.batch` process against 8 CLI runs in a row, a local Ray with 2 and with 1 worker
against the local batch, and a Ray worker killed (`kill -9`) in the middle of a job.

    python benchmarks/batch.py [--out benchmarks/results/batch]

Everything runs side by side in one invocation on warm caches (the scene, the original avatar
and the compilation cache are built first, as a user's second run would find them), each arm
into its own fresh folder. Writes `<out>.json` and `<out>.md`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

from gae_jax.batch import cluster, local, manifest
from gae_jax.run import folder
from gae_jax.run.bench import machine, write_report
from gae_jax.util.fileio import atomic_write_bytes

PROMPTS = ("turn the lips blue", "make the hair ginger", "make the eyebrows white",
           "make the skin pale")
SEEDS = (0, 1)


def manifest_text(prompts=PROMPTS, seeds=SEEDS, **defaults) -> str:
    lines = ["[defaults]"] + [f"{k} = {json.dumps(v)}" for k, v in defaults.items()]
    lines += ["", "[[jobs]]", 'name = "b"', f"prompt = {json.dumps(list(prompts))}",
              f"seed = {json.dumps(list(seeds))}"]
    return "\n".join(lines) + "\n"


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return round(time.perf_counter() - start, 1)


def cli_runs(jobs, out: str) -> None:
    """Each job as its own `python -m gae_jax.train` process, one after another."""
    for job in jobs:
        argv = [sys.executable, "-m", "gae_jax.train", "--out", os.path.join(out, job.name),
                "--prompt", job.config.prompt, "--seed", str(job.config.seed)]
        subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def batch_process(path: str, out: str, *flags) -> None:
    subprocess.run([sys.executable, "-m", "gae_jax.batch", path, "--out", out, *flags],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def same_scores(a: str, b: str) -> bool:
    return folder.read(a).metrics["evaluation"] == folder.read(b).metrics["evaluation"]


def killed_worker(work: str) -> dict:
    """One default job on Ray, its worker killed once the first checkpoint exists; against the
    same job run straight through."""
    path = os.path.join(work, "kill.toml")
    with open(path, "w") as f:
        f.write(manifest_text(prompts=PROMPTS[:1], seeds=(0,), video=False, checkpoint_every=10))
    jobs = manifest.read(path)
    run_dir = os.path.join(work, "kill_ray", jobs[0].name)
    state = {}

    def arm(actors):
        import ray

        pid = ray.get(actors[0].pid.remote())

        def watch():
            while not os.path.isfile(folder.path(run_dir, "checkpoint")):
                time.sleep(0.02)
            os.kill(pid, signal.SIGKILL)
            state["killed_at_s"] = round(time.perf_counter() - state["start"], 1)

        threading.Thread(target=watch, daemon=True).start()

    state["start"] = time.perf_counter()
    rows = cluster.run(jobs, os.path.join(work, "kill_ray"), {}, workers=1, progress=False,
                       on_started=arm)
    local.run(jobs, os.path.join(work, "kill_local"), {}, progress=False)
    return dict(row_state=rows[0]["state"], killed_at_s=state.get("killed_at_s"),
                metrics_equal_uninterrupted=same_scores(
                    run_dir, os.path.join(work, "kill_local", jobs[0].name)))


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="benchmarks/results/batch")
    args = p.parse_args(argv)
    work = tempfile.mkdtemp(prefix="batch-bench-")
    path = os.path.join(work, "jobs.toml")
    with open(path, "w") as f:
        f.write(manifest_text())
    jobs = manifest.read(path)
    warm = timed(lambda: cli_runs(jobs[:1], os.path.join(work, "warmup")))
    result = dict(machine=machine(), jobs=len(jobs), prompts=list(PROMPTS), seeds=list(SEEDS),
                  warmup_s=warm)
    result["cli_in_a_row_s"] = timed(lambda: cli_runs(jobs, os.path.join(work, "cli")))
    result["batch_local_s"] = timed(lambda: batch_process(path, os.path.join(work, "local")))
    result["ray_2_workers_s"] = timed(lambda: batch_process(
        path, os.path.join(work, "ray2"), "--ray", "--workers", "2"))
    result["ray_1_worker_s"] = timed(lambda: batch_process(
        path, os.path.join(work, "ray1"), "--ray", "--workers", "1"))
    result["speedup_batch_vs_cli"] = round(result["cli_in_a_row_s"] / result["batch_local_s"], 2)
    result["speedup_ray2_vs_batch"] = round(result["batch_local_s"] / result["ray_2_workers_s"],
                                            2)
    result["ray_overhead_per_job_s"] = round(
        (result["ray_1_worker_s"] - result["batch_local_s"]) / len(jobs), 1)
    result["scores_equal"] = {arm: all(same_scores(os.path.join(work, "cli", j.name),
                                                   os.path.join(work, arm, j.name))
                                       for j in jobs) for arm in ("local", "ray2", "ray1")}
    per_job = [folder.read(os.path.join(work, "local", j.name)).metrics["timings"]["total_s"]
               for j in jobs[1:]]  # after the first, which loads and compiles
    result["batch_seconds_per_job_after_the_first"] = round(sum(per_job) / len(per_job), 1)
    result["killed_worker"] = killed_worker(work)
    atomic_write_bytes(args.out + ".json", json.dumps(result, indent=1).encode())
    r = result
    write_report(args.out + ".md", "\n".join([
        "# Batch against CLI runs and Ray", "",
        "Command: `python benchmarks/batch.py`. 8 default jobs (4 instructions x 2 seeds, the "
        "MakeHuman head, 100 iterations), warm caches, every arm in one invocation.", "",
        "| arm | wall s | scores equal to the CLI's |", "| --- | --- | --- |",
        f"| 8 CLI runs in a row | {r['cli_in_a_row_s']} | - |",
        f"| one batch process | {r['batch_local_s']} | {r['scores_equal']['local']} |",
        f"| local Ray, 2 workers | {r['ray_2_workers_s']} | {r['scores_equal']['ray2']} |",
        f"| local Ray, 1 worker | {r['ray_1_worker_s']} | {r['scores_equal']['ray1']} |", "",
        f"Batch against CLI runs: {r['speedup_batch_vs_cli']}x. Ray with 2 workers against the "
        f"local batch: {r['speedup_ray2_vs_batch']}x (the 2 cores are shared by both workers). "
        f"Ray's overhead per job (1 worker against the local batch): "
        f"{r['ray_overhead_per_job_s']} s. A batch job after the first: "
        f"{r['batch_seconds_per_job_after_the_first']} s.", "",
        f"Killed worker: the job ended `{r['killed_worker']['row_state']}` after a kill at "
        f"{r['killed_worker']['killed_at_s']} s; metrics equal to an uninterrupted run: "
        f"{r['killed_worker']['metrics_equal_uninterrupted']}."]) + "\n")
    return result


if __name__ == "__main__":
    main()
