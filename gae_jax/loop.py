"""What the fit and the edit loops share: atomic checkpoints and a metrics recorder.

A checkpoint is one `.npz` written atomically: the leaves of named pytrees (`name/i`), extra
host arrays, and a JSON `meta` holding the run's config. `load_checkpoint` rebuilds the pytrees
from templates of the same structure and refuses a checkpoint written with another config,
naming the fields that differ.

`Recorder` keeps the history of per-step metrics. It converts a step's metrics to host floats
only when the next step has been dispatched (`push`), so the host never waits on the device
within the loop; `flush` records what is pending (before a checkpoint and at the end).
"""

from __future__ import annotations

import dataclasses
import io
import json
from typing import Callable, Optional

import jax
import numpy as np

from gae_jax.util.fileio import atomic_write_bytes


def save_checkpoint(path: str, trees: dict, arrays: dict, config, **meta) -> None:
    """Writes pytrees (name -> pytree), host arrays (name -> array) and meta (with the config's
    fields) into one `.npz`, atomically."""
    out = {f"{name}/{i}": np.asarray(leaf) for name, tree in trees.items()
           for i, leaf in enumerate(jax.tree_util.tree_leaves(tree))}
    out.update({f"array/{k}": np.asarray(v) for k, v in arrays.items()})
    blob = json.dumps(dict(meta, config=dataclasses.asdict(config))).encode()
    out["meta"] = np.frombuffer(blob, np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **out)
    atomic_write_bytes(path, buffer.getvalue())


def load_checkpoint(path: str, templates: dict, config):
    """(trees, arrays, meta) of `save_checkpoint`; `templates` gives each pytree's structure
    (a callable receives the arrays and returns the template, for shapes known only from the
    file). ValueError for an unreadable file or another config."""
    try:
        f = np.load(path)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: not a readable checkpoint ({e})") from e
    with f:
        meta = json.loads(bytes(f["meta"]).decode())
        check_config(meta["config"], config, path)
        arrays = {k[len("array/"):]: f[k] for k in f.files if k.startswith("array/")}
        trees = {}
        for name, template in templates.items():
            template = template(arrays) if callable(template) else template
            leaves, treedef = jax.tree_util.tree_flatten(template)
            trees[name] = jax.tree_util.tree_unflatten(
                treedef, [jax.numpy.asarray(f[f"{name}/{i}"]) for i in range(len(leaves))])
    return trees, arrays, meta


def check_config(saved: dict, config, path: str) -> None:
    """ValueError naming the fields in which `saved` (a config's asdict) differs from
    `config`."""
    current = json.loads(json.dumps(dataclasses.asdict(config)))
    differ = sorted(k for k in set(saved) | set(current) if saved.get(k) != current.get(k))
    if differ:
        fields = ", ".join(f"{k} (there {saved.get(k)!r}, here {current.get(k)!r})"
                           for k in differ)
        raise ValueError(f"{path}: written by a run with a different {type(config).__name__}: "
                         f"{fields}; use a new --out folder or the same flags")


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
        self.pending = None
        self.bar = tqdm(total=total, initial=initial, desc=desc, disable=not progress,
                        leave=False)

    def push(self, done: int, metrics: dict) -> None:
        """Metrics (device arrays) of the step that brought the count to `done`."""
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
