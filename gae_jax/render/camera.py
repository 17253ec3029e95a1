"""Pinhole cameras in the OpenCV convention.

Camera axes: x right, y down, z forward (the camera looks down +z). `w2c` maps world points to
camera points (`p_cam = R p_world + t`). Pixel (row i, column j) covers [j, j+1) x [i, i+1) and its
centre is (j + 0.5, i + 0.5); a camera point projects to (fx x/z + cx, fy y/z + cy).
Width and height are static pytree fields, so changing the image size recompiles.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
      intrinsics: (4,) fx, fy, cx, cy in pixels.
      w2c: (4, 4) world-to-camera rigid transform (OpenCV axes).
      width, height: image size in pixels (static).
    """

    intrinsics: jax.Array
    w2c: jax.Array
    width: int = dataclasses.field(metadata=dict(static=True))
    height: int = dataclasses.field(metadata=dict(static=True))

    @property
    def rotation(self) -> jax.Array:
        """(3, 3) world-to-camera rotation."""
        return self.w2c[:3, :3]

    @property
    def translation(self) -> jax.Array:
        """(3,) world-to-camera translation."""
        return self.w2c[:3, 3]

    @property
    def position(self) -> jax.Array:
        """(3,) camera centre in world coordinates, -R^T t."""
        return -self.rotation.T @ self.translation

    def world_to_camera(self, points: jax.Array) -> jax.Array:
        """(N, 3) world points -> (N, 3) camera points."""
        return points @ self.rotation.T + self.translation[None, :]


def focal_from_fov(fov_degrees: float, size: int) -> float:
    """Focal length in pixels for a field of view spanning `size` pixels."""
    return 0.5 * size / np.tan(0.5 * np.deg2rad(fov_degrees))


def look_at_w2c(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """(4, 4) world-to-camera matrix of a camera at `eye` looking at `target`.

    `up` is the world direction that should appear up in the image (the camera's -y axis).
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = target - eye
    norm = np.linalg.norm(forward)
    if norm == 0:
        raise ValueError("look_at: eye and target coincide")
    z = forward / norm
    down = -up - np.dot(-up, z) * z
    if np.linalg.norm(down) < 1e-9:
        raise ValueError("look_at: up is parallel to the viewing direction")
    y = down / np.linalg.norm(down)
    x = np.cross(y, z)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def make_camera(w2c, width: int, height: int, fov_degrees: float = 60.0,
                principal_point=None, dtype=jnp.float32) -> Camera:
    """A camera with a horizontal field of view `fov_degrees` and square pixels.

    Args:
      w2c: (4, 4) world-to-camera matrix.
      principal_point: (cx, cy) in pixels; the image centre when None.
    """
    w2c = np.asarray(w2c, dtype=np.float64)
    if w2c.shape != (4, 4) or not np.all(np.isfinite(w2c)):
        raise ValueError(f"w2c must be a finite (4, 4) matrix, got shape {w2c.shape}")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    f = focal_from_fov(fov_degrees, width)
    cx, cy = (0.5 * width, 0.5 * height) if principal_point is None else principal_point
    return Camera(intrinsics=jnp.asarray([f, f, cx, cy], dtype=dtype),
                  w2c=jnp.asarray(w2c, dtype=dtype), width=int(width), height=int(height))
