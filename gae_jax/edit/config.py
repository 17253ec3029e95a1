"""Settings of one edit (`EditConfig`, every field a flag of `python -m gae_jax.train`), the
presets, and the small hashable `StepConfig` that the jitted step reads.

Presets: `paper` (the paper's settings: forward WABE, L1 + SSIM, all rates 1e-2, 1000
iterations, no edit region), `fast` (the README default: the prompt's region, targets composited
over the unedited image, standard blending, L1, rates decaying to 3 %, the average of the
iterates released, partial 2D edits made again, each region's colour change held coherent),
the ablations `wabe` (forward WABE), `wabe_grad`
(WABE on the gradient), `ssim` (the paper's L1 + SSIM), `no_adv`, `no_region` (every Gaussian may
move), `previous` (the default before region-aware editing: no region, the editor keeping the
render, WABE on the gradient, L1 + SSIM, colour rate 1e-2 with Adam eps 1e-4, no decay), `code`
(the released code's gradient mask and pairs), and the baseline `in2n` (no GAN,
Instruct-NeRF2NeRF's dataset update, no region); `code` and `in2n` release the last iterate
with rates decaying to 10 %, keep every 2D edit and hold no colour change coherent, as the
default did before it averaged its iterates.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from gae_jax.edit import gan, region
from gae_jax.render import wabe


CHOICES = dict(editor=("semantic", "style", "ip2p"), editor_keeps=("render", "original"),
               blend=wabe.MODES, pair_mode=gan.PAIR_MODES, gradient_mask=("none", "code"),
               optimizer=("adam", "sgd"))


@dataclasses.dataclass(frozen=True)
class EditConfig:
    """Settings of one edit (every field is a command-line flag)."""

    # What a checkpoint or benchmark record written before a field existed did, where that is
    # not the field's default: the loss was L1 + SSIM before `ssim_weight`.
    ABSENT_MEANS: ClassVar[dict] = {"ssim_weight": 1.0, "average_decay": 0.0,
                                    "edit_retries": 0, "coherence_weight": 0.0,
                                    "edit_calibration": False}

    prompt: str = "turn the lips blue"
    editor: str = "semantic"
    editor_noise: float = 0.3
    editor_keeps: str = "original"
    editor_bleed: int = 0
    editor_modes: int = 1
    edit_retries: int = 2
    edit_calibration: bool = True
    ip2p_folder: str = ""
    clip_folder: str = ""
    iterations: int = 100
    batch: int = 1
    blend: str = "standard"
    beta: float = wabe.PAPER_BETA
    adversarial: bool = True
    pair_mode: str = "paper"
    gradient_mask: str = "none"
    dataset_update: bool = False
    region: str = "prompt"
    change_threshold: float = 0.1
    region_dilate: int = 2
    region_blur: float = 1.0
    recon_weight: float = 10.0
    ssim_weight: float = 0.0
    d_weight: float = 0.01
    g_weight: float = 0.01
    const_weight: float = 10.0
    coherence_weight: float = 1e-4
    lr: float = 1e-1
    lr_geometry: float = 1e-3
    lr_means: float = 1e-4
    lr_final: float = 0.03
    lr_decay_steps: int = 100
    adam_eps: float = 1e-8
    optimizer: str = "adam"
    average_decay: float = 0.9
    d_lr: float = 1e-4
    gan_max_side: int = 0
    reconstruct_iterations: int = 600
    checkpoint_every: int = 50
    seed: int = 0

    def __post_init__(self):
        for field, allowed in CHOICES.items():
            if getattr(self, field) not in allowed:
                raise ValueError(f"{field} must be one of {allowed}, got "
                                 f"{getattr(self, field)!r}")
        if self.iterations < 1 or self.batch < 1 or self.reconstruct_iterations < 1:
            raise ValueError("iterations, batch and reconstruct_iterations must be >= 1")
        if self.checkpoint_every < 0:
            raise ValueError(f"checkpoint_every must be >= 0, got {self.checkpoint_every}")
        if not 0 <= self.editor_noise <= 1:
            raise ValueError(f"editor_noise must be in [0, 1], got {self.editor_noise}")
        if not 0 <= self.editor_bleed <= 16:
            raise ValueError(f"editor_bleed must be in [0, 16] px, got {self.editor_bleed}")
        if not 0 < self.lr_final <= 1:
            raise ValueError(f"lr_final must be in (0, 1], got {self.lr_final}")
        if not 1 <= self.editor_modes <= 8:
            raise ValueError(f"editor_modes must be in [1, 8], got {self.editor_modes}")
        if not 0 <= self.edit_retries <= 8:
            raise ValueError(f"edit_retries must be in [0, 8], got {self.edit_retries}")
        if not 0 <= self.average_decay < 1:
            raise ValueError(f"average_decay must be in [0, 1), got {self.average_decay}")
        if self.lr_decay_steps < 1:
            raise ValueError(f"lr_decay_steps must be >= 1, got {self.lr_decay_steps}")
        if self.ssim_weight < 0:
            raise ValueError(f"ssim_weight must be >= 0, got {self.ssim_weight}")
        if self.gan_max_side and self.gan_max_side < gan.MIN_SIZE:
            raise ValueError(f"gan_max_side must be 0 (full resolution) or >= {gan.MIN_SIZE}, "
                             f"got {self.gan_max_side}")
        if self.coherence_weight < 0:
            raise ValueError(f"coherence_weight must be >= 0, got {self.coherence_weight}")
        if self.beta < 0:
            raise ValueError(f"beta must be >= 0, got {self.beta}")
        region.parse_region(self.region)
        if not 0 < self.change_threshold < 1:
            raise ValueError(f"change_threshold must be in (0, 1), got {self.change_threshold}")
        if self.region_dilate < 0 or self.region_blur < 0:
            raise ValueError("region_dilate and region_blur must be >= 0")
        if self.editor == "ip2p" and not self.ip2p_folder:
            raise ValueError("the ip2p editor needs --ip2p-folder (a local diffusers folder)")


HELP = {
    "prompt": "the edit instruction",
    "editor": "2D editor: semantic (built in), style (OpenCV), ip2p (local InstructPix2Pix)",
    "editor_noise": "semantic editor's inconsistency across calls, 0..1",
    "editor_keeps": "what the semantic editor returns outside the edited region: render (the "
                    "image it edits) or original (the unedited image it is conditioned on)",
    "editor_bleed": "px the semantic editor's edit spills across the region's outline (3x "
                    "into what the region occludes: teeth behind lips), as diffusion edits do",
    "editor_modes": "answers the semantic editor picks from per call, a multimodal "
                    "inconsistency: stripe phases (2: the stripes land on either half of the "
                    "region) or, for a recolour, shades of the colour from dark to light",
    "edit_retries": "a 2D edit that changes under 75 %% of the share of the region the run's "
                    "edits usually change (a partial edit: one lip of two) is made again with "
                    "another key, up to this many times (0: never; named regions only)",
    "edit_calibration": "bring each 2D edit's colour to the median of the run's edits (the "
                        "edit / unedited ratio on the region's pure pixels; a named region "
                        "recoloured, not striped): a diffusion editor answers in a different "
                        "shade per call",
    "ip2p_folder": "local diffusers InstructPix2Pix folder (editor ip2p)",
    "clip_folder": "local CLIP folder for CLIP-S / CLIP-C in metrics.json (skipped if empty)",
    "iterations": "edit iterations",
    "batch": "(view, time) samples per iteration (sharded over the devices when > 1 exist)",
    "blend": "standard, wabe (paper: forward and backward) or wabe_grad (gradient only)",
    "beta": "WABE's beta",
    "adversarial": "temporal conditional GAN on/off",
    "pair_mode": "GAN pairs: paper (E_t, E_t-E_k) / (C_t, C_t-E_k), or code (released code)",
    "gradient_mask": "none, or code: only front Gaussians (first 10 per pixel), no mouth",
    "dataset_update": "Instruct-NeRF2NeRF dataset update (one image re-edited per iteration)",
    "region": "where the edit may act: prompt (the region the instruction names, else auto), "
              "auto (traced from the 2D edits), region names (lips, hair,brows, ...; from the "
              "avatar's binding) or none (every Gaussian)",
    "change_threshold": "auto region: an edit pixel votes 'changed' when it differs from the "
                        "unedited image by more than this (3x3-blurred, any channel)",
    "region_dilate": "pixels the region's 2D mask grows before compositing the target",
    "region_blur": "sigma in pixels of the composited mask's soft edge",
    "recon_weight": "lambda_1 (L1 + ssim_weight (1 - SSIM))",
    "ssim_weight": "weight of 1 - SSIM beside L1 in the edit's reconstruction term (the paper: "
                   "1; SSIM follows an inconsistent editor's outliers, L1 their median)",
    "d_weight": "lambda_2 (discriminator loss)",
    "g_weight": "lambda_3 (generator loss)",
    "const_weight": "lambda_4 (position / scale regulariser)",
    "coherence_weight": "weight of the prior pulling each edited Gaussian's colour change "
                        "(a ratio; a difference near black) towards its region's mean change, "
                        "rising to full as the rates decay (0: none)",
    "lr": "Adam learning rate of colours",
    "lr_geometry": "Adam learning rate of opacities, scales and rotations",
    "lr_means": "Adam learning rate of local positions",
    "lr_final": "every learning rate decays exponentially to this fraction of itself over "
                "lr_decay_steps iterations, then stays there (1: constant)",
    "lr_decay_steps": "iterations of the learning-rate decay (see lr_final)",
    "adam_eps": "Adam epsilon: gradients well below it barely move a parameter",
    "optimizer": "avatar optimiser: adam, or sgd (momentum 0.9: a step proportional to the "
                 "gradient, so WABE's weights scale the moves; set the rates for it)",
    "average_decay": "the edit releases the running average of its iterates, each iteration "
                     "weighing 1 - average_decay against the average before it (debiased; 0: "
                     "the last iterate): the 2D editor's call-to-call errors average out",
    "d_lr": "discriminator Adam learning rate",
    "gan_max_side": "longest side in px of the pairs the discriminator sees (resized, "
                    "antialiased; 0 = the render's own): at 512 px its convolutions are most "
                    "of an iteration, at 256 a quarter of that",
    "reconstruct_iterations": "steps of the original avatar's reconstruction when no --avatar "
                              "is given (600: teeth 19.7 dB, whole 34.9 against the truth, "
                              "300: 15.4 / 31.8; a new value reconstructs and caches a new "
                              "avatar)",
    "checkpoint_every": "iterations between atomic checkpoints (0: none)",
    "seed": "random seed",
}

PRESETS = {
    "paper": dict(iterations=1000, blend="wabe", adversarial=True, pair_mode="paper",
                  recon_weight=10.0, ssim_weight=1.0, d_weight=0.01, g_weight=0.01,
                  const_weight=10.0, lr=1e-2, lr_geometry=1e-2, lr_means=1e-2, lr_final=1.0,
                  adam_eps=1e-15, region="none", editor_keeps="render", average_decay=0.0,
                  edit_retries=0, coherence_weight=0.0, edit_calibration=False),
    "fast": dict(),
    "no_region": dict(region="none"),
    "previous": dict(region="none", editor_keeps="render", blend="wabe_grad", ssim_weight=1.0,
                     lr=1e-2, lr_final=1.0, adam_eps=1e-4, average_decay=0.0, edit_retries=0,
                     coherence_weight=0.0, edit_calibration=False),
    "wabe": dict(blend="wabe"),
    "wabe_grad": dict(blend="wabe_grad"),
    "ssim": dict(ssim_weight=1.0),
    "no_adv": dict(adversarial=False),
    "code": dict(pair_mode="code", gradient_mask="code", region="none", editor_keeps="render",
                 ssim_weight=1.0, lr_final=0.1, average_decay=0.0, edit_retries=0,
                 coherence_weight=0.0, edit_calibration=False),
    "in2n": dict(adversarial=False, dataset_update=True, region="none", lr_final=0.1,
                 average_decay=0.0, edit_retries=0, coherence_weight=0.0,
                 edit_calibration=False),
}


def preset(name: str, **overrides) -> EditConfig:
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {tuple(PRESETS)}")
    return EditConfig(**{**PRESETS[name], **overrides})


@dataclasses.dataclass(frozen=True)
class StepConfig:
    """What the jitted edit step reads (hashable): blending, losses, optimisers."""

    blend: wabe.Blend
    adversarial: bool
    pair_mode: str
    gradient_mask: str
    recon_weight: float
    ssim_weight: float
    d_weight: float
    g_weight: float
    const_weight: float
    coherence_weight: float
    lr: float
    lr_geometry: float
    lr_means: float
    lr_final: float
    lr_decay_steps: int
    adam_eps: float
    optimizer: str
    average_decay: float
    d_lr: float
    gan_max_side: int

    @classmethod
    def of(cls, config: EditConfig) -> "StepConfig":
        blend = wabe.named(config.blend, config.beta)
        fields = {f.name: getattr(config, f.name) for f in dataclasses.fields(cls)
                  if f.name != "blend"}
        return cls(blend=blend, **fields)
