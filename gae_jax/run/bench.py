"""Many edit variants in one process: the machinery of the studies in `benchmarks/`.

Runs `edit.edit_avatar` + `score.evaluate_avatars` for many `EditConfig`s in one process:
  * jitted steps are reused across configs with the same `StepConfig` (what the step reads), so
    each distinct step compiles once;
  * the evaluation sets (ray-cast ideal frames) are cached per (scene, prompt);
  * results go to a JSON file after every variant (atomic write) and a rerun skips variants already
    there with the same EditConfig, renderer filter, scenes (edited on, scored on) and original
    avatar, so an interrupted study resumes where it stopped and a changed default, head or
    reconstruction is re-run, not read back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time

import numpy as np

from gae_jax import loop
from gae_jax.edit import edit
from gae_jax.edit.config import EditConfig, StepConfig
from gae_jax.evaluation import protocols, score, truth
from gae_jax.model import avatar as av
from gae_jax.scene.synthetic import scene_fingerprint
from gae_jax.util.fileio import atomic_write_bytes


class Bench:
    """Runs and records edit variants; `results` maps a variant name to its record."""

    def __init__(self, path: str, clip_folder: str = "", frames: int = 4):
        self.path = path
        self.clip_folder = clip_folder
        self.frames = frames
        self.programs: dict = {}  # {StepConfig: (step, preview)}, see `edit.setup`
        self.evalsets: dict = {}
        self.results: dict = {}
        if os.path.isfile(path):
            with open(path) as f:
                self.results = json.load(f).get("variants", {})

    def setup(self, config: EditConfig, scene, original):
        """(`edit.setup`'s EditSetup, whether its step is new): the step and preview are
        compiled once per StepConfig."""
        fresh = StepConfig.of(config) not in self.programs
        setup = edit.setup(config, scene, original, self.programs)
        return setup, fresh

    def evalset(self, scene, prompt: str):
        key = (scene_fingerprint(scene), prompt)
        if key not in self.evalsets:
            self.evalsets[key] = truth.build(scene, prompt, frames=self.frames)
        return self.evalsets[key]

    def run(self, name: str, config: EditConfig, scene, original, extra: dict | None = None,
            evaluate: bool = True, on_edited=None, editor=None, eval_scene=None) -> dict:
        """Edits with `config` (unless `name` is already recorded) and records the result;
        `on_edited(avatar)` sees the edited avatar; `editor` replaces the config's 2D editor
        (the oracle); `eval_scene` is scored instead of `scene` (a scenario that edits on part
        of a scene's training split and is scored on all of it)."""
        scenes = dict(edited_on=scene_fingerprint(scene),
                      scored_on=scene_fingerprint(eval_scene or scene),
                      original=avatar_fingerprint(original))
        recorded = self.results.get(name)
        if recorded is not None and same_settings(recorded, config, scenes):
            return recorded
        setup, fresh = self.setup(config, scene, original)
        start = time.perf_counter()
        edited, history = edit.edit_avatar(setup, editor=editor)
        seconds = time.perf_counter() - start
        if on_edited is not None:
            on_edited(edited)
        finite = bool(all(np.all(np.isfinite(np.asarray(v))) for v in (
            edited.colors, edited.means, edited.log_scales, edited.opacity_logits)))
        record = dict(config=dataclasses.asdict(config), edit_seconds=round(seconds, 1),
                      compiled_in_this_run=fresh, finite=finite, gaussians=int(edited.num),
                      tile_capacity=setup.rig.tile_capacity, renderer=renderer_settings(),
                      scenes=scenes,
                      final_losses=history[-1] if history else {}, **(extra or {}))
        if evaluate and finite:
            t = time.perf_counter()
            record["evaluation"] = score.evaluate_avatars(
                self.evalset(eval_scene or scene, config.prompt), edited, original,
                setup.rig.tile_capacity, setup.step_config.blend, self.clip_folder)
            record["evaluation_seconds"] = round(time.perf_counter() - t, 1)
        self.results[name] = _jsonable(record)
        self.save()
        print(json.dumps({"variant": name, "edit_seconds": record["edit_seconds"],
                          "finite": finite}), flush=True)
        return self.results[name]

    def save(self, **meta):
        blob = dict(meta, machine=machine(), variants=self.results)
        atomic_write_bytes(self.path, json.dumps(blob, indent=1).encode())


def machine() -> dict:
    """Where and when a record was made: UTC date, CPU model, cores, JAX version and backend."""
    import platform
    import time

    import jax

    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f
                        if line.startswith("model name")), cpu)
    except OSError:
        pass
    return dict(date=time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), cpu=cpu,
                cores=os.cpu_count(), jax=jax.__version__, backend=jax.default_backend())


def renderer_settings() -> dict:
    """What a record depends on beyond its EditConfig."""
    from gae_jax.render import projection

    return dict(cov2d_dilation=projection.COV2D_DILATION)


def avatar_fingerprint(avatar: av.Avatar) -> str:
    """16 hex digits of a hash of the avatar's binding, regions and trainable arrays: the
    original avatar a record was edited from (a changed reconstruction changes it)."""
    digest = hashlib.sha256()
    for name in ("binding", "regions") + tuple(av.TRAINABLE):
        array = np.ascontiguousarray(np.asarray(getattr(avatar, name)))
        digest.update(f"{name}{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()[:16]


def same_settings(record: dict, config: EditConfig, scenes: dict | None = None) -> bool:
    """Whether `record` was made with `config` (fields it predates at their defaults), this
    renderer and, when given, the scenes and original avatar {"edited_on", "scored_on",
    "original": fingerprint} (a record that predates any of them matches none)."""
    saved = loop.with_defaults(record.get("config", {}), EditConfig)
    return (saved == _jsonable(dataclasses.asdict(config))
            and record.get("renderer") == renderer_settings()
            and (scenes is None or record.get("scenes") == scenes))


def default_scene_and_avatar(head: str = "procedural"):
    """The 128 px scene of `head` ("procedural", the library's default, or "makehuman", the
    CLI's) and its cached original avatar (the default job's reconstruction)."""
    from gae_jax.edit.config import preset
    from gae_jax.scene import synthetic
    from gae_jax.run.original import original_avatar

    scene = synthetic.make_synthetic_scene(size=128, progress=False, head_kind=head)
    return scene, original_avatar(scene, preset("fast").reconstruct_iterations, progress=False)


def save_figure(fig, path: str) -> None:
    """Writes a matplotlib figure as a PNG at `path` atomically."""
    import io

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=120)
    atomic_write_bytes(path, buffer.getvalue())


def write_report(path: str, text: str) -> None:
    """Writes a study's Markdown (atomically) and prints it."""
    atomic_write_bytes(path, text.encode())
    print(text)


def fmt(value, digits: int = 2) -> str:
    """A table cell: the number with `digits` decimals, "-" for None."""
    return "-" if value is None else f"{value:.{digits}f}"


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x


def score_of(record: dict, protocol: str, metric: str, region: str, who: str = "ours"):
    """A number from a record's evaluation, or None."""
    ev = record.get("evaluation")
    if not ev or protocol not in ev:
        return None
    return ev[protocol][who].get(metric, {}).get(region)


def paired_change(ours: list, control: list) -> tuple[list, float]:
    """Per-seed changes ours - control (lists in seed order) and the larger of the two lists'
    ranges: the run-to-run spread a study sets the mean change against."""
    changes = [a - b for a, b in zip(ours, control)]
    return changes, max(max(ours) - min(ours), max(control) - min(control))


def mean_over_protocols(record: dict, metric: str, region: str, who: str = "ours"):
    values = [score_of(record, p, metric, region, who) for p in protocols.PROTOCOLS]
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 3) if values else None
