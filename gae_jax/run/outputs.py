"""What an edit run leaves for people and tools: a labelled grid, a reenactment video, and the
avatars as GaussianAvatars folders (plus a posed 3DGS `.ply` that splat viewers open).

Grid columns: the untouched avatar, the editor's 2D edit of that render composited into it as
the loop's targets are (`region`), ours (the edited avatar), and the truth (the ideal edit on
the synthetic scene, the capture on a user's data); rows: frames x cameras of the
self-reenactment protocol (the training frames when the scene has none). A title line carries
the prompt and the edit region, whose outline (yellow) is drawn on the untouched render and the
2D target (ours and the truth stay clean to compare); images are shown at twice the render size.
"""

from __future__ import annotations

import os
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.edit import region as edit_region
from gae_jax.edit.edit import EditSetup
from gae_jax.edit.sampler import configured_editor, editor_context
from gae_jax.evaluation import protocols, truth
from gae_jax.model import avatar as av, avatar_io, head
from gae_jax.render import wabe
from gae_jax.run import folder
from gae_jax.scene import motion_io, rig as rigs
from gae_jax.scene.types import Scene, interpolated_vertices, posed_vertices, stacked_params
from gae_jax.util.fileio import atomic_write_bytes, encode_png
from gae_jax.util.image import to_uint8


GRID_TEXT = 0.45  # the grid's title and header text scale
GRID_COLUMNS = ("untouched", "2D edit (target)", "ours")  # and the truth's column


def _label_height(scale: float) -> int:
    return int(round(42 * scale))


def label(width: int, text: str, scale: float = 0.33) -> np.ndarray:
    """(h, width, 3) uint8 white strip with `text` in black (h from the text scale)."""
    import cv2

    height = _label_height(scale)
    strip = np.full((height, width, 3), 255, np.uint8)
    cv2.putText(strip, text, (3, int(height * 0.72)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (0, 0, 0), 1, cv2.LINE_AA)
    return strip


GRID_ZOOM = 2
OUTLINE = (255, 220, 0)


def _zoom_outlined(image: np.ndarray, mask) -> np.ndarray:
    """(H, W, 3) uint8 -> (2H, 2W, 3), with the (H, W) bool mask's outline drawn if given."""
    import cv2

    big = cv2.resize(image, None, fx=GRID_ZOOM, fy=GRID_ZOOM, interpolation=cv2.INTER_NEAREST)
    if mask is not None and mask.any():
        m = cv2.resize(mask.astype(np.uint8), None, fx=GRID_ZOOM, fy=GRID_ZOOM,
                       interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        big = cv2.drawContours(np.ascontiguousarray(big), contours, -1, OUTLINE, 1)
    return big


def write_grid(setup: EditSetup, edited: av.Avatar, path: str, key) -> None:
    """PNG grid (see the module docstring) of the edit `setup` made and its result `edited`,
    with a header naming the columns; the 2D edits are drawn with PRNG `key`."""
    s = setup
    name = ("self_reenactment" if "self_reenactment" in protocols.available(s.scene)
            else "novel_view" if "novel_view" in protocols.available(s.scene) else None)
    if name is None:
        protocol = protocols.ProtocolFrames("train", s.pairs[:3], tuple(s.scene.train_cameras[:2]))
    else:
        protocol = protocols.protocol_frames(s.scene, name, frames=3, cameras=2)
    ideal = truth.ideal_of(s.scene, s.config.prompt)[1] if s.scene.kind == "synthetic" else None
    reference = truth.frames_truth(s.scene, protocol, ideal)
    rig = rigs.with_vertices(s.rig, reference.vertices)
    render = rigs.make_view_renderer(s.step_config.blend)
    original = rigs.render_views(render, s.original.trainable(), rig, protocol.cameras)
    ours = rigs.render_views(render, edited.trainable(), rig, protocol.cameras)
    editor = configured_editor(s.config)
    region = edit_region.parse_region(s.config.region, s.config.prompt)
    rows = []
    for p, (seq, t) in enumerate(protocol.pairs):
        for k, cam in enumerate(protocol.cameras):
            untouched = original[p, k]
            view = s.preview(s.original.trainable(), rig, jnp.int32(cam), jnp.int32(p),
                             s.canonical)
            labels = np.asarray(view.regions)
            edit = np.clip(editor.edit(
                untouched, untouched, s.config.prompt, jax.random.fold_in(key, p * 97 + k),
                editor_context(view, (cam, seq, t))), 0, 1)
            outline = None
            if region == ("auto",):
                outline = edit_region.change_mask(edit, untouched, s.config.change_threshold)
            elif region != ("none",):
                outline = np.isin(labels, [head.REGION_ID[n] for n in region])
            if outline is not None:
                mask = edit_region.soft_mask(outline.astype(np.float32), s.config.region_dilate,
                                             s.config.region_blur) * np.asarray(view.alpha)
                edit = edit_region.composite(edit, untouched, mask)
            cells = [_zoom_outlined(to_uint8(x), outline) for x in (untouched, edit)]
            cells += [_zoom_outlined(to_uint8(ours[p, k]), None),
                      _zoom_outlined(reference.truth[p, k], None)]
            rows.append(np.concatenate(cells, axis=1))
    width = rows[0].shape[1] // 4
    kind = "ideal edit" if s.scene.kind == "synthetic" else "capture"
    header = np.concatenate([label(width, t, GRID_TEXT) for t in GRID_COLUMNS + (kind,)],
                            axis=1)
    where = "every Gaussian" if region == ("none",) else ", ".join(region)
    title = label(rows[0].shape[1], f'"{s.config.prompt}"   region: {where}', GRID_TEXT)
    atomic_write_bytes(path, encode_png(np.concatenate([title, header] + rows, axis=0)))


def write_video(scene: Scene, rig: rigs.Rig, blend: wabe.Blend, original: av.Avatar,
                edited: av.Avatar, path: str, fps: int = 24, per_frame: int = 3) -> None:
    """MP4 from the held-out camera (a training camera when none is held out), 24 fps: the
    held-out and cross-identity sequences (the training ones when the scene has neither), their
    FLAME parameters interpolated `per_frame` steps between captured frames; each frame is
    ours | the `original` avatar, rendered on `rig`'s cameras with `blend` at the scene's
    resolution, labelled."""
    import imageio.v2 as imageio

    cam = (scene.held_out_cameras or scene.train_cameras)[0]
    names = (scene.sequences_of("self_reenactment") + scene.sequences_of("cross_identity")
             or scene.sequences_of("train"))
    render = rigs.make_view_renderer(blend)
    width = rig.width
    header = np.concatenate([label(width, "ours"), label(width, "untouched")], axis=1)
    frames = []
    for seq in names:
        posed = rigs.with_vertices(rig, interpolated_vertices(scene, seq, per_frame))
        ours = rigs.render_views(render, edited.trainable(), posed, [cam])[:, 0]
        before = rigs.render_views(render, original.trainable(), posed, [cam])[:, 0]
        frames += [np.concatenate([header, np.concatenate([to_uint8(a), to_uint8(b)], axis=1)])
                   for a, b in zip(ours, before)]
    tmp = path + ".tmp.mp4"
    with warnings.catch_warnings():
        # imageio-ffmpeg starts ffmpeg with fork + exec; the child runs no Python (nor JAX)
        # before exec, so JAX's warning about forking a multithreaded process does not apply.
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called",
                                category=RuntimeWarning)
        with imageio.get_writer(tmp, fps=fps, codec="libx264", macro_block_size=1,
                                ffmpeg_log_level="error") as writer:
            for f in frames:
                writer.append_data(f)
    os.replace(tmp, path)


def write_avatar_files(scene: Scene, original: av.Avatar, edited: av.Avatar, run_dir: str,
                       extra: dict | None = None) -> None:
    """The run's "edited" and "original" avatars (GaussianAvatars folders with the held-out or
    training motion, the identity's static offset and `extra` flame_param keys: an input
    avatar's own), the edited avatar posed in world space at the first frame of that motion,
    and the motion file (every sequence and identity of the scene, for the viewer)."""
    names = scene.sequences_of("self_reenactment") or scene.sequences_of("train")
    motion = stacked_params(scene, names)
    for which, avatar in (("edited", edited), ("original", original)):
        folder.write_avatar(run_dir, which, avatar, scene.shapes["A"], motion,
                            scene.static_offsets.get("A"), scene.model.num_vertices, extra)
    motion_io.save(folder.path(run_dir, "motion"), scene.sequences, scene.shapes,
                   scene.static_offsets)
    verts = posed_vertices(scene, [(names[0], 0)])[0]
    avatar_io.save_posed_ply(av.deform(edited, jnp.asarray(verts), scene.model.faces),
                             folder.path(run_dir, "posed"))


def grid_cells(grid: np.ndarray) -> np.ndarray:
    """(rows, columns, 2H, 2W, 3) cells of a `write_grid` image (its title and header cut)."""
    body = grid[2 * _label_height(GRID_TEXT):]
    columns = len(GRID_COLUMNS) + 1
    size = body.shape[1] // columns
    return body.reshape(body.shape[0] // size, size, columns, size, 3).transpose(0, 2, 1, 3, 4)
