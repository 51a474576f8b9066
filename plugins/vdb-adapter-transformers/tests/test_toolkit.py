"""The adapter toolkit on a tiny randomly initialised Llama decoder (no weights file needed)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from transformers import LlamaConfig, LlamaForCausalLM
from vdb_adapter_transformers import toolkit
from vladrivebench import ConfigError, VdbError

VOCAB, START, END, PAD = 40, 1, 2, 0

# The toolkit uses the current transformers cache API: a deprecation warning is a failure.
pytestmark = pytest.mark.filterwarnings("error::FutureWarning")


@pytest.fixture(scope="module")
def lm():
    torch.manual_seed(0)
    config = LlamaConfig(vocab_size=VOCAB, hidden_size=32, intermediate_size=64, num_hidden_layers=2,
                         num_attention_heads=4, num_key_value_heads=2, max_position_embeddings=48)
    return LlamaForCausalLM(config).eval()


@pytest.fixture(scope="module")
def prefix(lm):
    embeds = torch.randn(1, 6, 32, generator=torch.Generator().manual_seed(1))
    return toolkit.encode_prefix(lm, embeds)


def test_sequential_splice_of_own_cot_is_bit_identical(lm, prefix):
    tokens, generated = toolkit.generate_between_markers(lm, toolkit.fork(prefix), START, END, 12,
                                                         banned=[PAD, START])
    assert tokens, "the random model should write at least one token before the limit"
    spliced = toolkit.splice_tokens(lm, toolkit.fork(prefix), tokens, START, END, mode="sequential")
    assert toolkit.kv_digest(spliced) == toolkit.kv_digest(generated)
    assert toolkit.cache_difference(spliced, generated) == 0.0
    assert torch.equal(spliced.last_hidden, generated.last_hidden)


def test_prefill_splice_is_close_and_its_difference_is_reported(lm, prefix):
    tokens, generated = toolkit.generate_between_markers(lm, toolkit.fork(prefix), START, END, 12,
                                                         banned=[PAD, START])
    spliced = toolkit.splice_tokens(lm, toolkit.fork(prefix), tokens, START, END, mode="prefill")
    difference = toolkit.cache_difference(spliced, generated)
    assert difference < 1e-4
    assert spliced.length == generated.length
    # The digest is exact: it tells the two apart whenever any bit differs.
    assert (toolkit.kv_digest(spliced) == toolkit.kv_digest(generated)) == (difference == 0.0)


def test_digest_changes_with_the_text(lm, prefix):
    a = toolkit.splice_tokens(lm, toolkit.fork(prefix), [5, 6, 7], START, END)
    b = toolkit.splice_tokens(lm, toolkit.fork(prefix), [5, 6, 8], START, END)
    c = toolkit.splice_tokens(lm, toolkit.fork(prefix), [5, 6, 7], START, END)
    assert toolkit.kv_digest(a) != toolkit.kv_digest(b)
    assert toolkit.kv_digest(a) == toolkit.kv_digest(c)


def test_fork_is_independent(lm, prefix):
    before = toolkit.kv_digest(prefix)
    toolkit.splice_tokens(lm, toolkit.fork(prefix), [5, 6], START, END)
    assert toolkit.kv_digest(prefix) == before
    assert prefix.length == 6


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_pinned_rng_gives_the_same_torch_noise(seed):
    a = torch.randn(8, generator=toolkit.torch_generator(np.random.default_rng(seed)))
    b = torch.randn(8, generator=toolkit.torch_generator(np.random.default_rng(seed)))
    c = torch.randn(8, generator=toolkit.torch_generator(np.random.default_rng(seed + 1)))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_sampled_generation_is_reproducible_from_the_pinned_rng(lm, prefix):
    def sample(seed):
        gen = toolkit.torch_generator(np.random.default_rng(seed))
        return toolkit.generate_between_markers(lm, toolkit.fork(prefix), START, END, 10, generator=gen,
                                                temperature=1.0, banned=[PAD, START])[0]

    assert sample(3) == sample(3)
    assert any(sample(3) != sample(s) for s in range(4, 10))


@pytest.mark.parametrize("mode", ["prefill", "sequential"])
def test_batched_splice_equals_one_by_one(lm, prefix, mode):
    texts = [[5, 6, 7, 8, 9], [10], [11, 12, 13], []]
    batch = toolkit.splice_batch(lm, prefix, texts, START, END, PAD, mode=mode)
    assert batch.key_mask.shape == (len(texts), batch.length)
    for i, text in enumerate(texts):
        single = toolkit.splice_tokens(lm, toolkit.fork(prefix), text, START, END, mode="sequential")
        n = single.length
        assert int(batch.key_mask[i].sum()) == n
        for (kb, vb), (ks, vs) in zip(batch.keys_values(), single.keys_values(), strict=True):
            assert torch.allclose(kb[i : i + 1, :, :n], ks, atol=1e-5)
            assert torch.allclose(vb[i : i + 1, :, :n], vs, atol=1e-5)
        assert torch.allclose(batch.last_hidden[i], single.last_hidden[0], atol=1e-5)


def test_too_long_splice_names_the_limit(lm, prefix):
    with pytest.raises(toolkit.SpliceTooLongError, match=r"at most 48 positions.*at most 40 tokens"):
        toolkit.splice_tokens(lm, toolkit.fork(prefix), [5] * 41, START, END)
    with pytest.raises(VdbError, match="48"):
        toolkit.splice_batch(lm, prefix, [[5] * 41], START, END, PAD)
    # One token shorter fits exactly.
    assert toolkit.splice_tokens(lm, toolkit.fork(prefix), [5] * 40, START, END).length == 48


def test_unknown_mode_is_a_config_error(lm, prefix):
    with pytest.raises(ConfigError, match="sequential, prefill"):
        toolkit.splice_tokens(lm, toolkit.fork(prefix), [5], START, END, mode="fast")
