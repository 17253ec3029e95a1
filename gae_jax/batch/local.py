"""A batch in this process: jobs one after another through one `Runner`, a progress bar over
jobs, the summary rewritten after each."""

from __future__ import annotations

from tqdm import tqdm

from gae_jax.batch import summary
from gae_jax.batch.runner import Runner

# What a job's failure may raise without ending the batch: its row carries the message.
JOB_ERRORS = (ValueError, FileNotFoundError, NotADirectoryError, OSError)


def run(jobs: list, out: str, meta: dict, progress: bool = True) -> list:
    """Every job's summary row, in manifest order (failed jobs: `error`)."""
    runner, rows = Runner(), []
    bar = tqdm(jobs, desc="batch", unit="job", disable=not progress)
    for job in bar:
        bar.set_postfix_str(job.name)
        try:
            rows.append(runner.run(job, out))
        except JOB_ERRORS as e:
            rows.append(dict(name=job.name, state="failed", error=f"{type(e).__name__}: {e}"))
        summary.write(out, rows, meta)
    return rows
