"""fast_jit adds only backend-appropriate options and computes the same thing as jax.jit."""

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.util import compile as gcompile
from gae_jax.demo import main as demo_main


def test_fast_jit_matches_jit_and_options_are_cpu_only():
    fn = lambda x: jnp.exp(-0.5 * x * x).sum()  # noqa: E731
    x = jnp.linspace(-3, 3, 1000)
    np.testing.assert_allclose(gcompile.fast_jit(fn)(x), jax.jit(fn)(x), rtol=1e-6)
    opts = gcompile.compiler_options()
    assert set(opts) <= set(gcompile.AVX512_OPTIONS)
    if jax.default_backend() != "cpu":
        assert opts == {}


def test_demo_writes_a_png(tmp_path):
    report = demo_main(["--out", str(tmp_path), "--size", "32"])
    data = (tmp_path / "head.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert report["gaussians"] == report["faces"] and report["overflow_tiles"] >= 0
