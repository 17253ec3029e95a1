"""CLIP-S / CLIP-C on a tiny randomly initialised CLIP saved to a local folder."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gae_jax import instructions
from gae_jax.evaluation import clip_score


def tiny_clip_folder(folder):
    transformers = pytest.importorskip("transformers")
    config = transformers.CLIPConfig(
        text_config=dict(hidden_size=16, intermediate_size=32, num_attention_heads=2,
                         num_hidden_layers=1, vocab_size=64,  # 2 + 27 x 2 tokens
                         max_position_embeddings=77,
                         bos_token_id=0, eos_token_id=1, pad_token_id=1),
        vision_config=dict(hidden_size=16, intermediate_size=32, num_attention_heads=2,
                           num_hidden_layers=1, image_size=32, patch_size=8),
        projection_dim=8)
    with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
        model = transformers.FlaxCLIPModel(config, seed=0)
    model.save_pretrained(str(folder))
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1}
    for ch in [chr(c) for c in range(ord("a"), ord("z") + 1)] + ["'"]:
        vocab[ch] = len(vocab)
        vocab[ch + "</w>"] = len(vocab)
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    tok = transformers.CLIPTokenizer(str(folder / "vocab.json"), str(folder / "merges.txt"),
                                     model_max_length=77)
    tok.save_pretrained(str(folder))
    return model


def test_clip_metrics_equal_the_definition(tmp_path):
    model = tiny_clip_folder(tmp_path)
    clip = clip_score.load_clip(str(tmp_path))
    rng = np.random.default_rng(0)
    originals = rng.random((3, 32, 32, 3)).astype(np.float32)
    edits = rng.random((3, 32, 32, 3)).astype(np.float32)
    source, target = instructions.captions("turn the lips blue")

    # the reference: the model's own normalised embeddings, numpy cosines
    mean = np.asarray(clip_score.OPENAI_MEAN).reshape(1, 1, 1, 3)
    std = np.asarray(clip_score.OPENAI_STD).reshape(1, 1, 1, 3)
    tokens = clip.tokenizer([source, target], padding="max_length", max_length=77, truncation=True,
                            return_tensors="np")

    def embeds(images):
        with jax.numpy_dtype_promotion("standard"), jax.numpy_rank_promotion("allow"):
            out = model(input_ids=jnp.asarray(tokens["input_ids"], jnp.int32),
                        attention_mask=jnp.asarray(tokens["attention_mask"], jnp.int32),
                        pixel_values=((images - mean) / std).transpose(0, 3, 1, 2)
                        .astype(np.float32))
        return np.asarray(out.image_embeds, np.float64), np.asarray(out.text_embeds, np.float64)

    img_o, txt = embeds(originals)
    img_e, _ = embeds(edits)

    def cos(a, b):
        return np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)

    d = img_e - img_o
    expected_s = np.mean(cos(d, (txt[1] - txt[0])[None]))
    expected_c = np.mean(cos(d[1:], d[:-1]))
    np.testing.assert_allclose(clip_score.direction_similarity(clip, originals, edits, source,
                                                               target), expected_s, atol=1e-4)
    np.testing.assert_allclose(clip_score.direction_consistency(clip, originals, edits),
                               expected_c, atol=1e-4)
    # identical edits along time are perfectly consistent
    same = np.repeat(edits[:1], 3, 0)
    assert clip_score.direction_consistency(clip, np.repeat(originals[:1], 3, 0), same) == (
        pytest.approx(1.0, abs=1e-5))


def test_captions_and_missing_folder(tmp_path):
    assert instructions.captions("turn the lips blue")[1].endswith("with blue lips")
    assert "oil painting" in instructions.captions("make it an oil painting")[1]
    with pytest.raises(FileNotFoundError, match="config.json"):
        clip_score.load_clip(str(tmp_path))
