"""Real spherical harmonics up to degree 3, in the basis and sign convention of 3DGS.

Coefficients are stored as (N, K, C) with K = (degree + 1)^2 in the order
l=0; l=1: m=-1,0,1; l=2: m=-2..2; l=3: m=-3..3, evaluated at unit view directions (x, y, z).
3DGS adds 0.5 to the result and clamps at 0; that happens in `splat`, not here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
      -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
      -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def num_coefficients(degree: int) -> int:
    """(degree + 1)^2 coefficients per channel."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


def degree_of(num_coeffs: int) -> int:
    """Inverse of `num_coefficients`; raises on a count that is not 1, 4, 9 or 16."""
    for degree in range(4):
        if (degree + 1) ** 2 == num_coeffs:
            return degree
    raise ValueError(f"SH coefficient count must be 1, 4, 9 or 16, got {num_coeffs}")


def basis(dirs: jax.Array, degree: int) -> jax.Array:
    """(..., 3) unit directions -> (..., (degree+1)^2) basis values."""
    x, y, z = dirs[..., 0], dirs[..., 1], dirs[..., 2]
    out = [jnp.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2.0 * zz - xx - yy), C2[3] * xz,
                C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3.0 * xx - yy), C3[1] * xy * z, C3[2] * y * (4.0 * zz - xx - yy),
                C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), C3[4] * x * (4.0 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3.0 * yy)]
    return jnp.stack(out, axis=-1)


def evaluate(coeffs: jax.Array, dirs: jax.Array) -> jax.Array:
    """(N, K, C) coefficients at (N, 3) unit directions -> (N, C) values (no offset, no clamp)."""
    degree = degree_of(coeffs.shape[-2])
    return jnp.einsum("nk,nkc->nc", basis(dirs, degree), coeffs)


def rgb_to_dc(rgb: jax.Array) -> jax.Array:
    """Colour in [0, 1] -> degree-0 coefficient that renders to it (3DGS's RGB2SH)."""
    return (rgb - 0.5) / C0


def dc_to_rgb(dc: jax.Array) -> jax.Array:
    """Inverse of `rgb_to_dc`."""
    return dc * C0 + 0.5
