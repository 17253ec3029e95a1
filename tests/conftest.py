"""Hardened test settings: two forced CPU devices, strict dtype promotion, rank promotion raises.

x64 is off by default; a test that needs float64 asks for the `x64` fixture.
"""

import os

# Must be set before JAX initialises its backends.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                           + " --xla_force_host_platform_device_count=2").strip()
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# The entry points keep compiled programs in ~/.cache/gae_jax/xla by default; tests that call
# them in-process must not write there (a test that checks the cache names its own folder).
os.environ["GAE_JAX_COMPILE_CACHE"] = "off"

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture
def x64():
    """Runs the test with float64 enabled, restoring the previous setting afterwards."""
    previous = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", previous)
