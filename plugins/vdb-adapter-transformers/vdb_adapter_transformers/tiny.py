"""Tiny random-weight models of real transformers classes, built locally (no hub), for tests and smoke runs.

* :func:`byte_tokenizer` — a byte-level tokenizer (every UTF-8 byte is one token) with named special tokens,
  as a ``PreTrainedTokenizerFast``; deterministic, nothing trained or downloaded.
* :func:`tiny_llama`, :func:`tiny_qwen2_5_vl`, :func:`tiny_qwen3_vl` — a decoder-only LM and two
  vision-language models with a few layers of width 32, weights drawn from ``torch.manual_seed(seed)``.
* :func:`image_processor` — the Qwen-VL families' own image processor, sized for the tiny vision tower.
* :func:`vlm_inputs` — processor outputs for a prompt with image placeholders: what ``Qwen2_5_VLProcessor``
  / ``Qwen3VLProcessor`` return (``input_ids`` with every ``<|image_pad|>`` expanded to the image's merged
  patch count, ``attention_mask``, ``mm_token_type_ids``, ``pixel_values``, ``image_grid_thw``), built
  from the image processor and the tokenizer, because the processor classes themselves also construct a
  video processor that needs torchvision.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
from tokenizers import Tokenizer, decoders, models, pre_tokenizers
from transformers import (
    LlamaConfig,
    LlamaForCausalLM,
    PreTrainedTokenizerFast,
    Qwen2_5_VLConfig,
    Qwen2_5_VLForConditionalGeneration,
    Qwen3VLConfig,
    Qwen3VLForConditionalGeneration,
)

#: Special tokens of the Qwen-VL prompt layout (vision markers and placeholders), first in every tiny vocabulary.
VISION_TOKENS = ("<|pad|>", "<|vision_start|>", "<|vision_end|>", "<|image_pad|>", "<|video_pad|>")
IMAGE_PAD = "<|image_pad|>"


def byte_tokenizer(specials: Sequence[str] = ()) -> PreTrainedTokenizerFast:
    """A byte-level tokenizer: ids ``0 … len(VISION_TOKENS + specials) - 1`` are the special tokens (in that
    order), then one id per byte; ``decode(encode(text)) == text`` for every string."""
    names = list(dict.fromkeys([*VISION_TOKENS, *specials]))
    vocab = {name: i for i, name in enumerate(names)}
    for char in sorted(pre_tokenizers.ByteLevel.alphabet()):
        vocab[char] = len(vocab)
    tokenizer = Tokenizer(models.BPE(vocab=vocab, merges=[]))
    tokenizer.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False, use_regex=False)
    tokenizer.decoder = decoders.ByteLevel()
    tokenizer.add_special_tokens(names)
    return PreTrainedTokenizerFast(tokenizer_object=tokenizer, pad_token="<|pad|>")


def _text(vocab_size: int, max_positions: int, layers: int, mrope: list[int] | None) -> dict:
    config = dict(vocab_size=vocab_size, hidden_size=32, intermediate_size=64, num_hidden_layers=layers,
                  num_attention_heads=4, num_key_value_heads=2, max_position_embeddings=max_positions)
    if mrope is not None:
        config["rope_parameters"] = {"rope_type": "default", "rope_theta": 10000.0, "mrope_section": mrope}
    return config


def _vision_ids(tokenizer: PreTrainedTokenizerFast) -> dict[str, int]:
    ids = tokenizer.convert_tokens_to_ids
    return dict(image_token_id=ids(IMAGE_PAD), video_token_id=ids("<|video_pad|>"),
                vision_start_token_id=ids("<|vision_start|>"), vision_end_token_id=ids("<|vision_end|>"))


def tiny_llama(vocab_size: int, seed: int = 0, max_positions: int = 256, layers: int = 2) -> LlamaForCausalLM:
    """A random-weight ``LlamaForCausalLM`` (width 32, 4 heads, 2 KV heads), in eval mode."""
    torch.manual_seed(seed)
    return LlamaForCausalLM(LlamaConfig(**_text(vocab_size, max_positions, layers, None))).eval()


def tiny_qwen2_5_vl(tokenizer: PreTrainedTokenizerFast, seed: int = 0, max_positions: int = 512,
                    layers: int = 2) -> Qwen2_5_VLForConditionalGeneration:
    """A random-weight ``Qwen2_5_VLForConditionalGeneration`` (patch 14, merge 2) for ``tokenizer``."""
    text = {**_text(len(tokenizer), max_positions, layers, [2, 1, 1]), "bos_token_id": None, "eos_token_id": None}
    vision = dict(depth=2, hidden_size=32, intermediate_size=64, num_heads=2, patch_size=14, spatial_merge_size=2,
                  temporal_patch_size=2, window_size=56, out_hidden_size=32, fullatt_block_indexes=[1])
    torch.manual_seed(seed)
    config = Qwen2_5_VLConfig(text_config=text, vision_config=vision, **_vision_ids(tokenizer))
    return Qwen2_5_VLForConditionalGeneration(config).eval()


def tiny_qwen3_vl(tokenizer: PreTrainedTokenizerFast, seed: int = 0, max_positions: int = 1024,
                  layers: int = 2) -> Qwen3VLForConditionalGeneration:
    """A random-weight ``Qwen3VLForConditionalGeneration`` (patch 16, merge 2, interleaved multimodal RoPE,
    one deepstack layer) for ``tokenizer``."""
    text = _text(len(tokenizer), max_positions, layers, [2, 1, 1])
    text["head_dim"] = 8
    text["rope_parameters"]["mrope_interleaved"] = True
    vision = dict(depth=2, hidden_size=32, intermediate_size=64, num_heads=2, patch_size=16, spatial_merge_size=2,
                  temporal_patch_size=2, out_hidden_size=32, num_position_embeddings=64, deepstack_visual_indexes=[0])
    torch.manual_seed(seed)
    config = Qwen3VLConfig(text_config=text, vision_config=vision, **_vision_ids(tokenizer))
    return Qwen3VLForConditionalGeneration(config).eval()


def image_processor(model, min_pixels: int = 64 * 64, max_pixels: int = 160 * 160):
    """The Qwen-VL image processor matching ``model``'s vision tower (patch, merge and temporal patch sizes),
    resizing every image to between ``min_pixels`` and ``max_pixels`` pixels."""
    from transformers import Qwen2VLImageProcessorPil

    vision = model.config.vision_config
    return Qwen2VLImageProcessorPil(patch_size=vision.patch_size, merge_size=vision.spatial_merge_size,
                                    temporal_patch_size=vision.temporal_patch_size,
                                    size={"shortest_edge": min_pixels, "longest_edge": max_pixels})


def vlm_inputs(tokenizer: PreTrainedTokenizerFast, processor, prompt: str,
               images: Sequence[np.ndarray]) -> dict[str, torch.Tensor]:
    """Processor outputs (batch 1) for ``prompt``, whose ``<|image_pad|>`` placeholders (one per image, in
    order) are expanded to each image's merged patch count, exactly as the Qwen-VL processors do."""
    if prompt.count(IMAGE_PAD) != len(images):
        raise ValueError(f"the prompt has {prompt.count(IMAGE_PAD)} image placeholders for {len(images)} images")
    pixels = processor(images=list(images), return_tensors="pt") if images else {}
    merge = processor.merge_size ** 2
    pieces = prompt.split(IMAGE_PAD)
    text = pieces[0]
    for i, piece in enumerate(pieces[1:]):
        text += IMAGE_PAD * (int(pixels["image_grid_thw"][i].prod()) // merge) + piece
    ids = torch.tensor([tokenizer(text)["input_ids"]], dtype=torch.long)
    types = (ids == tokenizer.convert_tokens_to_ids(IMAGE_PAD)).to(torch.int32)
    return {"input_ids": ids, "attention_mask": torch.ones_like(ids), "mm_token_type_ids": types, **dict(pixels)}
