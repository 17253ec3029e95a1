"""Running batch jobs in one process: the scene, the original avatar and every compiled program
are kept between jobs, and each job writes an ordinary run folder (`run/folder.py`).

A job whose folder holds finished metrics is not run again (the folder is the record); one
whose folder holds an edit checkpoint resumes from it; a folder written for another job is
refused.
"""

from __future__ import annotations

import dataclasses
import os
import time

from gae_jax.batch.manifest import Job
from gae_jax.edit.config import preset
from gae_jax.evaluation import protocols
from gae_jax.model import avatar_io
from gae_jax.run import folder
from gae_jax.run import job as run_job
from gae_jax.run.original import original_avatar
from gae_jax.scene.load import SceneConfig, load_scene


def status(run_dir: str) -> str:
    """"done" (metrics written), "interrupted" (an edit checkpoint) or "new"."""
    if os.path.isfile(folder.path(run_dir, "metrics")):
        return "done"
    if os.path.isfile(folder.path(run_dir, "checkpoint")):
        return "interrupted"
    return "new"


def scores(metrics: dict) -> dict:
    """The summary's numbers of one run: PSNR of the edited region, the whole image and the
    untouched avatar's edited region, each the mean over the protocols (None where a run has
    no ideal), and its seconds."""
    def mean(who: str, region: str):
        values = [metrics["evaluation"][p][who]["psnr"].get(region)
                  for p in protocols.PROTOCOLS if p in metrics.get("evaluation", {})]
        values = [v for v in values if v is not None]
        return round(sum(values) / len(values), 3) if values else None

    return dict(edited=mean("ours", "edited"), whole=mean("ours", "whole"),
                untouched=mean("original_avatar", "edited"),
                seconds=metrics.get("timings", {}).get("total_s"))


class Runner:
    """Runs `Job`s into `out/<job name>/`, keeping what jobs share between them."""

    def __init__(self, progress: bool = False):
        self.progress = progress
        self.scenes: dict = {}
        self.originals: dict = {}
        self.shared: dict = {}  # compiled programs and evaluation sets (`run.job.run`)

    def scene(self, job: Job):
        if job.scene not in self.scenes:
            self.scenes[job.scene] = load_scene(job.scene, progress=self.progress)
        return self.scenes[job.scene]

    def original(self, job: Job, scene):
        key = (job.scene, job.avatar or job.config.reconstruct_iterations)
        if key not in self.originals:
            self.originals[key] = (
                avatar_io.load_bound_avatar(folder.avatar_file(job.avatar), scene.face_regions)
                if job.avatar else
                original_avatar(scene, job.config.reconstruct_iterations, self.progress))
        return self.originals[key]

    def run(self, job: Job, out: str) -> dict:
        """Runs `job` unless its folder is finished; its summary row (`record`)."""
        run_dir = os.path.join(out, job.name)
        state = status(run_dir)
        recorded = folder.read_job(run_dir)
        if recorded is not None and recorded != job.describe():
            raise ValueError(f"{run_dir}: holds another job's run (its job.json differs); "
                             "rename the job or remove the folder")
        if state == "done":
            return record(job, run_dir, "done before", folder.read(run_dir).metrics)
        start = time.perf_counter()
        os.makedirs(run_dir, exist_ok=True)
        folder.write_job(run_dir, job.describe())
        scene = self.scene(job)
        original = self.original(job, scene)
        params = os.path.join(job.avatar, "flame_param.npz") if job.avatar else ""
        extra = avatar_io.extra_flame_params(params) if params and os.path.isfile(params) else None
        metrics = run_job.run(job.config, run_dir, scene, original,
                              resume=state == "interrupted", progress=self.progress,
                              video=job.video, scene_config=job.scene, avatar_extra=extra,
                              shared=self.shared)
        row = record(job, run_dir, "resumed" if state == "interrupted" else "ran", metrics)
        row["wall_s"] = round(time.perf_counter() - start, 1)
        return row


def record(job: Job, run_dir: str, state: str, metrics: dict) -> dict:
    """A job's row of the batch summary."""
    return dict(name=job.name, folder=run_dir, state=state, prompt=job.config.prompt,
                seed=job.config.seed, settings=_differences(job), **scores(metrics))


def _differences(job: Job) -> dict:
    """The job's settings that differ from the CLI's defaults (what sets it apart)."""
    out = {k: v for k, v in dataclasses.asdict(job.scene).items()
           if v != getattr(SceneConfig(), k)}
    out.update({k: v for k, v in dataclasses.asdict(job.config).items()
                if v != getattr(preset("fast"), k) and k not in ("prompt", "seed")})
    if job.avatar:
        out["avatar"] = job.avatar
    return out
