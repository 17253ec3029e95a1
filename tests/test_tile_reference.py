"""The benchmark's CPU transcription of the standard tile algorithm draws what the brute-force
per-pixel compositor draws, and its autograd gradients are our renderer's: the speed ratio in
`benchmarks/render.py` compares two renderers of the same image."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax.render import tile_reference
from gae_jax.demo import random_frustum_scene
from gae_jax.render import splat
from tests import bruteforce

torch = pytest.importorskip("torch")
IMAGE_TOL = 1e-6  # float64 on both sides
GRAD_TOL = 1e-3  # relative to the largest gradient entry: float32 JAX against float64 torch


def scene(num=300, width=40, height=36):
    g, camera = random_frustum_scene(num, width, height, seed=3)
    return g, camera


def torch_inputs(g, camera, requires_grad=False):
    t = {k: torch.tensor(np.asarray(getattr(g, k), np.float64), requires_grad=requires_grad)
         for k in ("means", "quats", "scales", "opacities", "colors")}
    return t, torch.tensor(np.asarray(camera.intrinsics, np.float64)), torch.tensor(
        np.asarray(camera.w2c, np.float64))


def test_the_tile_reference_matches_the_brute_force_compositor():
    g, camera = scene()
    t, intr, w2c = torch_inputs(g, camera)
    background = torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64)
    ours = tile_reference.render(t["means"], t["quats"], t["scales"], t["opacities"],
                                 t["colors"], intr, w2c, camera.width, camera.height,
                                 background).numpy()
    reference, _, _ = bruteforce.render(g, camera, background=np.array([0.2, 0.3, 0.4]))
    np.testing.assert_allclose(ours, reference, atol=IMAGE_TOL)


def test_the_tile_references_gradients_are_our_renderers():
    g, camera = scene(num=200)
    weights = np.random.default_rng(0).random((camera.height, camera.width, 3))
    t, intr, w2c = torch_inputs(g, camera, requires_grad=True)
    image = tile_reference.render(t["means"], t["quats"], t["scales"], t["opacities"],
                                  t["colors"], intr, w2c, camera.width, camera.height,
                                  torch.ones(3, dtype=torch.float64))
    (image * torch.tensor(weights)).sum().backward()

    def loss(g):
        out = splat.render(g, camera, background=jnp.ones(3), tile_capacity=256)
        return jnp.sum(out.image * jnp.asarray(weights, jnp.float32))

    grads = jax.jit(jax.grad(loss))(g)
    for name in ("means", "scales", "opacities", "colors"):
        ours = np.asarray(getattr(grads, name), np.float64)
        theirs = t[name].grad.numpy()
        np.testing.assert_allclose(ours, theirs, atol=GRAD_TOL * np.abs(theirs).max(),
                                   err_msg=name)
