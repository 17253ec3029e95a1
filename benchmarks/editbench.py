"""Shared machinery of the edit studies (ablation, pareto, stability).

Runs `train.edit_avatar` + `train.evaluate_edit` for many `EditConfig`s in one process:
  * sessions (scene, original avatar, jitted step) are reused across configs that differ only in
    what the step does not read (prompt, editor, noise, seed, iteration count), so each distinct
    step compiles once;
  * the ideal (ray-cast) frames are cached per instruction;
  * results go to a JSON file after every variant (atomic write) and a rerun skips variants already
    there, so an interrupted study resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time

import numpy as np

from gae_jax import train
from gae_jax.util.fileio import atomic_write_bytes

# Fields the jitted step, preview and renderer do not read.
HOST_ONLY = ("prompt", "editor", "editor_noise", "ip2p_folder", "clip_folder", "seed",
             "checkpoint_every", "iterations")


class Bench:
    """Runs and records edit variants; `results` maps a variant name to its record."""

    def __init__(self, path: str, clip_folder: str = "", frames: int = 4):
        self.path = path
        self.clip_folder = clip_folder
        self.frames = frames
        self.sessions: dict = {}
        self.truth_cache: dict = {}
        self.results: dict = {}
        if os.path.isfile(path):
            with open(path) as f:
                self.results = json.load(f).get("variants", {})

    def session(self, config: train.EditConfig, scene=None, original=None):
        fields = dataclasses.asdict(config)
        key = json.dumps({k: v for k, v in fields.items() if k not in HOST_ONLY},
                         sort_keys=True) + str(id(scene)) + str(id(original))
        fresh = key not in self.sessions
        if fresh:
            self.sessions[key] = train.setup(config, scene=scene, original=original)
        return dataclasses.replace(self.sessions[key], config=config), fresh

    def run(self, name: str, config: train.EditConfig, extra: dict | None = None, scene=None,
            original=None, evaluate: bool = True, on_edited=None) -> dict:
        """Edits with `config` (unless `name` is already recorded) and records the result;
        `on_edited(avatar)` sees the edited avatar."""
        if name in self.results:
            return self.results[name]
        session, fresh = self.session(config, scene, original)
        start = time.perf_counter()
        edited, history = train.edit_avatar(session)
        seconds = time.perf_counter() - start
        if on_edited is not None:
            on_edited(edited)
        finite = bool(all(np.all(np.isfinite(np.asarray(v))) for v in (
            edited.colors, edited.means, edited.log_scales, edited.opacity_logits)))
        record = dict(config=dataclasses.asdict(config), edit_seconds=round(seconds, 1),
                      compiled_in_this_run=fresh, finite=finite, gaussians=int(edited.num),
                      tile_capacity=session.data.tile_capacity,
                      final_losses=history[-1] if history else {}, **(extra or {}))
        if evaluate and finite:
            t = time.perf_counter()
            record["evaluation"] = train.evaluate_edit(session, edited, frames=self.frames,
                                                       clip_folder=self.clip_folder,
                                                       truth_cache=self.truth_cache)
            record["evaluation_seconds"] = round(time.perf_counter() - t, 1)
        self.results[name] = _jsonable(record)
        self.save()
        print(json.dumps({"variant": name, "edit_seconds": record["edit_seconds"],
                          "finite": finite}), flush=True)
        return self.results[name]

    def save(self, **meta):
        blob = dict(meta, variants=self.results)
        atomic_write_bytes(self.path, json.dumps(blob, indent=1).encode())


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


def score(record: dict, protocol: str, metric: str, region: str, who: str = "ours"):
    """A number from a record's evaluation, or None."""
    ev = record.get("evaluation")
    if not ev or protocol not in ev:
        return None
    return ev[protocol][who].get(metric, {}).get(region)


def mean_over_protocols(record: dict, metric: str, region: str, who: str = "ours"):
    from gae_jax import evaluate

    values = [score(record, p, metric, region, who) for p in evaluate.PROTOCOLS]
    values = [v for v in values if v is not None]
    return round(float(np.mean(values)), 3) if values else None
