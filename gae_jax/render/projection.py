"""EWA projection of 3D Gaussians to screen-space ellipses (3DGS / gsplat numerics).

Conventions: quaternions are wxyz and normalised here; scales are linear (already activated);
camera axes are OpenCV (see `camera`). The 2D covariance is J W Sigma W^T J^T + dilation * I with J
the perspective Jacobian at the (frustum-clamped) camera-space mean, as in gsplat. A Gaussian is
culled when its depth is below `near`, its opacity cannot reach the 1/255 cut-off, or its screen
extent misses the image.

Screen extent ("opacity-aware"): a pixel can only receive alpha >= 1/255 when
o exp(-q/2) >= 1/255, i.e. q <= 2 ln(255 o). The extent is the bounding box of that ellipse,
half-widths sqrt(2 ln(255 o) Sigma2d_xx) and sqrt(2 ln(255 o) Sigma2d_yy). Unlike the classic
3-sigma square, no pixel outside it can receive a contribution, so tile culling loses nothing
(and faint Gaussians touch fewer tiles).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from gae_jax.render.camera import Camera

ALPHA_THRESHOLD = 1.0 / 255.0
NEAR_PLANE = 0.01
# Added to the 2D covariance (px^2). 3DGS/gsplat use 0.3; we use 0.1, about the variance of a
# 1-px box filter (1/12), which matches our supersampled ground truth: at 0.3 the lips' tails
# spill over the 1-2 px teeth and the fit cancels them by miscolouring the teeth.
COV2D_DILATION = 0.1
# The Jacobian is evaluated no further than this fraction of the half field of view outside the
# image (gsplat/3DGS use 1.3 tan(fov/2)), which keeps far off-screen Gaussians from exploding.
FRUSTUM_MARGIN = 0.3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Projected:
    """Per-Gaussian screen-space quantities, all (N, ...).

    Attributes:
      means2d: (N, 2) pixel coordinates (x, y) of the projected mean.
      conics: (N, 3) upper triangle (a, b, c) of the inverse 2D covariance.
      depths: (N,) camera-space z.
      opacities: (N,) opacity in [0, 1].
      extents: (N, 2) half-widths in pixels of the region that can receive alpha >= 1/255.
      visible: (N,) bool, False for culled Gaussians.
    """

    means2d: jax.Array
    conics: jax.Array
    depths: jax.Array
    opacities: jax.Array
    extents: jax.Array
    visible: jax.Array

    @property
    def radii(self) -> jax.Array:
        """(N,) int32 screen radius in pixels (ceil of the larger half-width), 0 if culled."""
        r = jnp.ceil(jnp.max(jnp.minimum(self.extents, 1e6), axis=-1)).astype(jnp.int32)
        return jnp.where(self.visible, r, 0)


def _rotation_entries(quats: jax.Array) -> list:
    """(N, 4) wxyz quaternions (any norm) -> 3 x 3 nested list of (N,) rotation entries."""
    w, x, y, z = (quats[..., i] for i in range(4))
    squared = w * w + x * x + y * y + z * z
    # A zero quaternion has no direction: it is the identity, and the square root never sees the
    # zero (whose derivative is infinite), so gradients stay finite.
    some = squared > 0
    inv = jnp.where(some, jax.lax.rsqrt(jnp.where(some, squared, 1.0)), 0.0)
    w = jnp.where(some, w * inv, 1.0)
    x, y, z = x * inv, y * inv, z * inv
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]


def quat_to_rotmat(quats: jax.Array) -> jax.Array:
    """(N, 4) wxyz quaternions (any norm) -> (N, 3, 3) rotation matrices."""
    rows = _rotation_entries(quats)
    return jnp.stack([jnp.stack(r, axis=-1) for r in rows], axis=-2)


def screen_covariance(quats: jax.Array, scales: jax.Array, rotation: jax.Array,
                      jac_x: jax.Array, jac_y: jax.Array, jac_xz: jax.Array,
                      jac_yz: jax.Array) -> jax.Array:
    """(N, 3) upper triangle (a, b, c) of the 2D covariance J W R S S^T R^T W^T J^T (no dilation).

    quats (N, 4), scales (N, 3), rotation: (3, 3) world-to-camera W; the perspective Jacobian
    J = [[jac_x, 0, jac_xz], [0, jac_y, jac_yz]], entries (N,). Written entry by entry: XLA:CPU
    runs its batched 3 x 3 products ~10x slower than one fused loop over the entries. The last
    step is a reduction on purpose: XLA:CPU does not copy a reduction into every consumer, which
    it does with a long elementwise chain (the packing would recompute it per column).
    """
    rot = _rotation_entries(quats)
    jw = [[jac_x * rotation[0, c] + jac_xz * rotation[2, c] for c in range(3)],
          [jac_y * rotation[1, c] + jac_yz * rotation[2, c] for c in range(3)]]  # J W
    tx, ty = (jnp.stack([(jw[r][0] * rot[0][c] + jw[r][1] * rot[1][c] + jw[r][2] * rot[2][c])
                         * scales[:, c] for c in range(3)], axis=-1)
              for r in range(2))  # the two (N, 3) rows of J W R S
    return jnp.sum(jnp.stack([tx * tx, tx * ty, ty * ty], axis=-2), axis=-1)


def project(means: jax.Array, quats: jax.Array, scales: jax.Array, opacities: jax.Array,
            camera: Camera, *, near: float = NEAR_PLANE,
            dilation: float = COV2D_DILATION) -> Projected:
    """Projects (N, 3) world means with (N, 4) quats, (N, 3) scales, (N,) opacities.

    dilation: px^2 added to the 2D covariance (the screen filter).
    """
    fx, fy, cx, cy = (camera.intrinsics[i] for i in range(4))
    rotation, translation = camera.rotation, camera.translation
    x, y, z = (sum(rotation[r, k] * means[:, k] for k in range(3)) + translation[r]
               for r in range(3))
    in_front = z >= near
    z_safe = jnp.where(in_front, z, 1.0)

    half_fov_x = 0.5 * camera.width / fx
    half_fov_y = 0.5 * camera.height / fy
    tx = z_safe * jnp.clip(x / z_safe, -(cx / fx + FRUSTUM_MARGIN * half_fov_x),
                           (camera.width - cx) / fx + FRUSTUM_MARGIN * half_fov_x)
    ty = z_safe * jnp.clip(y / z_safe, -(cy / fy + FRUSTUM_MARGIN * half_fov_y),
                           (camera.height - cy) / fy + FRUSTUM_MARGIN * half_fov_y)
    cov2d = screen_covariance(quats, scales, rotation, fx / z_safe, fy / z_safe,
                              -fx * tx / (z_safe * z_safe), -fy * ty / (z_safe * z_safe))
    a, b, c = cov2d[:, 0] + dilation, cov2d[:, 1], cov2d[:, 2] + dilation
    det = a * c - b * b
    det_ok = det > 0
    det_safe = jnp.where(det_ok, det, 1.0)
    conics = jnp.stack([c / det_safe, -b / det_safe, a / det_safe], axis=-1)
    means2d = jnp.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], axis=-1)

    reach = opacities > ALPHA_THRESHOLD
    q_max = 2.0 * jnp.log(255.0 * jnp.where(reach, opacities, 1.0))
    ext = jax.lax.stop_gradient(jnp.sqrt(jnp.maximum(
        q_max[:, None] * jnp.stack([a, c], axis=-1), 0.0)))
    m2 = jax.lax.stop_gradient(means2d)
    on_screen = ((m2[:, 0] + ext[:, 0] > 0) & (m2[:, 0] - ext[:, 0] < camera.width)
                 & (m2[:, 1] + ext[:, 1] > 0) & (m2[:, 1] - ext[:, 1] < camera.height))
    finite = jnp.all(jnp.isfinite(m2), axis=-1) & jnp.all(jnp.isfinite(ext), axis=-1)
    visible = in_front & det_ok & reach & on_screen & finite
    return Projected(means2d=means2d, conics=conics, depths=z, opacities=opacities,
                     extents=jnp.where(visible[:, None], ext, 0.0), visible=visible)
