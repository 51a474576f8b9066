"""Lockstep batches on tiny random-weight Qwen3-VL, Qwen2.5-VL and Llama models built locally (no hub).

Rows whose prompts have different lengths and whose images have different sizes (so different grids and
multimodal rope deltas) go through one prefill and advance column by column; each row must equal what the
model computes for it alone — the toolkit's batch-1 functions and the model's own forward pass and
``generate()`` — and a splice of the batch's own texts must be bit-identical to the generation.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vdb_adapter_transformers import lockstep, tiny
from vdb_adapter_transformers import toolkit as tk

pytestmark = pytest.mark.filterwarnings("error::FutureWarning")

TOKENIZER = tiny.byte_tokenizer(["<|cot_start|>", "<|cot_end|>"])
START, END = TOKENIZER.convert_tokens_to_ids("<|cot_start|>"), TOKENIZER.convert_tokens_to_ids("<|cot_end|>")
PAD = TOKENIZER.pad_token_id
BANNED = [PAD, START]
ROW_TOLERANCE = 1e-5  # float32: a row in a padded batch vs alone (measured ~1e-6)
FIDELITY = 1e-4
VISION = "<|vision_start|><|image_pad|><|vision_end|>"


def _image(seed: int, height: int, width: int) -> np.ndarray:
    return (np.random.default_rng(seed).random((height, width, 3)) * 255).astype(np.uint8)


#: (prompt, image sizes): prompts of different lengths, one and two images, images of different sizes.
ROWS = [
    (f"front: {VISION} go", [(96, 160)]),
    (f"front: {VISION} left: {VISION} turn left at the junction", [(80, 120), (64, 64)]),
    (f"{VISION} stop", [(128, 96)]),
]


@pytest.fixture(scope="module", params=["qwen3_vl", "qwen2_5_vl"])
def vlm(request):
    """(model, per-row processor outputs) for each VLM family."""
    build = {"qwen3_vl": tiny.tiny_qwen3_vl, "qwen2_5_vl": tiny.tiny_qwen2_5_vl}[request.param]
    model = build(TOKENIZER)
    processor = tiny.image_processor(model)
    rows = [tiny.vlm_inputs(TOKENIZER, processor, prompt, [_image(i + k, *size) for k, size in enumerate(sizes)])
            for i, (prompt, sizes) in enumerate(ROWS)]
    return model, rows


def test_rows_differ_in_length_and_rope_delta(vlm):
    model, rows = vlm
    alone = [tk.encode_inputs(model, r) for r in rows]
    assert len({s.length for s in alone}) == len(rows)
    assert len({int(s.rope_deltas) for s in alone}) > 1


def test_a_batched_prefill_gives_each_row_its_own_prefix(vlm):
    model, rows = vlm
    for state, inputs in zip(lockstep.encode_inputs_batch(model, rows), rows, strict=True):
        alone = tk.encode_inputs(model, inputs)
        assert state.length == alone.length and torch.equal(state.rope_deltas, alone.rope_deltas)
        assert tk.cache_difference(state, alone) < ROW_TOLERANCE
        assert torch.allclose(state.last_logits, alone.last_logits, atol=ROW_TOLERANCE)


def test_lockstep_generation_is_each_rows_own_generation_and_the_models_own(vlm):
    model, rows = vlm
    decoder = lockstep.LockstepDecoder.from_states(model, lockstep.encode_inputs_batch(model, rows), PAD)
    texts = lockstep.generate_lockstep(decoder, START, END, 10, banned=BANNED)
    for i, inputs in enumerate(rows):
        tokens, alone = tk.generate_between_markers(model, tk.encode_inputs(model, inputs), START, END, 10,
                                                    banned=BANNED)
        assert texts[i] == tokens
        assert tk.native_generate(model, inputs, START, END, 10, banned=BANNED) == tokens
        row = decoder.row_state(i, (START, *tokens, END))
        assert row.length == alone.length and tk.cache_difference(row, alone) < ROW_TOLERANCE
        assert tk.native_difference(model, inputs, row) < FIDELITY


def test_splicing_the_batchs_own_texts_is_bit_identical(vlm):
    model, rows = vlm
    prefixes = lockstep.encode_inputs_batch(model, rows)
    generated = lockstep.LockstepDecoder.from_states(model, prefixes, PAD)
    texts = lockstep.generate_lockstep(generated, START, END, 10, banned=BANNED)
    spliced = lockstep.LockstepDecoder.from_states(model, prefixes, PAD)
    lockstep.splice_lockstep(spliced, texts, START, END)
    for i, text in enumerate(texts):
        fed = (START, *text, END)
        assert tk.kv_digest(generated.row_state(i, fed)) == tk.kv_digest(spliced.row_state(i, fed))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(texts=st.lists(st.lists(st.integers(20, 200), max_size=9), min_size=3, max_size=3))
def test_any_lockstep_splice_equals_each_row_spliced_alone(vlm, texts):
    model, rows = vlm
    decoder = lockstep.LockstepDecoder.from_states(model, lockstep.encode_inputs_batch(model, rows), PAD)
    lockstep.splice_lockstep(decoder, texts, START, END)
    for i, (inputs, text) in enumerate(zip(rows, texts, strict=True)):
        alone = tk.splice_tokens(model, tk.encode_inputs(model, inputs), text, START, END)
        row = decoder.row_state(i, (START, *text, END))
        assert row.length == alone.length and tk.cache_difference(row, alone) < ROW_TOLERANCE
        assert torch.allclose(row.last_logits, alone.last_logits, atol=ROW_TOLERANCE)


def test_a_plain_lm_batch_from_embeddings_matches_each_row():
    model = tiny.tiny_llama(len(TOKENIZER), max_positions=96)
    embeds = torch.randn(3, 7, 32, generator=torch.Generator().manual_seed(1))
    decoder = lockstep.LockstepDecoder.from_embeddings(model, embeds, PAD)
    texts = lockstep.generate_lockstep(decoder, START, END, 8, banned=BANNED)
    for i in range(3):
        tokens, alone = tk.generate_between_markers(model, tk.encode_prefix(model, embeds[i:i + 1]), START, END, 8,
                                                    banned=BANNED)
        assert texts[i] == tokens
        assert tk.cache_difference(decoder.row_state(i), alone) < ROW_TOLERANCE


def test_a_picker_chooses_for_the_open_rows_only():
    model = tiny.tiny_llama(len(TOKENIZER), max_positions=96)
    embeds = torch.randn(2, 5, 32, generator=torch.Generator().manual_seed(2))
    decoder = lockstep.LockstepDecoder.from_embeddings(model, embeds, PAD)
    calls = []

    def pick_rows(logits, banned, picking):
        calls.append(list(picking))
        return [END if len(calls) > 2 else 40 + len(calls)] * len(picking)

    texts = lockstep.generate_lockstep(decoder, START, END, max_tokens=1, pick_rows=pick_rows)
    assert texts == [[41], [41]]
    assert calls == [[True, True], [False, False]]  # the max is reached: the end marker is fed, no draw wanted


def test_a_batch_that_outgrows_the_context_is_refused_in_one_line():
    model = tiny.tiny_llama(len(TOKENIZER), max_positions=12)
    decoder = lockstep.LockstepDecoder.from_embeddings(model, torch.zeros(2, 10, 32), PAD)
    decoder.feed([START, START])
    with pytest.raises(tk.SpliceTooLongError, match="needs 13 positions, more than the model's context of 12"):
        decoder.feed_block([50, 51])


def test_rows_with_and_without_images_cannot_share_a_prefill(vlm):
    model, rows = vlm
    text_only = {k: v for k, v in tiny.vlm_inputs(TOKENIZER, tiny.image_processor(model), "go", []).items()}
    with pytest.raises(ValueError, match="but not in others"):
        lockstep.encode_inputs_batch(model, [rows[0], text_only])
