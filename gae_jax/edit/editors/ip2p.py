"""InstructPix2Pix through diffusers, from a local folder, with Instruct-NeRF2NeRF's edit.

Needs the optional extra (`pip install torch==2.13.0 "gae-jax[ip2p]"`); torch and diffusers are
imported only when an edit is made. The folder is a diffusers
`StableDiffusionInstructPix2PixPipeline` saved with `save_pretrained` (e.g. a local copy of
timbrooks/instruct-pix2pix). No hub access is attempted.

The edit follows IN2N's `edit_image`: T ~ U{int(1000 lower), ..., int(1000 upper)}; a DDIM
scheduler whose `num_train_timesteps` is set to T before `set_timesteps(steps)` (so the steps
span [0, T) while the noise schedule stays the 1000-step one); the render's latent is noised at
the first timestep; the original image conditions the UNet (latents [c, c, 0]); text embeddings
[prompt, "", ""]; eps = eps_u + s_T (eps_text - eps_img) + s_I (eps_img - eps_u).
"""

from __future__ import annotations

import dataclasses
import os

import jax
import numpy as np

from gae_jax.edit.editors.base import as_image

_PIPELINES: dict = {}  # folder -> loaded pipeline (loading is the slow part)


@dataclasses.dataclass(frozen=True)
class InstructPix2PixEditor:
    folder: str
    guidance_scale: float = 7.5
    image_guidance_scale: float = 1.5
    steps: int = 20
    lower: float = 0.02
    upper: float = 0.98
    device: str = "cpu"

    def __post_init__(self):
        index = os.path.join(self.folder, "model_index.json")
        if not os.path.isfile(index):
            raise FileNotFoundError(
                f"no InstructPix2Pix pipeline at {self.folder!r} (expected {index}); save one "
                "with diffusers' StableDiffusionInstructPix2PixPipeline.save_pretrained and "
                "pass that folder")
        if not 0 <= self.lower < self.upper <= 1:
            raise ValueError(f"need 0 <= lower < upper <= 1, got {self.lower}, {self.upper}")
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")

    def pipeline(self):
        if self.folder not in _PIPELINES:
            try:
                from diffusers import StableDiffusionInstructPix2PixPipeline
            except ImportError as e:
                raise ImportError("the ip2p editor needs torch and diffusers: pip install "
                                  "torch==2.13.0 'gae-jax[ip2p]'") from e
            pipe = StableDiffusionInstructPix2PixPipeline.from_pretrained(
                self.folder, safety_checker=None, requires_safety_checker=False,
                local_files_only=True)
            _PIPELINES[self.folder] = pipe.to(self.device)
        return _PIPELINES[self.folder]

    def edit(self, render, original, prompt: str, key, context: dict | None = None):
        import torch
        from diffusers import DDIMScheduler

        image = as_image(render, "render")
        cond = as_image(original, "original")
        if cond.shape != image.shape:
            raise ValueError(f"original {cond.shape} and render {image.shape} differ in size")
        pipe = self.pipeline()
        k_seed, k_t = jax.random.split(key)
        generator = torch.Generator().manual_seed(int(jax.random.randint(k_seed, (), 0, 2**31 - 1)))
        t_max = int(jax.random.randint(k_t, (), int(1000 * self.lower), int(1000 * self.upper) + 1))
        scheduler = DDIMScheduler.from_config(pipe.scheduler.config)
        scheduler.register_to_config(num_train_timesteps=max(t_max, 1))
        scheduler.set_timesteps(self.steps)

        with torch.no_grad():
            text = self._embed(pipe, [prompt, "", ""])
            vae, unet = pipe.vae, pipe.unet
            dtype = next(unet.parameters()).dtype
            h, w = image.shape[:2]
            size = (max(8, h // 8 * 8), max(8, w // 8 * 8))
            x = self._tensor(image, size, dtype)
            c = self._tensor(cond, size, dtype)
            latents = vae.encode(2 * x - 1).latent_dist.sample(generator) * vae.config.scaling_factor
            image_latents = vae.encode(2 * c - 1).latent_dist.mode()
            image_latents = torch.cat([image_latents, image_latents, torch.zeros_like(image_latents)])
            noise = torch.randn(latents.shape, generator=generator, dtype=latents.dtype)
            latents = scheduler.add_noise(latents, noise, scheduler.timesteps[:1])
            for t in scheduler.timesteps:
                model_in = torch.cat([torch.cat([latents] * 3), image_latents], dim=1)
                eps_text, eps_image, eps_uncond = unet(model_in, t, text).sample.chunk(3)
                eps = (eps_uncond + self.guidance_scale * (eps_text - eps_image)
                       + self.image_guidance_scale * (eps_image - eps_uncond))
                latents = scheduler.step(eps, t, latents).prev_sample
            out = vae.decode(latents / vae.config.scaling_factor).sample
            out = (out / 2 + 0.5).clamp(0, 1)
            out = torch.nn.functional.interpolate(out.float(), size=(h, w), mode="bilinear")
        return out[0].permute(1, 2, 0).cpu().numpy().astype(np.float32)

    @staticmethod
    def _embed(pipe, prompts):
        import torch

        tokens = pipe.tokenizer(prompts, padding="max_length", truncation=True,
                                max_length=pipe.tokenizer.model_max_length, return_tensors="pt")
        with torch.no_grad():
            return pipe.text_encoder(tokens.input_ids.to(pipe.device))[0]

    @staticmethod
    def _tensor(image, size, dtype):
        import torch

        t = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1)[None].float()
        t = torch.nn.functional.interpolate(t, size=size, mode="bilinear")
        return t.to(dtype)
