"""Builds the optional C++ compositor, argsort and tile binning (`gae_jax/render/kernel/*.cc`, see
`gae_jax.render.cpu_kernel`) against the XLA FFI headers that jaxlib ships, and the optional ray
caster (`gae_jax/scene/kernel/raycast_cpu.cc`, see `gae_jax.scene.raycast_kernel`). Everything
else is in pyproject.toml. A failed build is reported and skipped: the package then composites
with its pure-JAX walk and casts rays with embree (slower on CPU, the same results).

GAE_JAX_KERNEL_FLAGS replaces the machine-specific optimisation flags (default
`-O3 -march=native`), e.g. for a wheel built on one machine and run on others.
"""

import os
import shlex
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


def _ffi_include() -> list:
    try:
        import jaxlib
    except ImportError:
        return []
    return [os.path.join(os.path.dirname(jaxlib.__file__), "include")]


class OptionalBuildExt(build_ext):
    """build_ext that warns instead of failing when the kernel cannot be compiled."""

    def run(self):
        try:
            super().run()
        except Exception as error:  # noqa: BLE001 -- any compiler failure means "no kernel"
            self._skip(error)

    def build_extension(self, ext):
        if ext.name == COMPOSITOR and (not INCLUDE or not os.path.isdir(INCLUDE[0])):
            self._skip("jaxlib's FFI headers were not found in the build environment")
            return
        try:
            super().build_extension(ext)
        except Exception as error:  # noqa: BLE001
            self._skip(error, ext.name)

    @staticmethod
    def _skip(why, name=None):
        fallback = {COMPOSITOR: "the C++ compositor kernel is not built; the pure-JAX "
                                "compositor will be used",
                    RAYCASTER: "the C++ ray caster is not built; embree will cast the rays"}
        for ext_name in [name] if name else [COMPOSITOR, RAYCASTER]:
            print(f"gae_jax: {fallback[ext_name]} ({why})", file=sys.stderr)


FLAGS = shlex.split(os.environ.get("GAE_JAX_KERNEL_FLAGS", "-O3 -march=native"))
INCLUDE = _ffi_include()
COMPOSITOR, RAYCASTER = "gae_jax.render._composite_cpu", "gae_jax.scene._raycast_cpu"

setup(
    ext_modules=[Extension(
        COMPOSITOR,
        sources=["gae_jax/render/kernel/composite_cpu.cc", "gae_jax/render/kernel/sort_cpu.cc",
                 "gae_jax/render/kernel/bin_cpu.cc"],
        language="c++",
        # -isystem: the XLA headers' own warnings are not ours.
        extra_compile_args=["-std=c++17", "-fopenmp-simd", "-fno-math-errno",
                            "-fno-trapping-math", "-Wall"]
        + [f"-isystem{path}" for path in INCLUDE] + FLAGS,
        extra_link_args=["-pthread"],
    ), Extension(
        RAYCASTER,
        sources=["gae_jax/scene/kernel/raycast_cpu.cc"],
        language="c++",
        # No fused multiply-adds: a shared edge's cross products must be exact negatives.
        extra_compile_args=["-std=c++17", "-fno-math-errno", "-ffp-contract=off", "-Wall"]
        + FLAGS,
    )],
    cmdclass={"build_ext": OptionalBuildExt},
)
