"""`fast_jit`: `jax.jit` plus backend-specific compiler options that speed up the renderer;
`use_persistent_cache`: JAX's on-disk cache of compiled programs, which the entry points turn on.

On CPUs with AVX-512, XLA's CPU backend still prefers 256-bit vectors by default; asking for
512-bit vectors speeds the compositor's exp-heavy loops by ~1.3x (measured side by side by
`benchmarks/render.py`, which runs both). The option is per compilation (no global state, no
environment variables) and is only added when the default backend is the CPU, so the same code
runs unchanged on GPU/TPU.
"""

from __future__ import annotations

import functools
import os

import jax

AVX512_OPTIONS = {"xla_cpu_prefer_vector_width": 512}


@functools.lru_cache(maxsize=None)
def _cpu_has_avx512() -> bool:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="ignore") as f:
            for line in f:
                if line.startswith("flags"):
                    return "avx512f" in line.split()
    except OSError:
        pass
    return False


def compiler_options() -> dict:
    """Options for the default backend: 512-bit vectors on AVX-512 CPUs, nothing elsewhere."""
    if jax.default_backend() == "cpu" and _cpu_has_avx512():
        return dict(AVX512_OPTIONS)
    return {}


def fast_jit(fun=None, **jit_kwargs):
    """`jax.jit(fun, **jit_kwargs)` with `compiler_options()` merged in (caller's keys win)."""
    if fun is None:
        return functools.partial(fast_jit, **jit_kwargs)
    options = {**compiler_options(), **(jit_kwargs.pop("compiler_options", None) or {})}
    return jax.jit(fun, compiler_options=options or None, **jit_kwargs)


# Programs that compile faster than this are not worth a disk round trip (loading one takes
# ~20 ms; LBS, the posing of the Gaussians and LPIPS compile in 0.3-0.45 s each).
CACHE_MIN_COMPILE_SECONDS = 0.1


def use_persistent_cache(folder: str | None) -> None:
    """Turns JAX's persistent compilation cache on in `folder` (None: leaves it off).

    A process-wide JAX setting, so only entry points call it (before their first compilation):
    a second run of the same job then loads its fit, edit and render programs from disk instead
    of compiling them. The cache key covers the program, the compiler options, the JAX version
    and the device; a folder shared between machines of different CPU features should not be
    used (XLA:CPU compiles for the host's instruction set).
    """
    if folder is None:
        return
    os.makedirs(folder, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_SECONDS)
