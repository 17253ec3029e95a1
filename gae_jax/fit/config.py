"""Settings of the reconstruction (`ReconstructConfig`, every field a flag of
`python -m gae_jax.reconstruct`) and the small hashable part the jitted step reads
(`FitStepConfig`)."""

from __future__ import annotations

import dataclasses
from typing import Optional

from gae_jax.render.projection import COV2D_DILATION

@dataclasses.dataclass(frozen=True)
class ReconstructConfig:
    """Settings of `fit` (learning rates in GaussianAvatars' triangle-local units).

    `region_weight` weighs the region loss (the rendered regions against the training views'
    projected labels, `fit.step.make_fit_step`); 0 fits colour alone. `label_samples`: each
    pixel's labels are those of several rays in it (`types.training_label_samples`, so that a
    pixel an outline crosses asks for the regions' mix); False: its centre ray's alone.
    `unseen_weight` weighs the same loss in `unseen_views` views no camera took
    (`scene.unseen`: between the training cameras and frames, the expression carried a quarter
    further; the tracked mesh's labels alone), one of them rendered beside each step's training
    view: a region's Gaussians then end where the region does in views they were not fitted
    in, so that recolouring them does not paint their neighbours there. `unseen_from`: the
    fraction of the iterations after which those views join (0: from the first step; the steps
    before it render the training view alone). `region_outline_weight` and
    `unseen_outline_weight`: how many times the pixels near an outline count in the region loss
    of the training views and of those views (`losses.outline_pixels`; 1: as every other pixel,
    the default: weighed more, the thin regions' reconstruction suffers and the seams move no
    more than refitting with another seed moves them, docs/editing.md).

    The Gaussian budget: `per_face` at the start, `max_gaussians` at most (0: no cap). Resolution
    is the scene's. `tile_capacity` 0 sizes the per-tile lists from the initial avatar.
    """

    iterations: int = 400
    per_face: int = 1
    init_opacity: float = 0.9
    init_scale: float = 0.3
    normal_scale: float = 0.3
    lr_means: float = 1e-2
    lr_means_final: float = 1e-4
    lr_quats: float = 1e-3
    lr_scales: float = 1.7e-2
    lr_opacity: float = 5e-2
    lr_colors: float = 5e-3
    dssim_weight: float = 0.2
    position_weight: float = 0.01
    scale_weight: float = 1.0
    region_weight: float = 0.1
    region_outline_weight: float = 1.0
    label_samples: bool = True
    unseen_weight: float = 0.1
    unseen_outline_weight: float = 1.0
    unseen_views: int = 64
    unseen_from: float = 0.0
    sh_degree: Optional[int] = None
    sh_every: int = 500
    densify_every: int = 0
    densify_from: int = 200
    densify_until: float = 0.6
    grad_threshold: float = 2e-4
    split_scale: float = 0.5
    prune_opacity: float = 0.005
    prune_unseen: bool = True
    max_gaussians: int = 0
    tile_capacity: int = 0
    tiles_per_chunk: int = 8
    screen_filter: float = COV2D_DILATION
    checkpoint_every: int = 0
    seed: int = 0

    def __post_init__(self):
        if self.iterations < 1 or self.per_face < 1 or self.tile_capacity < 0:
            raise ValueError("iterations and per_face must be >= 1, tile_capacity >= 0")
        if not 0 < self.init_opacity < 1:
            raise ValueError(f"init_opacity must be in (0, 1), got {self.init_opacity}")
        if self.sh_degree is not None and not 0 <= self.sh_degree <= 3:
            raise ValueError(f"sh_degree must be None or 0..3, got {self.sh_degree}")
        if min(self.densify_every, self.checkpoint_every, self.max_gaussians) < 0:
            raise ValueError("densify_every, checkpoint_every and max_gaussians must be >= 0")
        if not (self.region_outline_weight > 0 and self.unseen_outline_weight > 0):
            raise ValueError(f"region_outline_weight and unseen_outline_weight must be > 0, got "
                             f"{self.region_outline_weight} and {self.unseen_outline_weight}")
        if not (self.unseen_weight >= 0 and self.unseen_views >= 1):
            raise ValueError(f"unseen_weight must be >= 0 and unseen_views >= 1, got "
                             f"{self.unseen_weight} and {self.unseen_views}")
        if not 0 <= self.unseen_from < 1:
            raise ValueError(f"unseen_from is a fraction of the iterations in [0, 1), got "
                             f"{self.unseen_from}")
        if not self.screen_filter >= 0:
            raise ValueError(f"screen_filter is px^2 added to a covariance, >= 0; got "
                             f"{self.screen_filter}")
        if not 0 <= self.densify_until <= 1:
            raise ValueError(f"densify_until is a fraction of the iterations, got "
                             f"{self.densify_until}")


@dataclasses.dataclass(frozen=True)
class FitStepConfig:
    """What the jitted fit step reads: losses, learning rates, the SH schedule (hashable)."""

    iterations: int
    lr_means: float
    lr_means_final: float
    lr_quats: float
    lr_scales: float
    lr_opacity: float
    lr_colors: float
    dssim_weight: float
    position_weight: float
    scale_weight: float
    region_weight: float
    region_outline_weight: float
    unseen_weight: float
    unseen_outline_weight: float
    sh_degree: Optional[int]
    sh_every: int
    tiles_per_chunk: int

    @classmethod
    def of(cls, config: ReconstructConfig) -> "FitStepConfig":
        return cls(**{f.name: getattr(config, f.name) for f in dataclasses.fields(cls)})
