"""Blending weights for front-to-back compositing, including the paper's WABE.

Standard alpha blending composites C = sum_k c_k a_k T_k with T_k = prod_{j<k} (1 - a_j).
WABE (weighted alpha blending equation, GaussianAvatar-Editor eq. 3-4) multiplies each term by a
visibility weight w_k = exp(-beta (1 - T_k)): fully visible Gaussians keep w = 1, Gaussians behind
an opaque occluder get w -> 0, so the edit's gradient stops at the occluder.

A `Blend` is a small static (hashable) description that the compositor reads:
  * `standard()`        w = 1.
  * `wabe(beta)`        w(T) in the forward pass, hence also in the gradients (the paper).
  * `wabe_grad(beta)`   the image is standard blending; each Gaussian's gradient from a pixel is
                        multiplied by its w_k there (what is trained is what is seen at inference,
                        while occluded Gaussians still receive almost no gradient).
Alpha and depth outputs always use standard compositing; the weights act on colour.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

MODES = ("standard", "wabe", "wabe_grad")
PAPER_BETA = 6.0


@dataclasses.dataclass(frozen=True)
class Blend:
    """How colour contributions are weighted by the transmittance in front of them.

    Attributes:
      mode: one of "standard", "wabe", "wabe_grad".
      beta: WABE sharpness (>= 0); ignored by "standard".
    """

    mode: str = "standard"
    beta: float = 0.0

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"unknown blend mode {self.mode!r}; expected one of {MODES}")
        if not (math.isfinite(self.beta) and self.beta >= 0.0):
            raise ValueError(f"beta must be a finite number >= 0, got {self.beta}")

    @property
    def weights_forward(self) -> bool:
        """True when the weights change the rendered colour (and so its exact gradient)."""
        return self.mode == "wabe"

    @property
    def weights_gradient(self) -> bool:
        """True when per-Gaussian gradients are scaled by the weights."""
        return self.mode in ("wabe", "wabe_grad")

    def weight(self, transmittance):
        """w(T) = exp(-beta (1 - T)) for the WABE modes, 1 for standard; same shape as T."""
        if self.mode == "standard":
            return jnp.ones_like(transmittance)
        return jnp.exp(-self.beta * (1.0 - transmittance))

    def weight_times_t_derivative(self, transmittance):
        """d/dT [w(T) T] = w(T) (1 + beta T): how a colour term reacts to its transmittance."""
        if self.mode != "wabe":
            return jnp.ones_like(transmittance)
        return self.weight(transmittance) * (1.0 + self.beta * transmittance)


def standard() -> Blend:
    """Plain 3DGS alpha blending (w = 1)."""
    return Blend("standard", 0.0)


def wabe(beta: float = PAPER_BETA) -> Blend:
    """The paper's WABE, weights in the forward pass (and therefore in the gradients)."""
    return Blend("wabe", float(beta))


def wabe_grad(beta: float = PAPER_BETA) -> Blend:
    """Standard image, gradients weighted per Gaussian and pixel by w_k."""
    return Blend("wabe_grad", float(beta))


BLENDS = {"standard": lambda beta: standard(), "wabe": wabe, "wabe_grad": wabe_grad}


def named(name: str, beta: float = PAPER_BETA) -> Blend:
    """The blend called `name` ("standard", "wabe" or "wabe_grad"; beta unused by standard)."""
    if name not in BLENDS:
        raise ValueError(f"unknown blend {name!r}; choose from {', '.join(BLENDS)}")
    return BLENDS[name](beta)
