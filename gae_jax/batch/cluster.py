"""A batch on Ray (the optional `cluster` extra): one actor per worker slot, each a `Runner`
that keeps its scene, original avatar and compiled programs between the jobs it is given; one
task per job with the job's resources; a worker that dies is restarted and its job retried,
resuming from the job folder's checkpoint; rows stream into the summary as jobs finish.

Without an address a local Ray is started (and stopped) here; with one, the cluster's nodes
must see `out` at the same path (a shared file system), as they write the run folders.
"""

from __future__ import annotations

import os
import warnings

from tqdm import tqdm

from gae_jax.batch import summary
from gae_jax.batch.manifest import Job
from gae_jax.batch.runner import Runner

ENV_PREFIXES = ("GAE_JAX_", "XLA_", "JAX_")  # what workers must see of the driver's environment


class Worker:
    """The actor: a `Runner` kept for the actor's life."""

    def __init__(self):
        self.runner = Runner()

    def run(self, description: dict, out: str) -> dict:
        return self.runner.run(Job.from_description(description), out)

    def pid(self) -> int:
        return os.getpid()


def import_ray():
    try:
        import ray
    except ImportError:
        raise ValueError("--ray needs Ray: pip install 'gae-jax[cluster]'") from None
    return ray


def start(address: str = "", num_cpus: int | None = None):
    """Ray, connected to `address` or to a local Ray started here (`num_cpus` cores); whether
    this call started it (then `ray.shutdown()` is the caller's)."""
    ray = import_ray()
    if ray.is_initialized():
        return ray, False
    env = {k: v for k, v in os.environ.items() if k.startswith(ENV_PREFIXES)}
    with warnings.catch_warnings():
        # Ray starts its processes with fork + exec; no Python (nor JAX) runs in the child
        # before exec, so JAX's warning about forking a multithreaded process does not apply.
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called",
                                category=RuntimeWarning)
        ray.init(address=address or None, num_cpus=None if address else num_cpus,
                 include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": env} if env else None)
    return ray, True


def make_workers(ray, count: int, cpus_per_job: float, gpus_per_job: float, retries: int):
    """`count` Worker actors with one job's resources each, restarted when they die."""
    actor = ray.remote(num_cpus=cpus_per_job, num_gpus=gpus_per_job, max_restarts=-1,
                       max_task_retries=retries)(Worker)
    return [actor.remote() for _ in range(count)]


def run(jobs: list, out: str, meta: dict, address: str = "", cpus_per_job: float = 1.0,
        gpus_per_job: float = 0.0, workers: int = 0, retries: int = 3, num_cpus=None,
        progress: bool = True, on_started=None) -> list:
    """Every job's summary row, in manifest order. `workers` 0: as many as the cluster's CPUs
    (and GPUs) allow one job each; `on_started(actors)` sees the actors once they exist."""
    ray, started = start(address, num_cpus)
    try:
        resources = ray.cluster_resources()
        slots = int(resources.get("CPU", 1) // max(cpus_per_job, 1e-9))
        if gpus_per_job:
            slots = min(slots, int(resources.get("GPU", 0) // gpus_per_job))
        count = max(1, min(workers or slots, len(jobs)))
        actors = make_workers(ray, count, cpus_per_job, gpus_per_job, retries)
        if on_started is not None:
            on_started(actors)
        queue, pending, rows = list(jobs), {}, {}
        bar = tqdm(total=len(jobs), desc="batch (ray)", unit="job", disable=not progress)

        def submit(actor):
            if queue:
                job = queue.pop(0)
                pending[actor.run.remote(job.describe(), os.path.abspath(out))] = (actor, job)

        for actor in actors:
            submit(actor)
        while pending:
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            actor, job = pending.pop(ref)
            try:
                rows[job.name] = ray.get(ref)
            except ray.exceptions.RayError as e:
                cause = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
                rows[job.name] = dict(name=job.name, state="failed", error=cause)
            bar.update(1)
            summary.write(out, [rows[j.name] for j in jobs if j.name in rows], meta)
            submit(actor)
        bar.close()
        return [rows[j.name] for j in jobs]
    finally:
        if started:
            ray.shutdown()
