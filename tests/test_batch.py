"""`python -m gae_jax.batch`: manifests, the local batch against the CLI, a local Ray against
the local batch, and a Ray worker killed in the middle of a job."""

import json
import os
import signal
import threading
import time

import numpy as np
import pytest

from gae_jax import train
from gae_jax.batch import __main__ as batch_cli
from gae_jax.batch import cluster, local, manifest
from gae_jax.run import folder

TINY = """
[defaults]
head = "procedural"
size = 32
reconstruct_iterations = 20
iterations = 3
video = false
"""


def write(tmp_path, text: str, name: str = "jobs.toml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def scores(run_dir) -> dict:
    """Every number of a run's evaluation, flattened."""
    def flat(d, pre=""):
        out = {}
        for k, v in d.items():
            if isinstance(v, dict):
                out.update(flat(v, f"{pre}{k}/"))
            elif isinstance(v, (int, float)):
                out[pre + k] = v
        return out

    return flat(folder.read(str(run_dir)).metrics["evaluation"])


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache folder for the module (scene and avatar built once), set for Ray's workers
    too (they inherit GAE_JAX_* from the driver)."""
    path = str(tmp_path_factory.mktemp("cache"))
    old = os.environ.get("GAE_JAX_CACHE")
    os.environ["GAE_JAX_CACHE"] = path
    yield path
    if old is None:
        del os.environ["GAE_JAX_CACHE"]
    else:
        os.environ["GAE_JAX_CACHE"] = old


def test_a_list_expands_the_entry_into_a_grid_of_named_jobs(tmp_path):
    jobs = manifest.read(write(tmp_path, TINY + """
[[jobs]]
name = "colours"
prompt = ["turn the lips blue", "make the hair ginger"]
seed = [0, 1]

[[jobs]]
prompt = "make the teeth black"
iterations = 5
"""))
    assert [j.name for j in jobs] == [
        "colours_turn-the-lips-blue_seed0", "colours_turn-the-lips-blue_seed1",
        "colours_make-the-hair-ginger_seed0", "colours_make-the-hair-ginger_seed1", "job2"]
    assert [(j.config.prompt, j.config.seed) for j in jobs[:2]] == [
        ("turn the lips blue", 0), ("turn the lips blue", 1)]
    assert all(j.scene.head == "procedural" and j.scene.size == 32 and not j.video for j in jobs)
    assert jobs[0].config.iterations == 3 and jobs[4].config.iterations == 5
    again = manifest.Job.from_description(json.loads(json.dumps(jobs[0].describe())))
    assert again == jobs[0]


@pytest.mark.parametrize("body, message", [
    ('[[jobs]]\nname = "a"\niteratons = 5\n', "job 'a': unknown field 'iteratons'"),
    ('[[jobs]]\nname = "a"\niterations = "many"\n', "job 'a': iterations: 'many' is not an "
                                                    "integer"),
    ('[[jobs]]\nname = "a"\niterations = 0\n', "job 'a': iterations"),
    ('[[jobs]]\nname = "a"\nhead = "robot"\n', "job 'a': unknown head 'robot'"),
    ('[[jobs]]\nname = "a"\nprompt = "make him taller"\nseed = [1, 2]\nseed2 = 1\n',
     "job 'a': unknown field 'seed2'"),
    ('[[jobs]]\nname = "a"\ndata = "nowhere"\n', "job 'a': data: "),
    ('[[jobs]]\nname = "a"\navatar = "."\n', "job 'a': avatar: "),
    ('[[jobs]]\nname = "a"\nseed = []\n', "job 'a': seed: an empty list"),
    ('[[jobs]]\nname = "a"\n[[jobs]]\nname = "a"\n', "two jobs are named 'a'"),
    ('[job]\nname = "a"\n', "unknown table 'job'"),
    ('[[jobs]\n', "not TOML"),
])
def test_a_bad_manifest_gets_one_line_naming_the_job_and_the_field(tmp_path, capsys, body,
                                                                     message):
    path = write(tmp_path, body)
    assert batch_cli.main([path, "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_the_local_batch_writes_run_folders_the_cli_would_and_never_reruns_them(
        tmp_path, cache, capsys):
    path = write(tmp_path, TINY + """
[[jobs]]
name = "t"
prompt = ["turn the lips blue", "make the hair ginger"]
""")
    out = tmp_path / "out"
    assert batch_cli.main([path, "--out", str(out)]) == 0
    run_dir = out / "t_turn-the-lips-blue"
    assert train.main(["--head", "procedural", "--size", "32", "--reconstruct-iterations", "20",
                       "--iterations", "3", "--no-video", "--out", str(tmp_path / "cli")]) == 0
    assert scores(run_dir) == scores(tmp_path / "cli")
    summary = json.loads((out / "summary.json").read_text())
    assert [r["state"] for r in summary["jobs"]] == ["ran", "ran"]
    assert (out / "summary.md").is_file() and (out / "summary.png").is_file()
    stamp = os.path.getmtime(folder.path(str(run_dir), "metrics"))
    capsys.readouterr()
    assert batch_cli.main([path, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [r["state"] for r in summary["jobs"]] == ["done before", "done before"]
    assert os.path.getmtime(folder.path(str(run_dir), "metrics")) == stamp
    other = write(tmp_path, TINY.replace("iterations = 3", "iterations = 4") + """
[[jobs]]
name = "t"
prompt = ["turn the lips blue", "make the hair ginger"]
""", "changed.toml")
    rows = local.run(manifest.read(other), str(out), {}, progress=False)
    assert all("holds another job's run" in r["error"] for r in rows)


@pytest.fixture(scope="module")
def ray_local(cache):
    pytest.importorskip("ray")
    ray, started = cluster.start(num_cpus=2)  # the workers see GAE_JAX_CACHE (`cache`)
    yield ray
    if started:
        ray.shutdown()


def test_a_local_ray_runs_the_jobs_as_the_local_batch_does(tmp_path, cache, ray_local):
    jobs = manifest.read(write(tmp_path, TINY + """
[[jobs]]
name = "r"
prompt = ["turn the lips blue", "make the eyebrows white", "make the skin pale"]
"""))
    local.run(jobs, str(tmp_path / "local"), {}, progress=False)
    rows = cluster.run(jobs, str(tmp_path / "ray"), {}, workers=2, progress=False)
    assert [r["state"] for r in rows] == ["ran"] * 3
    for job in jobs:
        here = folder.read(str(tmp_path / "local" / job.name)).metrics
        there = folder.read(str(tmp_path / "ray" / job.name)).metrics
        assert here["evaluation"] == there["evaluation"], job.name
        assert here["config"] == there["config"] and here["scene"] == there["scene"]
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert [r["name"] for r in summary["jobs"]] == [j.name for j in jobs]


def test_a_worker_killed_mid_job_is_restarted_and_the_job_resumes_to_the_same_result(
        tmp_path, cache, ray_local):
    jobs = manifest.read(write(tmp_path, TINY.replace("iterations = 3", "iterations = 240") + """
checkpoint_every = 5

[[jobs]]
name = "k"
prompt = "turn the lips blue"
"""))
    run_dir = tmp_path / "ray" / jobs[0].name
    killed = {}

    def kill_when_checkpointed(actors):
        pid = ray_local.get(actors[0].pid.remote())

        def watch():
            deadline = time.time() + 300
            while time.time() < deadline:
                if os.path.isfile(folder.path(str(run_dir), "checkpoint")):
                    os.kill(pid, signal.SIGKILL)
                    killed["pid"] = pid
                    return
                time.sleep(0.02)

        threading.Thread(target=watch, daemon=True).start()

    rows = cluster.run(jobs, str(tmp_path / "ray"), {}, workers=1, progress=False,
                       on_started=kill_when_checkpointed)
    assert killed and rows[0]["state"] == "resumed", rows
    local.run(jobs, str(tmp_path / "local"), {}, progress=False)
    resumed, straight = scores(run_dir), scores(tmp_path / "local" / jobs[0].name)
    assert resumed.keys() == straight.keys()
    np.testing.assert_array_equal([resumed[k] for k in straight], list(straight.values()))
