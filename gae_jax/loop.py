"""What the fit and the edit loops share: atomic checkpoints and a metrics recorder.

A checkpoint is one `.npz` written atomically: the leaves of named pytrees (`name/i`), extra
host arrays, and a JSON `meta` holding the run's config. The checkpoint it replaces is kept as
`<name>.prev.npz` until the new one is complete, and `load_checkpoint` falls back to it (saying
so) when the newest is unreadable. It rebuilds the pytrees from templates of the same structure
and refuses a checkpoint written with another config, naming the fields that differ; `free`
fields may differ, `growable` ones may grow (more iterations extend a finished run).

`Recorder` keeps the history of per-step metrics. It converts a step's metrics to host floats
only when the next step has been dispatched (`push`), so the host never waits on the device
within the loop; `flush` records what is pending (before a checkpoint and at the end).
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from typing import Callable, Optional

import jax
import numpy as np

from gae_jax.util.fileio import atomic_write_bytes, npz_bytes


def previous_path(path: str) -> str:
    """Where the checkpoint before the newest is kept."""
    return path[:-len(".npz")] + ".prev.npz" if path.endswith(".npz") else path + ".prev"


def remove_checkpoint(path: str) -> None:
    """Deletes a checkpoint and the previous one (a finished run that keeps none)."""
    for p in (path, previous_path(path)):
        if os.path.isfile(p):
            os.remove(p)


def save_checkpoint(path: str, trees: dict, arrays: dict, config, **meta) -> None:
    """Writes pytrees (name -> pytree), host arrays (name -> array) and meta (with the config's
    fields) into one `.npz`, atomically; the checkpoint it replaces becomes the previous one."""
    out = {f"{name}/{i}": np.asarray(leaf) for name, tree in trees.items()
           for i, leaf in enumerate(jax.tree_util.tree_leaves(tree))}
    out.update({f"array/{k}": np.asarray(v) for k, v in arrays.items()})
    blob = json.dumps(dict(meta, config=dataclasses.asdict(config))).encode()
    out["meta"] = np.frombuffer(blob, np.uint8)
    data = npz_bytes(out)
    if os.path.isfile(path):
        os.replace(path, previous_path(path))
    atomic_write_bytes(path, data)


def load_checkpoint(path: str, templates: dict, config, free=(), growable=()):
    """(trees, arrays, meta) of `save_checkpoint`; `templates` gives each pytree's structure
    (a callable receives the arrays and returns the template, for shapes known only from the
    file). An unreadable newest checkpoint falls back to the previous one, with a warning on
    stderr. ValueError when neither is readable or the config differs (see `check_config`)."""
    try:
        return _load(path, templates, config, free, growable)
    except _Unreadable as newest:
        previous = previous_path(path)
        if not os.path.isfile(previous):
            raise ValueError(str(newest)) from None
        print(f"warning: {newest}; resuming from the previous checkpoint {previous}",
              file=sys.stderr)
        try:
            return _load(previous, templates, config, free, growable)
        except _Unreadable as e:
            raise ValueError(f"{newest}; and {e}") from None


class _Unreadable(Exception):
    pass


def _load(path, templates, config, free, growable):
    try:
        with np.load(path) as f:
            meta = json.loads(bytes(f["meta"]).decode())
            check_config(meta["config"], config, path, free, growable)
            arrays = {k[len("array/"):]: f[k] for k in f.files if k.startswith("array/")}
            trees = {}
            for name, template in templates.items():
                template = template(arrays) if callable(template) else template
                leaves, treedef = jax.tree_util.tree_flatten(template)
                trees[name] = jax.tree_util.tree_unflatten(
                    treedef, [jax.numpy.asarray(f[f"{name}/{i}"]) for i in range(len(leaves))])
    except _ConfigDiffers:
        raise
    except Exception as e:  # truncated zip, bad CRC or JSON, missing member: "unreadable"
        raise _Unreadable(f"{path}: not a readable checkpoint ({type(e).__name__}: {e})") \
            from None
    return trees, arrays, meta


class _ConfigDiffers(ValueError):
    """A readable checkpoint written with another config (never a reason to fall back)."""


def with_defaults(saved: dict, config_type) -> dict:
    """`saved` (a config's asdict, from JSON) with the fields it lacks at what a config written
    before the field existed did: `config_type.ABSENT_MEANS[name]` where the field came with a
    default other than the old behaviour, else the field's default (JSON-normalised)."""
    absent = getattr(config_type, "ABSENT_MEANS", {})
    missing = {f.name: absent.get(f.name, f.default) for f in dataclasses.fields(config_type)
               if f.name not in saved and f.default is not dataclasses.MISSING}
    return dict(json.loads(json.dumps(missing)), **saved)


def check_config(saved: dict, config, path: str, free=(), growable=()) -> None:
    """ValueError naming the fields in which `saved` (a config's asdict) differs from `config`,
    other than `free` ones and `growable` ones that grew. A field `saved` lacks (written before
    the field existed) reads as what such a run did (`with_defaults`)."""
    current = json.loads(json.dumps(dataclasses.asdict(config)))
    saved = with_defaults(saved, type(config))
    differ = sorted(k for k in set(saved) | set(current) if saved.get(k) != current.get(k)
                    and k not in free and not (k in growable and k in saved and k in current
                                               and current[k] > saved[k]))
    if differ:
        fields = ", ".join(f"{k} (there {saved.get(k)!r}, here {current.get(k)!r})"
                           for k in differ)
        raise _ConfigDiffers(f"{path}: written by a run with a different "
                             f"{type(config).__name__}: {fields}; use a new --out folder or the "
                             "same flags")


class Recorder:
    """History of per-step metrics with a tqdm bar, one step behind the device.

    Args:
      desc, total, initial: the bar's label, length and starting count.
      history: records so far (a resumed run's).
      progress: show the bar.
      progress_fn: called as progress_fn(steps_done, metrics) for every recorded step.
      postfix: host metrics -> dict shown on the bar, every `postfix_every` records.
    """

    def __init__(self, desc: str, total: int, initial: int = 0, history: Optional[list] = None,
                 progress: bool = False, progress_fn: Optional[Callable] = None,
                 postfix: Optional[Callable[[dict], dict]] = None, postfix_every: int = 1):
        from tqdm import tqdm

        self.history = list(history or [])
        self.progress_fn = progress_fn
        self.postfix, self.postfix_every = postfix, max(postfix_every, 1)
        self.pending, self.desc, self.initial = None, desc, initial
        # The first step compiles (seconds to a minute): say so instead of a wild estimate.
        self.bar = tqdm(total=total, initial=initial, desc=f"{desc} (compiling)",
                        disable=not progress, leave=False)

    def push(self, done: int, metrics: dict) -> None:
        """Metrics (device arrays) of the step that brought the count to `done`."""
        if self.pending is None and len(self.history) == 0 and not self.bar.disable:
            # Restart the clock after compilation so that the rate and the estimate are the
            # steps' own.
            self.bar.reset()
            self.bar.n = self.bar.last_print_n = self.initial
            self.bar.set_description(self.desc)
        self.flush()
        self.pending = (done, metrics)

    def flush(self) -> None:
        if self.pending is None:
            return
        done, metrics = self.pending
        self.pending = None
        host = {k: float(v) for k, v in metrics.items()}
        self.history.append(host)
        self.bar.update(1)
        if self.postfix is not None and done % self.postfix_every == 0:
            self.bar.set_postfix(self.postfix(host))
        if self.progress_fn is not None:
            self.progress_fn(done, host)

    def close(self) -> list:
        self.flush()
        self.bar.close()
        return self.history
