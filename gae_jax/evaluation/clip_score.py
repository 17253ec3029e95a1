"""CLIP-S and CLIP-C (Instruct-NeRF2NeRF's metrics, used by the paper) from a local CLIP folder.

  CLIP-S (text-image direction similarity): mean over frames of
      cos(I(ours) - I(original), T(target caption) - T(source caption));
  CLIP-C (direction consistency): mean over consecutive frames t, t+1 of one camera of
      cos(I(ours_t) - I(original_t), I(ours_t+1) - I(original_t+1)),
where I and T are CLIP's unit-normalised image and text embeddings (as InstructPix2Pix's
`ClipSimilarity`, which Instruct-NeRF2NeRF uses) and "original" is the unedited avatar's render.

The folder is a Hugging Face CLIP checkpoint (config.json, Flax or PyTorch weights, tokenizer
files, optionally preprocessor_config.json); it is read with `local_files_only` and run with
transformers' Flax CLIP. No CLIP weights ship with any package reachable here, so the metrics are
computed only when a folder is given.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os

import jax
import jax.numpy as jnp
import numpy as np

OPENAI_MEAN = (0.48145466, 0.4578275, 0.40821073)
OPENAI_STD = (0.26862954, 0.26130258, 0.27577711)
@dataclasses.dataclass(frozen=True)
class Clip:
    """A loaded CLIP: the Flax model, its tokenizer, input size and normalisation."""

    model: object
    tokenizer: object
    size: int
    mean: tuple
    std: tuple

    def image_embeddings(self, images) -> np.ndarray:
        """(N, D) unit embeddings of (N, H, W, 3) images in [0, 1]."""
        x = jnp.asarray(images, jnp.float32)
        x = jax.image.resize(x, (x.shape[0], self.size, self.size, 3), "bicubic")
        x = (jnp.clip(x, 0, 1) - jnp.asarray(self.mean).reshape(1, 1, 1, 3)) / jnp.asarray(
            self.std).reshape(1, 1, 1, 3)
        with _third_party_numerics():
            return _unit(self.model.get_image_features(pixel_values=x.transpose(0, 3, 1, 2)))

    def text_embeddings(self, texts: list) -> np.ndarray:
        """(N, D) unit embeddings of N strings."""
        tokens = self.tokenizer(list(texts), padding="max_length", truncation=True,
                                max_length=self.tokenizer.model_max_length, return_tensors="np")
        with _third_party_numerics():
            return _unit(self.model.get_text_features(input_ids=tokens["input_ids"],
                                                      attention_mask=tokens["attention_mask"]))


@contextlib.contextmanager
def _third_party_numerics():
    """transformers' Flax code relies on JAX's default implicit promotion."""
    with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
        yield


def check_folder(folder: str) -> None:
    """FileNotFoundError unless `folder` looks like a CLIP checkpoint (has config.json)."""
    if not os.path.isfile(os.path.join(folder, "config.json")):
        raise FileNotFoundError(f"{folder!r} is not a CLIP folder (no config.json)")


def load_clip(folder: str) -> Clip:
    """Loads a local CLIP folder; clear errors when it or transformers is missing."""
    check_folder(folder)
    try:
        import transformers
    except ImportError as e:
        raise ImportError("CLIP metrics need transformers (pip install 'gae-jax[ip2p]')") from e
    from_pt = not os.path.isfile(os.path.join(folder, "flax_model.msgpack"))
    with _third_party_numerics():
        model = transformers.FlaxCLIPModel.from_pretrained(folder, local_files_only=True,
                                                           from_pt=from_pt)
    tokenizer = transformers.CLIPTokenizer.from_pretrained(folder, local_files_only=True)
    mean, std = OPENAI_MEAN, OPENAI_STD
    pre = os.path.join(folder, "preprocessor_config.json")
    if os.path.isfile(pre):
        with open(pre) as f:
            cfg = json.load(f)
        mean, std = tuple(cfg.get("image_mean", mean)), tuple(cfg.get("image_std", std))
    return Clip(model, tokenizer, int(model.config.vision_config.image_size), mean, std)


def _unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float64)
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)


def direction_similarity(clip: Clip, originals, edits, source: str, target: str) -> float:
    """CLIP-S over (N, H, W, 3) renders of the original and the edited avatar."""
    d_img = _unit(clip.image_embeddings(edits) - clip.image_embeddings(originals))
    t = clip.text_embeddings([source, target])
    d_txt = _unit(t[1] - t[0])
    return float(np.mean(d_img @ d_txt))


def direction_consistency(clip: Clip, originals, edits) -> float:
    """CLIP-C over (T, H, W, 3) consecutive frames of one camera (T >= 2)."""
    if len(edits) < 2:
        raise ValueError("CLIP-C needs at least two consecutive frames")
    d = _unit(clip.image_embeddings(edits) - clip.image_embeddings(originals))
    return float(np.mean(np.sum(d[1:] * d[:-1], axis=-1)))
