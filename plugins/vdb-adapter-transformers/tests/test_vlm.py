"""The toolkit on tiny random-weight Qwen3-VL, Qwen2.5-VL and Llama models built locally (no hub).

What is shown: prefix encoding from processor outputs, positions from the model's own logic (multimodal RoPE
deltas for the Qwen-VL families, plain positions for the LM), context limits from the text config, the
selfsplice digest, and the fidelity gate against the model's own forward pass and its own ``generate()``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from vdb_adapter_transformers import tiny
from vdb_adapter_transformers import toolkit as tk

pytestmark = pytest.mark.filterwarnings("error::FutureWarning")

TOKENIZER = tiny.byte_tokenizer(["<|cot_start|>", "<|cot_end|>"])
START, END = TOKENIZER.convert_tokens_to_ids("<|cot_start|>"), TOKENIZER.convert_tokens_to_ids("<|cot_end|>")
BANNED = [TOKENIZER.pad_token_id, START]
PROMPT = "front: <|vision_start|><|image_pad|><|vision_end|> left: <|vision_start|><|image_pad|><|vision_end|> go"
FIDELITY = 1e-4  # float32: one batched pass vs one pass per token


def _images():
    rng = np.random.default_rng(0)
    return [(rng.random((96, 160, 3)) * 255).astype(np.uint8), (rng.random((80, 120, 3)) * 255).astype(np.uint8)]


@pytest.fixture(scope="module", params=["qwen3_vl", "qwen2_5_vl"])
def vlm(request):
    """(model, processor outputs of the prefix, prefix state) for each VLM family."""
    build = {"qwen3_vl": tiny.tiny_qwen3_vl, "qwen2_5_vl": tiny.tiny_qwen2_5_vl}[request.param]
    model = build(TOKENIZER)
    inputs = tiny.vlm_inputs(TOKENIZER, tiny.image_processor(model), PROMPT, _images())
    return model, inputs, tk.encode_inputs(model, inputs)


@pytest.fixture(scope="module")
def llama():
    model = tiny.tiny_llama(len(TOKENIZER), max_positions=96)
    embeds = torch.randn(1, 7, 32, generator=torch.Generator().manual_seed(1))
    return model, embeds, tk.encode_prefix(model, embeds)


def test_prefix_positions_are_the_models_own_rope_index(vlm):
    model, inputs, prefix = vlm
    positions, deltas = model.model.get_rope_index(inputs["input_ids"], inputs["mm_token_type_ids"],
                                                   image_grid_thw=inputs["image_grid_thw"],
                                                   attention_mask=inputs["attention_mask"])
    ours, our_deltas = tk.prefix_positions(model, inputs)
    assert torch.equal(ours, positions)
    assert torch.equal(prefix.rope_deltas, deltas.view(-1, 1))
    # Images take fewer positions than tokens: the delta is negative, so text continues below the cache length.
    assert int(prefix.rope_deltas) < 0
    nxt = prefix.next_position_ids(3)
    assert nxt.shape == (3, 1, 3)
    assert nxt[:, 0, 0].tolist() == [prefix.length + int(prefix.rope_deltas)] * 3


def test_context_limit_comes_from_the_text_config(vlm, llama):
    model, _, _ = vlm
    assert tk.context_limit(model) == model.config.get_text_config().max_position_embeddings
    assert tk.context_limit(llama[0]) == 96


def test_vlm_selfsplice_is_bit_identical_and_matches_the_native_forward_pass(vlm):
    model, inputs, prefix = vlm
    tokens, generated = tk.generate_between_markers(model, tk.fork(prefix), START, END, 10, banned=BANNED)
    assert tokens
    spliced = tk.splice_tokens(model, tk.fork(prefix), tokens, START, END)
    assert tk.kv_digest(spliced) == tk.kv_digest(generated)
    assert tk.native_difference(model, inputs, spliced) < FIDELITY
    native = tk.native_state(model, inputs, spliced.tokens)
    assert native.length == spliced.length
    assert torch.allclose(native.last_logits, spliced.last_logits, atol=1e-4)


def test_vlm_greedy_cot_equals_the_models_own_generate(vlm):
    model, inputs, prefix = vlm
    tokens, _ = tk.generate_between_markers(model, tk.fork(prefix), START, END, 10, banned=BANNED)
    assert tk.native_generate(model, inputs, START, END, 10, banned=BANNED) == tokens


def test_a_dropped_rope_delta_passes_selfsplice_and_fails_fidelity(vlm):
    model, inputs, prefix = vlm
    wrong = dataclasses.replace(tk.fork(prefix), rope_deltas=torch.zeros_like(prefix.rope_deltas))
    tokens, generated = tk.generate_between_markers(model, tk.fork(wrong), START, END, 10, banned=BANNED)
    spliced = tk.splice_tokens(model, tk.fork(wrong), tokens, START, END)
    assert tk.kv_digest(spliced) == tk.kv_digest(generated)  # generation and splice agree with each other …
    assert tk.native_difference(model, inputs, spliced) > 100 * FIDELITY  # … not with the model


def test_vlm_prefill_and_batch_splices_agree_with_sequential(vlm):
    model, inputs, prefix = vlm
    texts = [[40, 41, 42, 43], [50], []]
    batch = tk.splice_batch(model, prefix, texts, START, END, TOKENIZER.pad_token_id, mode="prefill")
    for i, text in enumerate(texts):
        single = tk.splice_tokens(model, tk.fork(prefix), text, START, END)
        prefill = tk.splice_tokens(model, tk.fork(prefix), text, START, END, mode="prefill")
        assert tk.cache_difference(single, prefill) < FIDELITY
        for (kb, vb), (ks, vs) in zip(batch.keys_values(), single.keys_values(), strict=True):
            assert torch.allclose(kb[i : i + 1, :, : single.length], ks, atol=1e-5)
            assert torch.allclose(vb[i : i + 1, :, : single.length], vs, atol=1e-5)


def test_llama_positions_are_plain_and_splices_match_its_forward_pass(llama):
    model, embeds, prefix = llama
    assert prefix.rope_deltas is None
    assert prefix.next_position_ids(2).tolist() == [[7, 8]]
    tokens, generated = tk.generate_between_markers(model, tk.fork(prefix), START, END, 8, banned=BANNED)
    spliced = tk.splice_tokens(model, tk.fork(prefix), tokens, START, END)
    assert tk.kv_digest(spliced) == tk.kv_digest(generated)
    assert tk.native_difference(model, {}, spliced, embeds=embeds) < FIDELITY


def test_llama_processor_inputs_use_plain_positions_and_generate_agrees(llama):
    model, _, _ = llama
    ids = torch.tensor([TOKENIZER("a prompt")["input_ids"]])
    inputs = {"input_ids": ids, "attention_mask": torch.ones_like(ids)}
    prefix = tk.encode_inputs(model, inputs)
    positions, deltas = tk.prefix_positions(model, inputs)
    assert deltas is None and positions.tolist() == [list(range(ids.shape[1]))]
    tokens, generated = tk.generate_between_markers(model, tk.fork(prefix), START, END, 8, banned=BANNED)
    assert tk.native_generate(model, inputs, START, END, 8, banned=BANNED) == tokens
    assert tk.native_difference(model, inputs, generated) < FIDELITY


def test_byte_tokenizer_round_trips_and_keeps_specials_whole():
    text = "Ahead: a red light — stop."
    assert TOKENIZER.decode(TOKENIZER(text)["input_ids"]) == text
    assert TOKENIZER("<|cot_start|>x")["input_ids"][0] == START


def test_vlm_inputs_reject_a_placeholder_count_that_does_not_match():
    model = tiny.tiny_qwen3_vl(TOKENIZER)
    with pytest.raises(ValueError, match="2 image placeholders for 1 images"):
        tiny.vlm_inputs(TOKENIZER, tiny.image_processor(model), PROMPT, _images()[:1])
