"""The discriminator's convolution: 4x4 kernel, padding 1, stride 1 or 2, NHWC / HWIO, with a
VJP that XLA:CPU runs at about its forward's speed.

The forward is `lax.conv_general_dilated`. Its automatic transpose is what is slow on CPU: the
input gradient of a stride-2 convolution is a convolution of the output gradient dilated by 2
(`lhs_dilation`), which XLA:CPU runs at a third of the forward's rate (at 512 px, the PatchGAN's
64->128 layer: 72 ms against 26 for its forward), and the kernel gradient of a one-channel output
is a correlation with a (Ho, Wo) kernel that it runs at ~1 GFLOP/s. Here:

  * input gradient, stride 2, by phases: x[2m + 1] receives w[2] g[m] + w[0] g[m + 1] and
    x[2m + 2] receives w[3] g[m] + w[1] g[m + 1] (per axis), so one stride-1 2x2 convolution of
    the zero-bordered output gradient with the four phases' kernels side by side
    (Cout -> 4 Cin channels), then depth-to-space, gives every row and column of x;
  * input gradient, stride 1: the full correlation with the flipped kernel (padding 2), which is
    what XLA would do, written out;
  * kernel gradient: XLA's own, except for one output channel, where it is 16 reductions of the
    shifted padded input against the output gradient.

Every path is tested against the automatic VJP of `lax.conv_general_dilated` and in float64 by
`check_grads` (`tests/test_patchconv.py`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

KERNEL = 4
PAD = 1
STRIDES = (1, 2)
_DIMENSIONS = ("NHWC", "HWIO", "NHWC")
# phase (0: odd rows 2m+1, 1: even rows 2m+2) x window position (g[m], g[m+1]) -> kernel row
_PHASE_TAPS = ((2, 0), (3, 1))


def output_size(size: int, stride: int) -> int:
    """Output side for an input side `size` (k 4, padding 1)."""
    return (size + 2 * PAD - KERNEL) // stride + 1


def _check(x: jax.Array, kernel: jax.Array, stride: int) -> None:
    if stride not in STRIDES:
        raise ValueError(f"stride must be one of {STRIDES}, got {stride}")
    if x.ndim != 4 or kernel.shape[:2] != (KERNEL, KERNEL) or kernel.shape[2] != x.shape[-1]:
        raise ValueError(f"expected x (B, H, W, Cin) and kernel (4, 4, Cin, Cout), got "
                         f"{x.shape} and {kernel.shape}")


def _forward(x, kernel, stride):
    return lax.conv_general_dilated(x, kernel, (stride, stride), ((PAD, PAD), (PAD, PAD)),
                                    dimension_numbers=_DIMENSIONS)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def conv(x: jax.Array, kernel: jax.Array, stride: int) -> jax.Array:
    """x (B, H, W, Cin), kernel (4, 4, Cin, Cout) -> (B, Ho, Wo, Cout), Ho = (H - 2) // s + 1,
    y[o] = sum_k x[s o + k - 1] kernel[k] (zero outside x), no bias."""
    _check(x, kernel, stride)
    return _forward(x, kernel, stride)


def _conv_fwd(x, kernel, stride):
    _check(x, kernel, stride)
    return _forward(x, kernel, stride), (x, kernel)


def _conv_bwd(stride, residuals, g):
    x, kernel = residuals
    if stride == 2:
        dx = input_grad_stride2(g, kernel, x.shape[1:3])
    else:
        dx = input_grad_stride1(g, kernel)
    return dx, kernel_grad(x, g, stride)


conv.defvjp(_conv_fwd, _conv_bwd)


def input_grad_stride1(g: jax.Array, kernel: jax.Array) -> jax.Array:
    """Cotangent of x for stride 1: g (B, Ho, Wo, Cout) -> (B, Ho + 1, Wo + 1, Cin)."""
    flipped = jnp.swapaxes(kernel[::-1, ::-1], 2, 3)
    pad = KERNEL - 1 - PAD
    return lax.conv_general_dilated(g, flipped, (1, 1), ((pad, pad), (pad, pad)),
                                    dimension_numbers=_DIMENSIONS)


def input_grad_stride2(g: jax.Array, kernel: jax.Array, size: tuple) -> jax.Array:
    """Cotangent of x for stride 2: g (B, Ho, Wo, Cout) -> (B, H, W, Cin), (H, W) = `size`
    (Ho = H // 2). One stride-1 2x2 convolution over g with a zero border yields, at window m
    (m = -1 .. Ho - 1), rows 2m + 1 and 2m + 2 of the cotangent; rows -1 and 2 Ho are cut."""
    batch, rows, cols, _ = g.shape
    cin = kernel.shape[2]
    taps = jnp.asarray(_PHASE_TAPS)
    # (phase y, window y, phase x, window x, Cin, Cout) -> (window y, window x, Cout, 4 Cin)
    phases = kernel[taps[:, :, None, None], taps[None, None, :, :]]
    phases = phases.transpose(1, 3, 5, 0, 2, 4).reshape(2, 2, -1, 4 * cin)
    bordered = jnp.pad(g, ((0, 0), (1, 1), (1, 1), (0, 0)))
    out = lax.conv_general_dilated(bordered, phases, (1, 1), "VALID",
                                   dimension_numbers=_DIMENSIONS)
    out = out.reshape(batch, rows + 1, cols + 1, 2, 2, cin).transpose(0, 1, 3, 2, 4, 5)
    out = out.reshape(batch, 2 * rows + 2, 2 * cols + 2, cin)
    return out[:, 1:1 + size[0], 1:1 + size[1]]


def kernel_grad(x: jax.Array, g: jax.Array, stride: int) -> jax.Array:
    """Cotangent of the kernel: x (B, H, W, Cin), g (B, Ho, Wo, Cout) -> (4, 4, Cin, Cout)."""
    if g.shape[-1] == 1:
        bordered = jnp.pad(x, ((0, 0), (PAD, PAD), (PAD, PAD), (0, 0)))
        rows, cols = g.shape[1:3]
        span = lambda k, n: slice(k, k + stride * (n - 1) + 1, stride)  # noqa: E731
        taps = [jnp.einsum("bhwc,bhwo->co", bordered[:, span(ky, rows), span(kx, cols)], g)
                for ky in range(KERNEL) for kx in range(KERNEL)]
        return jnp.stack(taps).reshape(KERNEL, KERNEL, x.shape[-1], 1)
    # the convolution is linear in the kernel: any point serves to linearise it
    kernel = jnp.zeros((KERNEL, KERNEL, x.shape[-1], g.shape[-1]), g.dtype)
    _, pullback = jax.vjp(lambda k: _forward(x, k, stride), kernel)
    return pullback(g)[0]
