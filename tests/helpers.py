"""Small assertion helpers for pytrees (instead of extra assertion libraries)."""

from __future__ import annotations

import importlib.util
import os

import jax
import numpy as np


def tree_allclose(a, b, rtol=1e-6, atol=1e-6) -> None:
    """Asserts two pytrees have the same structure and element-wise close leaves."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb, f"tree structures differ: {ta} vs {tb}"
    for i, (x, y) in enumerate(zip(la, lb)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=rtol, atol=atol,
                                   err_msg=f"leaf {i} differs")


def assert_tree_finite(tree) -> None:
    """Asserts every floating leaf of a pytree is finite."""
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        arr = np.asarray(leaf)
        if np.issubdtype(arr.dtype, np.floating):
            assert np.all(np.isfinite(arr)), f"non-finite values at {jax.tree_util.keystr(path)}"


def random_unit_cotangent(key, tree):
    """A random pytree shaped like `tree` (normal entries), for VJP comparisons."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    keys = jax.random.split(key, len(leaves))
    return jax.tree_util.tree_unflatten(
        treedef, [jax.random.normal(k, np.shape(x), np.asarray(x).dtype)
                  for k, x in zip(keys, leaves)])


def near(mask):
    """Pixels of (..., H, W) `mask` dilated by one pixel (8-neighbourhood)."""
    padded = np.pad(mask, [(0, 0)] * (mask.ndim - 2) + [(1, 1), (1, 1)])
    h, w = mask.shape[-2:]
    return np.any([padded[..., 1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                   for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)


def load_script(path: str):
    """A script of the repository (`tools/...`, `benchmarks/...`, relative to its root) as a
    module, loaded from its file: scripts are not a package."""
    full = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), path)
    spec = importlib.util.spec_from_file_location(os.path.basename(path)[:-3], full)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
