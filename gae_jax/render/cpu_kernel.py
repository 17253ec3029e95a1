"""The C++ compositor (`kernel/composite_cpu.cc`), argsort (`kernel/sort_cpu.cc`) and tile
binning (`kernel/bin_cpu.cc`), called through the XLA FFI on CPU.

`pip install` compiles it into `gae_jax/render/_composite_cpu*.so` (see `setup.py`); when it is
not built, or cannot be loaded, `available()` is False and `composite` uses its pure-JAX walk,
which is also the path on GPU/TPU and in float64. The kernel computes what
`composite._composite_fwd` / `_composite_bwd` compute, per tile (threaded over tiles, the 256
pixels of a tile as SIMD lanes); per-slot outputs are scattered to Gaussians by the caller.

`forward` and `backward` take and return per-tile arrays exactly as the pure-JAX path lays them
out (see `composite`); both are float32 only.
"""

from __future__ import annotations

import ctypes
import functools
import importlib.util
import time

import jax
import jax.numpy as jnp
import numpy as np

MODULE = "gae_jax.render._composite_cpu"
FORWARD_TARGET = "gae_jax_composite_forward"
BACKWARD_TARGET = "gae_jax_composite_backward"
ARGSORT_TARGET = "gae_jax_argsort_int32"
BIN_TARGET = "gae_jax_bin_tiles"
MODE_CODES = {"standard": 0, "wabe": 1, "wabe_grad": 2}
PIXELS_PER_TILE = 256


@functools.cache
def _open() -> tuple:
    """Loads and registers the kernel once per process: (the library, None) on success, else
    (None, why not)."""
    spec = importlib.util.find_spec(MODULE)
    if spec is None or not spec.origin:
        return None, "not built (reinstall with `pip install -e .` and a C++17 compiler)"
    try:
        library = ctypes.CDLL(spec.origin)
        jax.ffi.register_ffi_target(FORWARD_TARGET, jax.ffi.pycapsule(library.GaeCompositeForward),
                                    platform="cpu")
        jax.ffi.register_ffi_target(BACKWARD_TARGET,
                                    jax.ffi.pycapsule(library.GaeCompositeBackward),
                                    platform="cpu")
        jax.ffi.register_ffi_target(ARGSORT_TARGET, jax.ffi.pycapsule(library.GaeArgsortInt32),
                                    platform="cpu")
        jax.ffi.register_ffi_target(BIN_TARGET, jax.ffi.pycapsule(library.GaeBinTiles),
                                    platform="cpu")
    except (OSError, AttributeError, RuntimeError, ValueError) as error:
        return None, f"{spec.origin} did not load: {error}"
    return library, None


def _load() -> str | None:
    """None when the kernel is loaded and registered, else why not."""
    return _open()[1]


def exp_rate(threads: int = 0, rounds: int = 100_000, repeats: int = 5,
             pause_s: float = 0.2) -> float:
    """The compositor's own exp (the kernel's `fast_exp`, at its SIMD width) in evaluations per
    second on `threads` workers (0: every hardware thread), best of `repeats` runs of `rounds`
    x 256 per worker, `pause_s` apart: the arithmetic bound of a compositor that needs one exp
    per (pixel, Gaussian) pair, measured with the kernel's own code and flags. (Right after
    other work, thread pools still spinning on a core can halve a single run.)"""
    _require()
    probe = _open()[0].GaeExpRate
    probe.restype = ctypes.c_double
    probe.argtypes = [ctypes.c_int32, ctypes.c_int64, ctypes.POINTER(ctypes.c_float)]
    checksum = ctypes.c_float()
    rates = []
    for _ in range(repeats):
        time.sleep(pause_s)
        rates.append(probe(threads, rounds, ctypes.byref(checksum)))
    if not np.isfinite(checksum.value):
        raise RuntimeError("the exp probe's results are not finite")
    return max(rates)


def available() -> bool:
    """True when the kernel is built and registered with XLA's CPU backend."""
    return _load() is None


def unavailable_reason() -> str | None:
    """Why `available()` is False (None when it is True)."""
    return _load()


def _require() -> None:
    reason = _load()
    if reason is not None:
        raise RuntimeError(f"the CPU compositor kernel is {reason}")


def _attributes(cfg) -> dict:
    _require()
    return dict(alpha_clamp=np.float32(cfg.alpha_clamp), mode=np.int32(MODE_CODES[cfg.blend.mode]),
                beta=np.float32(cfg.blend.beta), tiles_x=np.int64(cfg.tiles_x),
                threads=np.int32(cfg.kernel_threads))


def forward(cfg, table: jax.Array, kept: jax.Array, packed: jax.Array):
    """Front-to-back walk of every tile.

    Args:
      cfg: `composite.CompositeConfig`; table (T, cap) int32; kept (T,) int32; packed (N, 7 + C)
        float32.
    Returns color (T, 256, C), transmittance (T, 256), depth (T, 256), last (T, 256) int32 (one
    past each pixel's last composited slot), and per slot (T, cap): pixels composited and the
    visibility weight (max over pixels; zeros when cfg.front_contributors is 0).
    """
    num_tiles, cap = table.shape
    num_channels = packed.shape[1] - 7
    f32 = jnp.float32
    out_types = (jax.ShapeDtypeStruct((num_tiles, PIXELS_PER_TILE, num_channels), f32),
                 jax.ShapeDtypeStruct((num_tiles, PIXELS_PER_TILE), f32),
                 jax.ShapeDtypeStruct((num_tiles, PIXELS_PER_TILE), f32),
                 jax.ShapeDtypeStruct((num_tiles, PIXELS_PER_TILE), jnp.int32),
                 jax.ShapeDtypeStruct((num_tiles, cap), f32),
                 jax.ShapeDtypeStruct((num_tiles, cap), f32))
    call = jax.ffi.ffi_call(FORWARD_TARGET, out_types, vmap_method="sequential")
    return call(table, kept, packed, front_contributors=np.int32(cfg.front_contributors),
                visibility_beta=np.float32(cfg.visibility_beta), **_attributes(cfg))


def backward(cfg, table, kept, packed, t_final, last, g_color, g_transmittance, g_depth):
    """Back-to-front gradient walk of every tile.

    Args: as `forward`, plus the forward's transmittance and last (T, 256) and the cotangents of
      color (T, 256, C), transmittance and depth (T, 256).
    Returns (T, cap, 7 + C) per-slot gradients of the packed parameters (zeros at unused slots).
    """
    num_tiles, cap = table.shape
    out_type = jax.ShapeDtypeStruct((num_tiles, cap, packed.shape[1]), jnp.float32)
    call = jax.ffi.ffi_call(BACKWARD_TARGET, out_type, vmap_method="sequential")
    return call(table, kept, packed, t_final, last, g_color, g_transmittance, g_depth,
                **_attributes(cfg))


def argsort(keys: jax.Array) -> jax.Array:
    """(N,) int32 stable argsort of (N,) int32 keys (ties by index), as
    `lax.sort((keys, iota), num_keys=1, is_stable=True)[1]`."""
    _require()
    call = jax.ffi.ffi_call(ARGSORT_TARGET, jax.ShapeDtypeStruct(keys.shape, jnp.int32),
                            vmap_method="sequential")
    return call(keys)


def bin_tiles(x0, x1, y0, y1, order, tiles_x: int, num_tiles: int, capacity: int, budget: int):
    """Per-tile lists of Gaussians in depth order, as `tiles.bin_gaussians` builds them.

    Args:
      x0, x1, y0, y1: (N,) int32 inclusive tile ranges (empty when x1 < x0 or y1 < y0);
      order: (N,) int32 depth order; budget: pairs kept in all, counted nearest first.
    Returns table (num_tiles, capacity) int32 (-1 padding) and (num_tiles,) int32 pairs of the
    budget per tile (before the capacity).
    """
    _require()
    out_types = (jax.ShapeDtypeStruct((num_tiles, capacity), jnp.int32),
                 jax.ShapeDtypeStruct((num_tiles,), jnp.int32))
    call = jax.ffi.ffi_call(BIN_TARGET, out_types, vmap_method="sequential")
    return call(x0, x1, y0, y1, order, tiles_x=np.int64(tiles_x), budget=np.int64(budget))
