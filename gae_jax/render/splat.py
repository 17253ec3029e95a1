"""Differentiable tile-based Gaussian splatting: project, bin, sort, composite.

`render(gaussians, camera, ...)` follows 3DGS / gsplat numerics (see `projection`, `tiles`,
`composite` for each stage) and is differentiable with respect to means, quaternions, scales,
opacities, colours / SH coefficients and the camera. Choices that differ from the Inria code:
  * alpha clamp 0.99 (Inria; gsplat uses 0.999) -- a `render` argument;
  * opacity-aware screen extent instead of the 3-sigma square, so tile culling is exact;
  * a static per-tile capacity: tiles touched by more Gaussians keep the nearest ones, and the
    number of overflowing tiles and dropped (Gaussian, tile) pairs is reported in `RenderOutput`.

Colours: `Gaussians.colors` is either (N, C) plain values (RGB or any feature channels) or
(N, K, 3) SH coefficients (K = 1, 4, 9, 16), evaluated towards the camera centre and turned into
RGB as max(SH + 0.5, 0), as in 3DGS.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gae_jax.render import composite as comp
from gae_jax.render import sh, wabe
from gae_jax.render.camera import Camera
from gae_jax.render.projection import COV2D_DILATION, project
from gae_jax.render.tiles import bin_gaussians

DEFAULT_ALPHA_CLAMP = 0.99
DEFAULT_TILE_CAPACITY = 256
DEPTH_EPS = 1e-8


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Gaussians:
    """World-space 3D Gaussians with activated attributes.

    Attributes:
      means: (N, 3) world positions.
      quats: (N, 4) rotations, wxyz, any non-zero norm.
      scales: (N, 3) standard deviations along the rotated axes (linear, > 0).
      opacities: (N,) in [0, 1].
      colors: (N, C) plain colours / features, or (N, K, 3) SH coefficients.
    """

    means: jax.Array
    quats: jax.Array
    scales: jax.Array
    opacities: jax.Array
    colors: jax.Array

    @property
    def num(self) -> int:
        return self.means.shape[0]

    @property
    def is_sh(self) -> bool:
        return self.colors.ndim == 3


def check_gaussians(g: Gaussians) -> None:
    """Raises ValueError naming the field when shapes are inconsistent (runs on static shapes)."""
    n = g.means.shape[0] if g.means.ndim == 2 else -1
    expected = dict(means=(n, 3), quats=(n, 4), scales=(n, 3), opacities=(n,))
    for name, shape in expected.items():
        if getattr(g, name).shape != shape:
            raise ValueError(f"Gaussians.{name} must have shape {shape}, got "
                             f"{getattr(g, name).shape}")
    if g.colors.shape[0] != n or g.colors.ndim not in (2, 3):
        raise ValueError(f"Gaussians.colors must be (N, C) or (N, K, 3), got {g.colors.shape}")
    if g.colors.ndim == 3:
        sh.degree_of(g.colors.shape[1])
        if g.colors.shape[2] != 3:
            raise ValueError(f"SH colours must be (N, K, 3), got {g.colors.shape}")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RenderStats:
    """Per-Gaussian screen statistics and binning health.

    Attributes:
      radii: (N,) int32 screen radius in pixels, 0 when culled.
      means2d: (N, 2) projected means (pass `screen_offset` to `render` to get their gradient).
      pixels: (N,) number of pixels each Gaussian was composited into.
      contributed: (N,) bool, pixels > 0.
      visibility: (N,) max over pixels of exp(-beta (1 - T)) alpha among the pixel's first
        contributors (the official GaussianAvatar-Editor code's gradient-mask signal).
      overflow_tiles: () tiles touched by more Gaussians than the capacity.
      dropped_pairs: () (Gaussian, tile) pairs left out (farthest first).
      num_slots: () the longest tile list that was walked.
    """

    radii: jax.Array
    means2d: jax.Array
    pixels: jax.Array
    contributed: jax.Array
    visibility: jax.Array
    overflow_tiles: jax.Array
    dropped_pairs: jax.Array
    num_slots: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RenderOutput:
    """image (H, W, C), alpha (H, W), depth (H, W) expected depth of the covered part, stats."""

    image: jax.Array
    alpha: jax.Array
    depth: jax.Array
    stats: RenderStats


def colors_towards(gaussians: Gaussians, camera: Camera) -> jax.Array:
    """(N, C) colours as seen from the camera centre (SH evaluated; plain colours unchanged)."""
    if not gaussians.is_sh:
        return gaussians.colors
    dirs = gaussians.means - camera.position[None, :]
    norm = jnp.sqrt(jnp.sum(dirs * dirs, axis=-1, keepdims=True))
    dirs = dirs / jnp.where(norm > 0, norm, 1.0)
    return jnp.maximum(sh.evaluate(gaussians.colors, dirs) + 0.5, 0.0)


def render(gaussians: Gaussians, camera: Camera, *, background=None,
           blend: wabe.Blend = wabe.standard(), tile_capacity: int = DEFAULT_TILE_CAPACITY,
           max_pairs: int | None = None, alpha_clamp: float = DEFAULT_ALPHA_CLAMP,
           screen_offset: jax.Array | None = None, unroll: int = 8, unroll_backward: int = 8,
           tiles_per_chunk: int = 32,
           visibility_contributors: int = 0,
           visibility_beta: float = wabe.PAPER_BETA, kernel: str = "auto",
           screen_filter: float = COV2D_DILATION) -> RenderOutput:
    """Renders Gaussians into camera.height x camera.width.

    Args:
      gaussians: the scene (see `Gaussians`).
      camera: pinhole camera, OpenCV axes.
      background: (C,) colour composited behind everything; zeros when None.
      blend: colour weighting (`wabe.standard()`, `wabe.wabe(beta)`, `wabe.wabe_grad(beta)`).
      tile_capacity: static list length per 16x16 tile.
      max_pairs: static (Gaussian, tile) pair budget; num_tiles * tile_capacity when None.
      alpha_clamp: upper bound on a single Gaussian's alpha.
      screen_offset: optional (N, 2) added to the projected means; pass zeros and differentiate
        with respect to it to obtain the screen-space mean gradient used for densification.
      unroll, unroll_backward: list slots per loop iteration of the compositor's forward and
        backward walks (speed only).
      tiles_per_chunk: tiles the compositor walks together (speed only).
      visibility_contributors: when > 0, compute `stats.visibility` over each pixel's first this
        many contributors (the official code uses 10); 0 skips it (zeros) and saves time.
      visibility_beta: beta of the visibility statistic.
      kernel: "auto" (the C++ compositor for float32 and the C++ depth sort on CPU when built,
        see `cpu_kernel`) or "jax" (always the pure-JAX compositor and `lax.sort`).
      screen_filter: px^2 added to each 2D covariance (`projection.COV2D_DILATION`; 3DGS and
        gsplat use 0.3).
    """
    check_gaussians(gaussians)
    if not 0.0 < alpha_clamp < 1.0:
        raise ValueError(f"alpha_clamp must be in (0, 1), got {alpha_clamp}")
    dtype = gaussians.means.dtype
    proj = project(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
                   camera, dilation=screen_filter)
    means2d = proj.means2d if screen_offset is None else proj.means2d + screen_offset
    colors = colors_towards(gaussians, camera).astype(dtype)
    num_channels = colors.shape[-1]
    if background is None:
        background = jnp.zeros((num_channels,), dtype)
    background = jnp.asarray(background, dtype)
    if background.shape != (num_channels,):
        raise ValueError(f"background must have shape ({num_channels},), got {background.shape}")

    bins = bin_gaussians(jax.lax.stop_gradient(means2d), proj.extents, proj.depths,
                         proj.visible, camera.width, camera.height, tile_capacity, max_pairs,
                         kernel=kernel)
    packed = jnp.concatenate([
        means2d, proj.conics, proj.opacities[:, None], proj.depths[:, None], colors], axis=-1)
    # Culled Gaussians never appear in a list; zero their row so no NaN from a culled projection
    # can reach the gradient through the packing.
    packed = jnp.where(proj.visible[:, None], packed, 0.0)
    cfg = comp.CompositeConfig(blend=blend, alpha_clamp=float(alpha_clamp),
                               tiles_x=bins.tiles_x, tiles_y=bins.tiles_y, unroll=int(unroll),
                               unroll_backward=int(unroll_backward),
                               tiles_per_chunk=int(tiles_per_chunk),
                               front_contributors=int(visibility_contributors),
                               visibility_beta=float(visibility_beta), kernel=kernel)
    color, transmittance, depth_acc, (pixels, visibility) = comp.composite(
        cfg, bins.table, bins.kept, packed)

    def to_image(x):
        return comp.tiles_to_image(x, bins.tiles_x, bins.tiles_y, camera.width, camera.height)

    transmittance = to_image(transmittance)
    alpha = 1.0 - transmittance
    image = to_image(color) + transmittance[..., None] * background[None, None, :]
    depth = to_image(depth_acc) / jnp.maximum(alpha, DEPTH_EPS)
    stats = RenderStats(radii=proj.radii, means2d=jax.lax.stop_gradient(means2d), pixels=pixels,
                        contributed=pixels > 0, visibility=visibility,
                        overflow_tiles=bins.overflow_tiles, dropped_pairs=bins.dropped_pairs,
                        num_slots=bins.num_slots)
    return RenderOutput(image=image, alpha=alpha, depth=depth, stats=stats)


def tile_load(gaussians: Gaussians, camera: Camera,
              screen_filter: float = COV2D_DILATION) -> jax.Array:
    """() int32: the most Gaussians touching any one tile, i.e. the `tile_capacity` at which
    this view renders without overflow (with `render`'s `screen_filter`)."""
    proj = project(gaussians.means, gaussians.quats, gaussians.scales, gaussians.opacities,
                   camera, dilation=screen_filter)
    bins = bin_gaussians(proj.means2d, proj.extents, proj.depths, proj.visible, camera.width,
                         camera.height, 1, None)
    return jnp.max(bins.counts)
