"""The one host -> device boundary, and the one avatar-render composition.

`make_rig` (and `put_rig` for a scene) moves what a jitted step reads about a scene and an avatar's binding onto the device as
a registered pytree: faces, the avatar's binding and regions, the posed mesh of the frames in use,
cameras and background; image size and tile capacity are static fields (they shape the program).
`render_bound(params, rig, frame, cam)` is the only place that composes
Avatar -> `avatar.deform` -> `Camera` -> `splat.render`; every stage (fit, edit, preview,
evaluation, outputs) renders through it.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.model import avatar as av
from gae_jax.render import splat, wabe
from gae_jax.render.camera import Camera
from gae_jax.render.projection import COV2D_DILATION
from gae_jax.util.compile import fast_jit

TILES_PER_CHUNK = 8  # tiles the compositor walks together; 8 measured fastest at 128 px


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Rig:
    """Device-resident constants of rendering one bound avatar in one scene.

    Attributes:
      faces: (F, 3) int32 mesh triangles.
      binding: (N,) int32 face of each Gaussian; regions: (N,) int32 its region label.
      vertices: (T, V, 3) posed mesh of each frame in use (frame indices index this axis).
      intrinsics: (C, 4) fx, fy, cx, cy; w2c: (C, 4, 4) world-to-camera, OpenCV axes.
      background: (3,) colour.
      width, height, tile_capacity: static.
      screen_filter: static, px^2 added to each 2D covariance (`splat.render`'s; the avatar
        renders as it was fitted).
    """

    faces: jax.Array
    binding: jax.Array
    regions: jax.Array
    vertices: jax.Array
    intrinsics: jax.Array
    w2c: jax.Array
    background: jax.Array
    width: int = dataclasses.field(metadata=dict(static=True))
    height: int = dataclasses.field(metadata=dict(static=True))
    tile_capacity: int = dataclasses.field(metadata=dict(static=True))
    screen_filter: float = dataclasses.field(default=COV2D_DILATION, metadata=dict(static=True))

    def camera(self, cam) -> Camera:
        """Camera `cam` (a traced or Python int) of the rig."""
        return Camera(intrinsics=self.intrinsics[cam], w2c=self.w2c[cam], width=self.width,
                      height=self.height)


def make_rig(faces, avatar: av.Avatar, vertices, intrinsics, w2c, background, width: int,
             height: int, tile_capacity: int, screen_filter: float = COV2D_DILATION) -> Rig:
    """The one place rendering data enters the device: host arrays -> a `Rig` pytree."""
    return Rig(faces=jnp.asarray(faces, jnp.int32), binding=jnp.asarray(avatar.binding, jnp.int32),
               regions=jnp.asarray(avatar.regions, jnp.int32),
               vertices=jnp.asarray(vertices, jnp.float32),
               intrinsics=jnp.asarray(intrinsics, jnp.float32),
               w2c=jnp.asarray(w2c, jnp.float32),
               background=jnp.asarray(background, jnp.float32), width=int(width),
               height=int(height), tile_capacity=max(int(tile_capacity), 1),
               screen_filter=float(screen_filter))


def put_rig(scene, avatar: av.Avatar, vertices, tile_capacity: int = 0,
            capacity_cameras=None, screen_filter: float = COV2D_DILATION) -> Rig:
    """The rig of `avatar` (its binding and regions) in `scene` with (T, V, 3) posed `vertices`.

    `tile_capacity` 0 sizes it with `required_capacity` over `capacity_cameras` (default: the
    scene's training cameras) at the first frame.
    """
    rig = make_rig(scene.model.faces, avatar, vertices, scene.intrinsics, scene.w2c,
                   scene.background, scene.width, scene.height, tile_capacity, screen_filter)
    if tile_capacity:
        return rig
    cams = scene.train_cameras if capacity_cameras is None else capacity_cameras
    return dataclasses.replace(rig, tile_capacity=required_capacity(avatar.trainable(), rig,
                                                                    cams))


def with_vertices(rig: Rig, vertices) -> Rig:
    """The same rig posed at other (T, V, 3) frames (evaluation, outputs)."""
    return dataclasses.replace(rig, vertices=jnp.asarray(vertices, jnp.float32))


def one_frame(rig: Rig, frame) -> Rig:
    """The rig holding only frame `frame` (vertices (1, V, 3)): what a jitted function of one
    frame takes, so that it compiles once for rigs of every length (the edit's 80 frames, the
    grid's 3, the evaluation's 4 and 16), not once per length (~1.5 s each)."""
    return dataclasses.replace(rig, vertices=jax.lax.dynamic_slice_in_dim(
        rig.vertices, jnp.asarray(frame, jnp.int32), 1))


def gaussians_at(params: dict, rig: Rig, frame) -> splat.Gaussians:
    """World-space Gaussians of the bound avatar at rig frame `frame`."""
    avatar = av.Avatar(binding=rig.binding, regions=rig.regions, **params)
    return av.deform(avatar, rig.vertices[frame], rig.faces)


def render_bound(params: dict, rig: Rig, frame, cam, *, blend: wabe.Blend = wabe.standard(),
                 extra_channels=None, **render_options) -> splat.RenderOutput:
    """Renders the avatar with trainable arrays `params` at rig frame `frame` from camera `cam`.

    extra_channels: optional (N, K) per-Gaussian values composited after the (view-dependent)
      colour, over a zero background (region votes, canonical positions).
    render_options: passed to `splat.render` (screen_offset, visibility_contributors, ...).
    """
    g = gaussians_at(params, rig, frame)
    camera = rig.camera(cam)
    background = rig.background
    if extra_channels is not None:
        rgb = splat.colors_towards(g, camera)
        g = dataclasses.replace(g, colors=jnp.concatenate(
            [rgb, extra_channels.astype(rgb.dtype)], -1))
        background = jnp.concatenate([background, jnp.zeros(extra_channels.shape[-1],
                                                             background.dtype)])
    render_options.setdefault("tiles_per_chunk", TILES_PER_CHUNK)
    render_options.setdefault("screen_filter", rig.screen_filter)
    return splat.render(g, camera, background=background, blend=blend,
                        tile_capacity=rig.tile_capacity, **render_options)


def required_capacity(params: dict, rig: Rig, cameras, frame: int = 0) -> int:
    """1.25x the busiest tile of the avatar over the given cameras at one frame, rounded up to
    128 (a 25 % margin for the motion and the edit's changes)."""
    worst = max(int(_tile_load(params, _one_view(rig, frame, int(c)))) for c in cameras)
    return int(128 * math.ceil(1.25 * worst / 128))


def _one_view(rig: Rig, frame: int, cam: int) -> Rig:
    """The rig holding only frame `frame` and camera `cam`, its capacity unset: `_tile_load`
    compiles once for rigs of every length, camera count and capacity (the fit's, its unseen
    views', the edit's)."""
    return dataclasses.replace(rig, vertices=rig.vertices[frame:frame + 1],
                               intrinsics=rig.intrinsics[cam:cam + 1], w2c=rig.w2c[cam:cam + 1],
                               tile_capacity=1)


@jax.jit
def _tile_load(params: dict, rig: Rig) -> jax.Array:
    return splat.tile_load(gaussians_at(params, rig, 0), rig.camera(0), rig.screen_filter)


@functools.lru_cache(maxsize=None)
def make_view_renderer(blend: wabe.Blend = wabe.standard()):
    """`render(params, rig, frame, cam) -> (H, W, 3)` image, one per blend (so the grid, the video
    and the evaluation share its compilation: `render.jitted`, one per avatar size, since it
    sees the rig of one frame)."""
    @fast_jit
    def render_frame(params, rig, cam):
        return render_bound(params, rig, 0, cam, blend=blend).image

    def render(params, rig, frame, cam):
        return render_frame(params, one_frame(rig, frame), cam)

    render.jitted = render_frame
    return render


def render_views(render, params: dict, rig: Rig, cameras) -> np.ndarray:
    """(T, K, H, W, 3) float images of every rig frame from K cameras with a
    `make_view_renderer` function."""
    return np.stack([np.stack([np.asarray(render(params, rig, jnp.int32(t), jnp.int32(c)))
                               for c in cameras]) for t in range(rig.vertices.shape[0])])
