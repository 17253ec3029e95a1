"""Densify and prune outside jit (array sizes change): a pure `densify_and_prune(state, ...)`.

Gaussians whose mean screen gradient exceeds the threshold are cloned (small) or split (large),
nearly transparent ones are pruned and, with `prune_unseen`, so are those that contributed to no
pixel of any sampled view since the last round (the back of the head, the closed mouth's inside:
a frontal rig never sees them). Optimiser moments follow each Gaussian; `max_gaussians` caps
growth.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from gae_jax.fit.config import ReconstructConfig
from gae_jax.fit.step import FitState
from gae_jax.model import avatar as av


def _gather_state(state: FitState, source: np.ndarray, params: dict) -> FitState:
    """State for re-indexed Gaussians: optimiser moments follow `source` (old indices)."""
    old_n = state.grad_sum.shape[0]
    index = jnp.asarray(source)

    def follow(x):
        return x[index] if getattr(x, "ndim", 0) >= 1 and x.shape[0] == old_n else x

    opt_state = jax.tree_util.tree_map(follow, state.opt_state)
    n = source.shape[0]
    return FitState(params, opt_state, state.key, state.step, jnp.zeros((n,), jnp.float32),
                    jnp.zeros((n,), jnp.int32))


def densify_and_prune(state: FitState, avatar_fixed: av.Avatar, config: ReconstructConfig,
                      num_faces: int) -> tuple[FitState, av.Avatar]:
    """One densify/prune round on the host; returns the new state and the new fixed arrays."""
    a = av.Avatar(binding=avatar_fixed.binding, regions=avatar_fixed.regions, **state.params)
    mean_grad = np.asarray(state.grad_sum) / np.maximum(np.asarray(state.seen), 1)
    big = np.asarray(jnp.max(a.log_scales, axis=-1)) > math.log(config.split_scale)
    grow = mean_grad >= config.grad_threshold
    room = (config.max_gaussians - a.num) if config.max_gaussians else a.num
    if grow.sum() > max(room, 0):  # keep the strongest gradients within the budget
        keep = np.argsort(-mean_grad)[:max(room, 0)]
        grow = np.zeros_like(grow)
        grow[keep] = True
    key, sub = jax.random.split(state.key)
    a, source = av.densify(a, grow & ~big, grow & big, sub, return_source=True)
    opacity = 1 / (1 + np.exp(-np.asarray(a.opacity_logits)))
    remove = opacity < config.prune_opacity
    if config.prune_unseen:
        seen = np.asarray(state.seen)[source]
        remove |= seen == 0
    a, kept = av.prune(a, remove, num_faces, return_source=True,
                       keep_every_face=not config.prune_unseen)
    source = source[kept]
    new = _gather_state(dataclasses.replace(state, key=key), source, a.trainable())
    return new, a
