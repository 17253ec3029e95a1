"""gae_jax: text-driven editing of animatable 3D Gaussian head avatars (GaussianAvatar-Editor).

Modules follow the paper's Method section: `camera`, `projection`, `tiles`, `composite` and
`splat` (the differentiable renderer), `sh` (view-dependent colour), `wabe` (occlusion-aware
blending weights).
"""

__version__ = "0.1.0"
