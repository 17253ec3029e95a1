"""fast_jit computes what jax.jit computes and adds 512-bit vectors exactly on AVX-512 CPUs;
the demo renders the head."""

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
