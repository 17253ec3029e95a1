"""fast_jit computes what jax.jit computes and adds 512-bit vectors exactly on AVX-512 CPUs;
the demo renders the head; every entry point turns the persistent compilation cache on, and a
second process then compiles nothing new."""

import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.demo import main as demo_main
from gae_jax.util import compile as gcompile


def test_fast_jit_matches_jit():
    fn = lambda x: jnp.exp(-0.5 * x * x).sum()  # noqa: E731
    x = jnp.linspace(-3, 3, 1000)
    np.testing.assert_allclose(gcompile.fast_jit(fn)(x), jax.jit(fn)(x), rtol=1e-6)


def test_options_follow_the_cpu_flags(monkeypatch):
    monkeypatch.setattr(gcompile, "_cpu_has_avx512", lambda: True)
    expected = gcompile.AVX512_OPTIONS if jax.default_backend() == "cpu" else {}
    assert gcompile.compiler_options() == expected
    monkeypatch.setattr(gcompile, "_cpu_has_avx512", lambda: False)
    assert gcompile.compiler_options() == {}


@pytest.mark.parametrize("kind", ["procedural", "makehuman"])
def test_demo_writes_the_head_without_overflow(tmp_path, kind):
    report = demo_main(["--out", str(tmp_path), "--size", "32", "--head", kind])
    data = (tmp_path / "head.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert report["gaussians"] == report["faces"] and report["overflow_tiles"] == 0


PROGRAM = """
import sys
import jax, jax.numpy as jnp
from gae_jax import cli
cli.prepare_process(sys.argv[1])
# The cache skips programs that compile in under CACHE_MIN_COMPILE_SECONDS; this one takes about
# that long on an idle machine, so the threshold is lifted here: the test is about the cache.
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

@jax.jit
def chain(x):
    for i in range(300):
        x = jnp.sin(x) * 1.01 + i
    return x

chain(jnp.ones(64)).block_until_ready()
"""


def test_a_second_run_loads_its_programs_from_the_compilation_cache(tmp_path):
    import subprocess
    import sys

    cache = tmp_path / "xla"

    def run():
        subprocess.run([sys.executable, "-c", PROGRAM, str(cache)], check=True,
                       capture_output=True, cwd=os.getcwd())
        return sorted(os.listdir(cache))

    first = run()
    assert any(name.startswith("jit_chain") for name in first), first
    assert run() == first  # the program came from the cache: nothing new was written


def test_every_entry_point_prepares_its_process(monkeypatch, tmp_path):
    from gae_jax import cli, evaluate, reconstruct, train, view
    from gae_jax.batch import __main__ as batch

    calls = []

    def record(choice):
        calls.append(choice)
        raise SystemExit(0)  # stop before any work

    monkeypatch.setattr(cli, "prepare_process", record)
    entries = (train, reconstruct, evaluate, view, batch, __import__("gae_jax.demo").demo)
    for entry in entries:
        argv = ["--compile-cache", str(tmp_path)] + {evaluate: ["x"], reconstruct: [
            "--out", str(tmp_path / "out")], batch: ["jobs.toml", "--out", str(tmp_path / "out")]
        }.get(entry, [])
        with pytest.raises(SystemExit):
            entry.main(argv)
    assert calls == [str(tmp_path)] * len(entries)


def test_the_compilation_cache_flag_and_environment_choose_the_folder(monkeypatch, tmp_path):
    from gae_jax import cli

    monkeypatch.setenv("GAE_JAX_CACHE", str(tmp_path))
    monkeypatch.delenv("GAE_JAX_COMPILE_CACHE")
    assert cli.compile_cache_folder(None) == os.path.join(str(tmp_path), "xla")
    assert cli.compile_cache_folder("off") is None
    assert cli.compile_cache_folder(str(tmp_path / "mine")) == str(tmp_path / "mine")
    monkeypatch.setenv("GAE_JAX_COMPILE_CACHE", "off")
    assert cli.compile_cache_folder(None) is None
