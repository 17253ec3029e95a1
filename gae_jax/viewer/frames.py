"""One viewer frame: FLAME parameters -> posed Gaussians -> our renderer's image from the
browser's camera, jitted, with the tile capacity grown when a view overflows it.

Cameras: the browser (viser) reports its camera as `P_world = R p_camera + position` in OpenCV
axes (x right, y down, z forward) with a vertical field of view; our `Camera` takes the inverse
(world-to-camera). The image the browser stretches over its viewport has a width quantised to
quarter steps of aspect ratio (each width compiles once), and its horizontal focal length
follows the viewport's true aspect, so the stretched picture is undistorted.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.model import avatar as av
from gae_jax.model import flame
from gae_jax.model.avatar import Avatar
from gae_jax.model.flame import FlameModel, FlameParams
from gae_jax.render import sh, splat, wabe
from gae_jax.render.camera import Camera
from gae_jax.render.projection import quat_to_rotmat
from gae_jax.scene import rig as rigs
from gae_jax.util.compile import fast_jit

ASPECT_STEPS = 4  # image widths per unit of aspect ratio
CAPACITY_MARGIN = 1.5


def camera_of_view(position, wxyz, fov_y: float, aspect: float, height: int) -> Camera:
    """Our camera for the browser's view.

    position: (3,) camera centre; wxyz: (4,) rotation camera -> world (OpenCV axes); fov_y:
    vertical field of view (radians); aspect: viewport width / height; height: image rows.
    """
    if not (0 < fov_y < math.pi and aspect > 0 and height >= 8):
        raise ValueError(f"bad view: fov {fov_y}, aspect {aspect}, height {height}")
    width = max(8, int(round(height * max(round(aspect * ASPECT_STEPS), 1) / ASPECT_STEPS)))
    r_wc = np.asarray(quat_to_rotmat(jnp.asarray(wxyz, jnp.float32)[None])[0], np.float64)
    w2c = np.eye(4)
    w2c[:3, :3] = r_wc.T
    w2c[:3, 3] = -r_wc.T @ np.asarray(position, np.float64)
    fy = 0.5 * height / math.tan(0.5 * fov_y)
    fx = fy * width / (height * aspect)
    return Camera(intrinsics=jnp.asarray([fx, fy, 0.5 * width, 0.5 * height], jnp.float32),
                  w2c=jnp.asarray(w2c, jnp.float32), width=width, height=int(height))


def view_of_camera(intrinsics, w2c, height: int):
    """(position (3,), wxyz (4,), vertical fov) of a rig camera, for the browser."""
    w2c = np.asarray(w2c, np.float64)
    r_wc = w2c[:3, :3].T
    position = -r_wc @ w2c[:3, 3]
    wxyz = np.asarray(av.rotmat_to_quat(jnp.asarray(r_wc, jnp.float32)[None])[0], np.float64)
    fov_y = 2.0 * math.atan(0.5 * height / float(intrinsics[1]))
    return position, wxyz / np.linalg.norm(wxyz), fov_y


def front_camera(w2c) -> int:
    """Index of the rig camera (w2c (C, 4, 4)) nearest the rig's mean viewing direction: the
    frontal one of a rig around a face."""
    w2c = np.asarray(w2c, np.float64)
    dirs = -w2c[:, 2, :3]  # from the head towards each camera
    mean = dirs.mean(0)
    return int(np.argmax(dirs @ (mean / max(np.linalg.norm(mean), 1e-9))))


def side_by_side(camera: Camera) -> Camera:
    """The camera of one half of a side-by-side picture: half the width over half the
    viewport, so the same focal length (in pixels) keeps the view's scale; only the principal
    point moves to the half's centre."""
    width = max(camera.width // 2, 8)
    fx, fy, _, cy = (camera.intrinsics[i] for i in range(4))
    return Camera(intrinsics=jnp.stack([fx, fy, jnp.asarray(0.5 * width, fx.dtype), cy]),
                  w2c=camera.w2c, width=width, height=camera.height)


def posed(model: FlameModel, avatar: Avatar, params: FlameParams) -> splat.Gaussians:
    """World-space Gaussians of `avatar` on the mesh `model` poses with `params`."""
    return av.deform(avatar, flame.lbs(model, params), model.faces)


def _view_rig(model, avatar, params, camera, background, capacity) -> rigs.Rig:
    return rigs.Rig(faces=model.faces, binding=avatar.binding, regions=avatar.regions,
                    vertices=flame.lbs(model, params)[None],
                    intrinsics=camera.intrinsics[None], w2c=camera.w2c[None],
                    background=background, width=camera.width, height=camera.height,
                    tile_capacity=capacity)


@functools.lru_cache(maxsize=None)
def _image_fn(blend: wabe.Blend):
    def image(model, avatar, params, camera, background, capacity):
        rig = _view_rig(model, avatar, params, camera, background, capacity)
        out = rigs.render_bound(avatar.trainable(), rig, 0, 0, blend=blend)
        return out.image, out.stats.overflow_tiles

    return fast_jit(image, static_argnames="capacity")


@jax.jit
def _tile_load(model, avatar, params, camera):
    return splat.tile_load(posed(model, avatar, params), camera)


def capacity_for(load: int) -> int:
    """The tile capacity for a view whose busiest tile holds `load` Gaussians: 1.5x, rounded up
    to 128, so that the motion and small camera moves rarely need another compilation."""
    return int(128 * math.ceil(CAPACITY_MARGIN * max(load, 1) / 128))


def render(model: FlameModel, avatar: Avatar, params: FlameParams, camera: Camera,
           background, blend: wabe.Blend, capacity: int | None = None):
    """((H, W, 3) float image in [0, 1], the tile capacity it used) with `capacity` Gaussians
    per tile (None: sized from this view's busiest tile), grown (`capacity_for`) and rendered
    again when the view overflows it. Pass the returned capacity back next time."""
    background = jnp.asarray(background, jnp.float32)
    if capacity is None:
        capacity = capacity_for(int(_tile_load(model, avatar, params, camera)))
    image, overflow = _image_fn(blend)(model, avatar, params, camera, background, capacity)
    if int(overflow):
        load = int(_tile_load(model, avatar, params, camera))
        capacity = max(capacity, capacity_for(load))
        image, _ = _image_fn(blend)(model, avatar, params, camera, background, capacity)
    return np.clip(np.asarray(image), 0.0, 1.0), capacity


@dataclasses.dataclass(frozen=True)
class SplatArrays:
    """What a browser-side splat renderer takes: centers (N, 3), covariances (N, 3, 3),
    rgbs (N, 3) in [0, 1] (the colour's view-independent part), opacities (N, 1)."""

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray


@jax.jit
def _splat_arrays(model, avatar, params):
    g = posed(model, avatar, params)
    rot = quat_to_rotmat(g.quats)
    cov = jnp.einsum("nij,nj,nkj->nik", rot, g.scales ** 2, rot)
    rgb = sh.dc_to_rgb(g.colors[:, 0]) if g.is_sh else g.colors
    return g.means, cov, jnp.clip(rgb, 0.0, 1.0), g.opacities[:, None]


def splat_arrays(model: FlameModel, avatar: Avatar, params: FlameParams) -> SplatArrays:
    """The posed avatar for a browser-side splat renderer (no SH view dependence, no WABE)."""
    return SplatArrays(*(np.asarray(x, np.float32) for x in _splat_arrays(model, avatar, params)))
