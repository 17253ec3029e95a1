"""The host side of the edit loop: which (camera, frame) to edit next, the 2D editor calls, the
edit region (`region`: tracing and composited targets), the edit cache, Instruct-NeRF2NeRF's
dataset, and placing a batch on the devices.

A named region that most training views do not show (the teeth, the tongue) is edited from the
views that show it (`showing_views`): a uniform draw would spend most iterations on views where
its Gaussians get no gradient.

Stripes are placed by the tracked mesh's rest positions projected into the view
(`types.projected_rest_positions`, as the labels are): the avatar's rendered positions, a
blend of its Gaussians' along each ray, misplace them (docs/instructions.md measures by how
much). The editor also reads the labels of several rays in each pixel
(`types.projected_label_samples`): how much of a pixel on a region's outline the region covers,
so that only that share of it is recoloured.

A 2D editor sometimes edits part of the region only (one lip of two, the upper teeth): an edit
that changes much less of the region than the run's edits usually do is made again with
another key (`EditConfig.edit_retries`). A rarely seen Gaussian (a back tooth) learns from a few
edits, and one that left it unedited pulls it back to its old colour.

A 2D editor also answers each call in its own shade: a recolour of a named region is brought to
the per-channel median colour of the run's calls so far (`calibration`,
`EditConfig.edit_calibration`), read on the pixels the region covers whole.

Edits are quantised to 8 bits (an editor's output image), so checkpoints hold them exactly and
a resumed run reproduces an uninterrupted one.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from gae_jax import instructions
from gae_jax.edit import calibration, region as edit_region
from gae_jax.edit.config import EditConfig
from gae_jax.edit.editors import make_editor
from gae_jax.model import head
from gae_jax.scene.types import (projected_label_samples, projected_labels,
                                 projected_rest_positions, training_labels)
from gae_jax.util.image import to_uint8


SHOWING_FRACTION = 0.25  # of the pixels a well-showing view shows, for a view to count
ALL_VIEWS = 0.95  # above this share of showing views the draw stays uniform
PARTIAL = 0.75  # an edit changing under this share of the usual share of the region is partial
USUAL_AFTER = 3  # edits of a run before the usual share is known
USUAL_LEAST = 0.4  # below this usual share no edit is judged partial
CHANGED = 0.05  # a pixel differing from the unedited one by more (some channel) is changed
JUDGED_PIXELS = 4  # region pixels a view must show for its edit to be judged
RETRY_SALT = 0x7265  # folded into an edit's key for each retry


def _asks_stripes(prompt: str) -> bool:
    """Whether the prompt is an instruction to paint stripes (a style is not)."""
    try:
        return instructions.parse(prompt).stripes
    except ValueError:
        return False


def frame_table(scene, pairs):
    """For each (sequence, frame) pair, the rows of its neighbours in time among `pairs`."""
    index = {p: i for i, p in enumerate(pairs)}
    neighbours = []
    for name, t in pairs:
        n = scene.sequences[name].num_frames
        neighbours.append([index[(name, k)] for k in (t - 1, t + 1) if (name, k) in index
                           and 0 <= k < n])
    return neighbours


def data_mesh(batch: int):
    """A ("data",) mesh over the devices when the batch splits evenly over more than one, else
    None (single device)."""
    devices = jax.devices()
    if batch < 2 or len(devices) < 2:
        return None
    count = max(d for d in range(1, len(devices) + 1) if batch % d == 0)
    return Mesh(np.asarray(devices[:count]), ("data",)) if count > 1 else None


def put_batch(batch: dict, mesh) -> dict:
    """Host batch -> device arrays; with a mesh, the batch axis is split over its "data" axis."""
    if mesh is None:
        return {k: jnp.asarray(v) for k, v in batch.items()}
    sharding = NamedSharding(mesh, PartitionSpec("data"))
    return {k: jax.device_put(np.asarray(v), sharding) for k, v in batch.items()}


def replicate(tree, mesh):
    """Puts a pytree on every device of the mesh (no-op without one)."""
    if mesh is None:
        return tree
    return jax.device_put(tree, NamedSharding(mesh, PartitionSpec()))


def configured_editor(config: EditConfig):
    """The 2D editor `config` names, with its options."""
    options = {"semantic": dict(noise=config.editor_noise, keeps=config.editor_keeps,
                                 bleed=config.editor_bleed, modes=config.editor_modes),
               "ip2p": dict(folder=config.ip2p_folder)}.get(config.editor, {})
    return make_editor(config.editor, **options)


def editor_context(view, where: tuple, labels=None, canonical=None, samples=None) -> dict:
    """The context a 2D editor reads (`editors` protocol) from a `step.Preview` of one view;
    where: (camera, sequence, frame); labels: (H, W) region labels of the view to use instead
    of the avatar's rendered ones (a training view's projected mesh labels); canonical: (H, W,
    3) head-space positions to use instead of the avatar's rendered ones (the tracked mesh's
    rest positions projected into the view); samples: (H, W, S) region labels of S rays in
    each pixel (the same projection: how much of an edge pixel each region covers)."""
    regions = np.asarray(view.regions) if labels is None else np.maximum(labels, -1)
    coords = np.asarray(view.coords) if canonical is None else np.asarray(canonical)
    context = dict(regions=regions, canonical=coords, normals=np.asarray(view.normals),
                   view=tuple(where))
    if samples is not None:
        context["samples"] = np.maximum(samples, -1)
    return context


def showing_views(scene, region: tuple, stride: int | None = None) -> np.ndarray | None:
    """(K, 2) int (camera, training-frame row) of the training views that show the region
    (named regions `region`): at least `SHOWING_FRACTION` of the pixels the region covers in
    its 90th-percentile view, from the tracked mesh's labels projected into the views
    (`types.training_labels`, every `stride`-th pixel). None when nearly all views show it (the
    sampler then draws cameras and frames independently, as without a region)."""
    stride = stride or max(1, round(scene.width / 128))
    labels = training_labels(scene, stride)[np.asarray(scene.train_cameras)]
    counts = np.isin(labels, [head.REGION_ID[n] for n in region]).sum((-2, -1))  # (C, T)
    threshold = max(1.0, SHOWING_FRACTION * float(np.percentile(counts, 90)))
    cams, rows = np.nonzero(counts >= threshold)
    if len(cams) >= ALL_VIEWS * counts.size or len(cams) == 0:
        return None
    return np.stack([np.asarray(scene.train_cameras)[cams], rows], -1).astype(np.int64)


@functools.partial(jax.jit, static_argnums=(2, 3))
def draw(key, i, batch: int, uniform: bool, cameras, rows, showing, choices):
    """Every random index of iteration `i` in one device call: (cams (B,), frame rows (B,),
    neighbour choices (B,), edit keys (2B + 1, 2)), as `jax.random` draws them from `key`.

    uniform: cameras from `cameras` (C,) and frame rows from `rows` frame rows independently;
      else a (camera, frame row) pair from `showing` (S, 2).
    choices: (R,) int32, how many temporal neighbours each frame row has; sample b picks one
      with edit key B + b.
    """
    k_sample, k_edit = jax.random.split(jax.random.fold_in(key, i))
    if uniform:
        cams = cameras[jax.random.randint(k_sample, (batch,), 0, cameras.shape[0])]
        frames = jax.random.randint(jax.random.fold_in(k_sample, 1), (batch,), 0, rows)
    else:
        cams, frames = showing[jax.random.randint(k_sample, (batch,), 0, showing.shape[0])].T
    edit_keys = jax.random.split(k_edit, 2 * batch + 1)
    neighbour = jax.vmap(lambda k, n: jax.random.randint(k, (), 0, n))(
        edit_keys[batch:2 * batch], choices[frames])
    return cams, frames, neighbour, edit_keys


class EditSampler:
    """Samples (camera, frame) pairs and produces their 2D edits.

    Args:
      config: the edit's settings (editor, batch, prompt, region, ...).
      scene: the scene (training images: the original the editor is conditioned on).
      pairs: the training (sequence, frame) pairs, in rig frame order.
      preview: `step.make_preview(...)` function; rig and canonical (N, 6) for it.
      region_fns: (`region.make_tracer()`, `region.make_coverage()`) jitted functions.
      editor: a 2D editor object used instead of `config.editor` (benchmarks' oracle).

    `votes` (N, 2) holds the `auto` region's accumulated tracing; `editable()` is the region's
    (N,) bool selection; the cache holds composited targets.
    """

    def __init__(self, config: EditConfig, scene, pairs, preview, rig, canonical, region_fns,
                 editor=None):
        self.config, self.scene, self.pairs = config, scene, pairs
        self.preview, self.rig, self.canonical = preview, rig, canonical
        self.neighbours = frame_table(scene, pairs)
        self.editor = editor or configured_editor(config)
        self.cache: dict = {}  # (cam, row) -> uint8 edit
        self.dataset: dict = {}  # in2n: (cam, row) -> uint8 edited dataset image
        self.spots = [(int(cam), row) for row in range(len(pairs))
                      for cam in scene.train_cameras]
        self.region = edit_region.parse_region(config.region, config.prompt)
        self.trace, self.coverage = region_fns
        labels = np.asarray(rig.regions)
        self.votes = np.zeros((len(labels), 2))
        self.fixed = (np.ones(len(labels), bool) if self.region == ("none",) else
                      None if self.region == ("auto",) else
                      edit_region.named_selection(labels, self.region))
        self.named = self.region not in (("none",), ("auto",))  # regions the labels name
        self.showing = showing_views(scene, self.region) if self.named else None
        self.label_cache: dict = {}
        self.sample_cache: dict = {}
        self.rest_cache: dict = {}
        self.stripes = _asks_stripes(config.prompt)
        self.shares: list = []  # share of the region each judged edit changed, in call order
        self.colours: list = []  # (3,) colour of each read call (`calibration`), in call order
        # What `draw` samples from: cameras, (camera, frame row) pairs, neighbour counts.
        self.draw_tables = (jnp.asarray(scene.train_cameras, jnp.int32),
                            jnp.asarray(np.zeros((1, 2)) if self.showing is None
                                        else self.showing, jnp.int32),
                            jnp.asarray([max(len(n), 1) for n in self.neighbours], jnp.int32))

    def editable(self) -> np.ndarray:
        """(N,) bool: the Gaussians the edit may move now."""
        return self.fixed if self.fixed is not None else edit_region.select(self.votes)

    def original_image(self, cam, row):
        name, t = self.pairs[row]
        return self.scene.images[name][cam, t]

    def edit(self, params, cam, row, key):
        view = self.preview(params, self.rig, jnp.int32(cam), jnp.int32(row), self.canonical)
        unedited = self.original_image(cam, row) / 255.0
        labels = self.labels(cam, row)
        canonical = self.rest_positions(cam, row) if self.stripes else None
        context = editor_context(view, (cam,) + tuple(self.pairs[row]), labels, canonical,
                                 self.label_samples(cam, row))
        edited = self.whole_edit(np.asarray(view.image), unedited, context, key, labels)
        if self.named and self.config.edit_calibration and not self.stripes:
            edited = self.calibrated(edited, unedited, context.get("samples"), labels)
        if self.region != ("none",):
            edited = self.composited(params, cam, row, edited, unedited, view, labels)
        edited = to_uint8(edited)
        self.cache[(cam, row)] = edited
        return edited

    def whole_edit(self, image, unedited, context: dict, key, labels) -> np.ndarray:
        """The 2D editor's (H, W, 3) edit of a view, clipped to [0, 1]. With a named region, an
        edit that changes (`region.changed_share`) under `PARTIAL` of the median share the
        run's judged edits changed is made again with the key folded with `RETRY_SALT` + k,
        up to `edit_retries` times; the first that is not partial is kept, else the one that
        changed most. Every judged call's share enters the median."""
        c = self.config
        inside = self.region_pixels(labels) if self.named else None
        if inside is None or inside.sum() < JUDGED_PIXELS:
            return np.clip(self.editor.edit(image, unedited, c.prompt, key, context), 0, 1)
        usual = (float(np.median(self.shares)) if len(self.shares) >= USUAL_AFTER else 0.0)
        tries = []
        for k in range(1 + (c.edit_retries if usual >= USUAL_LEAST else 0)):
            k_edit = key if k == 0 else jax.random.fold_in(key, RETRY_SALT + k)
            edited = np.clip(self.editor.edit(image, unedited, c.prompt, k_edit, context), 0, 1)
            share = edit_region.changed_share(edited, unedited, inside, CHANGED)
            self.shares.append(share)
            tries.append((share, edited))
            if share >= PARTIAL * usual:
                return edited
        return max(tries, key=lambda t: t[0])[1]

    def calibrated(self, edited, unedited, samples, labels) -> np.ndarray:
        """The (H, W, 3) edit brought to the colour of the run's edits so far
        (`calibration`): its colour read on the pixels all of whose rays (the (H, W, S) label
        `samples`; without them, the (H, W) `labels`' interior) see the named region, then
        moved by the region's share of each pixel. A call whose colour cannot be read is kept
        as it is and not counted."""
        if samples is None:
            samples = labels[..., None]
        share = self.region_pixels(samples).mean(-1, dtype=np.float32)
        own = calibration.call_colour(edited, unedited,
                                      calibration.pure_pixels(share, samples.shape[-1]))
        if own is None:
            return edited
        self.colours.append(own)
        return calibration.to_consensus(edited, unedited, share, own,
                                        calibration.consensus(self.colours))

    def region_pixels(self, labels: np.ndarray) -> np.ndarray:
        """(H, W) bool: the named region's pixels in a view's (H, W) labels."""
        return np.isin(labels, [head.REGION_ID[n] for n in self.region])

    def labels(self, cam: int, row: int) -> np.ndarray:
        """(H, W) int8 region labels of a training view: the tracked mesh projected into it
        (`types.projected_labels`, what a user has; computed once per view)."""
        if (cam, row) not in self.label_cache:
            self.label_cache[(cam, row)] = projected_labels(self.scene, [self.pairs[row]],
                                                            [cam])[0, 0]
        return self.label_cache[(cam, row)]

    def label_samples(self, cam: int, row: int) -> np.ndarray:
        """(H, W, S) int8 region labels of S rays in each pixel of a training view: the tracked
        mesh projected along them (`types.projected_label_samples`, what a user has; computed
        once per view)."""
        if (cam, row) not in self.sample_cache:
            self.sample_cache[(cam, row)] = projected_label_samples(
                self.scene, [self.pairs[row]], [cam])[0, 0]
        return self.sample_cache[(cam, row)]

    def rest_positions(self, cam: int, row: int) -> np.ndarray:
        """(H, W, 3) the tracked mesh's rest positions projected into a training view
        (`types.projected_rest_positions`, what a user has; computed once per view): where
        stripes go."""
        if (cam, row) not in self.rest_cache:
            self.rest_cache[(cam, row)] = projected_rest_positions(self.scene, self.pairs[row],
                                                                   cam)
        return self.rest_cache[(cam, row)]

    def composited(self, params, cam, row, edited, unedited, view, labels):
        """The edit inside the region's soft mask at this view, the unedited image outside;
        `auto` first votes this edit's change mask into the tracing (which moves the region:
        its coverage is rendered again after the vote). The mask is the named region's
        projected labels (`labels`), or the avatar's coverage of the traced Gaussians (`auto`),
        dilated and blurred, and
        clipped to the avatar's own coverage `view.alpha`: nothing is painted beyond the
        silhouette."""
        c = self.config
        cam_, row_ = jnp.int32(cam), jnp.int32(row)
        if self.region == ("auto",):
            change = edit_region.change_mask(edited, unedited, c.change_threshold)
            self.votes += np.asarray(self.trace(params, self.rig, cam_, row_,
                                                jnp.asarray(change, jnp.float32)), np.float64)
        if self.region == ("auto",):
            coverage = np.asarray(self.coverage(params, self.rig, cam_, row_,
                                                jnp.asarray(self.editable())))
        else:
            coverage = self.region_pixels(labels).astype(np.float32)
        mask = (edit_region.soft_mask(coverage, c.region_dilate, c.region_blur)
                * np.asarray(view.alpha))
        return edit_region.composite(edited, unedited, mask)

    def batch(self, params, i: int, key) -> dict:
        """The i-th batch as host arrays: samples, fresh edits (or in2n's dataset), neighbours."""
        c = self.config
        cams, rows, choice, edit_keys = jax.device_get(draw(
            key, i, c.batch, self.showing is None, self.draw_tables[0], len(self.pairs),
            *self.draw_tables[1:]))
        targets, neighbours = [], []
        if c.dataset_update:  # IN2N: refresh one dataset image per iteration, in order
            spot = self.spots[i % len(self.spots)]
            self.dataset[spot] = self.edit(params, *spot, edit_keys[-1])
        for b, (cam, row) in enumerate(zip(cams.tolist(), rows.tolist())):
            if c.dataset_update:
                target = self.dataset.get((cam, row), self.original_image(cam, row))
            else:
                target = self.edit(params, cam, row, edit_keys[b])
            k_row = (self.neighbours[row] or [row])[int(choice[b])]
            neighbour = self.cache.get((cam, k_row))
            if neighbour is None and c.adversarial:
                neighbour = self.edit(params, cam, k_row, jax.random.fold_in(edit_keys[b], 7))
            targets.append(target)
            neighbours.append(neighbour if neighbour is not None else target)
        return dict(cams=cams.astype(np.int32), frames=rows.astype(np.int32),
                    target=np.stack(targets).astype(np.float32) / 255.0,
                    neighbour=np.stack(neighbours).astype(np.float32) / 255.0)
