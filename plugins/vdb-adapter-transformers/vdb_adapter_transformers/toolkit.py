"""Adapter toolkit for transformers-based VLAs: CoT between marker tokens, and CoT splicing into the KV cache.

A VLA built on a decoder-only language model (``LlamaForCausalLM`` or any ``*ForCausalLM`` that accepts
``inputs_embeds`` and a ``DynamicCache``) usually works like this: encode a *prefix* (vision tokens,
ego-state tokens, a prompt), generate the chain-of-thought between a start and an end marker token, then
let an action head read the resulting KV cache or a hidden state. This module gives the pieces the
benchmark needs around that loop:

* :func:`encode_prefix` — one pass over the prefix embeddings; the returned :class:`DecoderState` can be
  forked (:func:`fork`) so that generation and every spliced condition start from the very same cache.
* :func:`generate_between_markers` — the model's own CoT, one forward pass per token (greedy, or sampled
  from a pinned ``torch.Generator``).
* :func:`splice_tokens` — the CoT the model *would* hold had it generated a given text: ``"sequential"``
  mode feeds one token per forward pass, exactly as generation did, so a selfsplice is bit-identical;
  ``"prefill"`` mode feeds the whole text in one batched pass (fast, equal to ~1e-7 but not bit for bit).
* :func:`kv_digest` / :func:`cache_difference` — the selfsplice gate: a hash of the cache and the largest
  absolute difference between two caches.
* :func:`torch_generator` — a ``torch.Generator`` seeded from the ``numpy.random.Generator`` the benchmark
  passes in, so a sampled action head draws the same noise for the baseline and every spliced condition.
* :func:`splice_batch` — several conditions spliced at once over one shared prefix cache (right-padded,
  with the attention mask and a key mask for the action head).

Only torch and transformers are needed; nothing here knows about driving.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from transformers import DynamicCache
from vladrivebench import ConfigError, VdbError

SPLICE_MODES = ("sequential", "prefill")


class SpliceTooLongError(VdbError):
    """A splice text that does not fit in the model's context."""


@dataclass
class DecoderState:
    """A decoder's KV cache after some prefix and tokens, with what an action head may read from it.

    ``cache`` holds keys/values of every position so far (batch size 1, or K for :func:`splice_batch`);
    ``last_hidden`` is the final-layer hidden state of the last position, ``(B, hidden)``; ``last_logits``
    the next-token logits, ``(B, vocab)``; ``length`` the number of cached positions; ``tokens`` the token
    ids fed after the prefix (for a batch: those of the first row); ``key_mask`` (batched states only) is
    ``(B, length)`` with ``True`` for real positions and ``False`` for padding.
    """

    cache: DynamicCache
    last_hidden: torch.Tensor
    last_logits: torch.Tensor
    length: int
    tokens: tuple[int, ...] = ()
    key_mask: torch.Tensor | None = None

    def keys_values(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per layer ``(keys, values)``, each ``(B, kv_heads, length, head_dim)``."""
        return [(layer.keys, layer.values) for layer in self.cache.layers]


def context_limit(lm: torch.nn.Module) -> int:
    """The longest sequence (prefix + CoT) the decoder was built for."""
    return int(lm.config.max_position_embeddings)


@torch.no_grad()
def encode_prefix(lm: torch.nn.Module, embeds: torch.Tensor) -> DecoderState:
    """Run the decoder over prefix embeddings ``(1, P, hidden)`` (vision tokens, prompt …) in one pass."""
    if embeds.dim() != 3:
        raise ValueError(f"prefix embeddings must be (batch, positions, hidden), got {tuple(embeds.shape)}")
    _check_fits(lm, embeds.shape[1], what="prefix")
    out = lm(inputs_embeds=embeds, past_key_values=DynamicCache(), use_cache=True, output_hidden_states=True)
    return DecoderState(out.past_key_values, out.hidden_states[-1][:, -1], out.logits[:, -1], embeds.shape[1])


def fork(state: DecoderState) -> DecoderState:
    """An independent copy of ``state``: feeding tokens to one never changes the other."""
    return DecoderState(
        copy.deepcopy(state.cache), state.last_hidden.clone(), state.last_logits.clone(), state.length,
        state.tokens, None if state.key_mask is None else state.key_mask.clone(),
    )


@torch.no_grad()
def feed_token(lm: torch.nn.Module, state: DecoderState, token_id: int) -> DecoderState:
    """Append one token with one forward pass (the autoregressive step); the cache grows in place."""
    _check_fits(lm, state.length + 1, what="sequence")
    ids = torch.tensor([[token_id]], dtype=torch.long)
    out = lm(input_ids=ids, past_key_values=state.cache, use_cache=True, output_hidden_states=True)
    return DecoderState(out.past_key_values, out.hidden_states[-1][:, -1], out.logits[:, -1],
                        state.length + 1, state.tokens + (token_id,))


@torch.no_grad()
def feed_tokens(lm: torch.nn.Module, state: DecoderState, token_ids: Sequence[int],
                mode: str = "sequential") -> DecoderState:
    """Append several tokens: one pass per token (``sequential``) or one pass for all (``prefill``)."""
    token_ids = [int(t) for t in token_ids]
    if mode not in SPLICE_MODES:
        raise ConfigError(f"splice mode {mode!r} is not known (expected one of: {', '.join(SPLICE_MODES)})")
    if not token_ids:
        return state
    if mode == "sequential":
        for token_id in token_ids:
            state = feed_token(lm, state, token_id)
        return state
    _check_fits(lm, state.length + len(token_ids), what="sequence")
    ids = torch.tensor([token_ids], dtype=torch.long)
    out = lm(input_ids=ids, past_key_values=state.cache, use_cache=True, output_hidden_states=True)
    return DecoderState(out.past_key_values, out.hidden_states[-1][:, -1], out.logits[:, -1],
                        state.length + len(token_ids), state.tokens + tuple(token_ids))


@torch.no_grad()
def generate_between_markers(
    lm: torch.nn.Module,
    state: DecoderState,
    start_id: int,
    end_id: int,
    max_tokens: int,
    generator: torch.Generator | None = None,
    temperature: float = 0.0,
    banned: Sequence[int] = (),
) -> tuple[list[int], DecoderState]:
    """The model's own CoT: feed ``start_id``, then pick and feed one token per pass until ``end_id``.

    Greedy when ``temperature`` is 0, else sampled from ``generator``. If ``max_tokens`` are reached
    without the end marker, the end marker is fed anyway so the cache always ends like a finished CoT.
    ``banned`` token ids (e.g. other markers, padding) are never picked. Returns the CoT token ids
    (without markers) and the state after the end marker.
    """
    state = feed_token(lm, state, start_id)
    text: list[int] = []
    banned_ids = torch.tensor(sorted(set(banned) - {end_id}), dtype=torch.long)
    while len(text) < max_tokens:
        token = _pick(state.last_logits[0], banned_ids, generator, temperature)
        if token == end_id:
            break
        text.append(token)
        state = feed_token(lm, state, token)
    return text, feed_token(lm, state, end_id)


def _pick(logits: torch.Tensor, banned: torch.Tensor, generator: torch.Generator | None,
          temperature: float) -> int:
    logits = logits.clone()
    if len(banned):
        logits[banned] = float("-inf")
    if temperature <= 0:
        return int(torch.argmax(logits))
    probs = torch.softmax(logits / temperature, dim=-1)
    return int(torch.multinomial(probs, 1, generator=generator))


def splice_tokens(lm: torch.nn.Module, state: DecoderState, token_ids: Sequence[int], start_id: int,
                  end_id: int, mode: str = "sequential", what: str = "splice text") -> DecoderState:
    """The state the model would hold had it generated ``token_ids`` between the markers itself.

    ``sequential`` feeds start marker, each token and end marker with one pass each — the same
    operations as :func:`generate_between_markers`, so splicing the model's own CoT gives a bit-identical
    cache. ``prefill`` feeds them in one pass (fast; equal only to floating-point rounding).
    Raises :class:`SpliceTooLongError` naming the limit when the text does not fit.
    """
    needed = state.length + len(token_ids) + 2
    limit = context_limit(lm)
    if needed > limit:
        raise SpliceTooLongError(
            f"{what} is {len(token_ids)} tokens, too long for the model's context: prefix {state.length} + "
            f"markers 2 + text must be at most {limit} positions (the text may have at most "
            f"{limit - state.length - 2} tokens)"
        )
    return feed_tokens(lm, state, [start_id, *token_ids, end_id], mode)


@torch.no_grad()
def splice_batch(lm: torch.nn.Module, prefix: DecoderState, texts: Sequence[Sequence[int]], start_id: int,
                 end_id: int, pad_id: int, mode: str = "prefill") -> DecoderState:
    """Splice K texts at once over one shared prefix cache; returns a batched state (batch K).

    The prefix cache is shared (copied K times along the batch, never recomputed); the texts are wrapped
    in markers and right-padded with ``pad_id``. Because attention is causal and the padding comes last,
    no real position ever attends to padding; ``key_mask`` marks real positions for the action head and
    ``last_hidden``/``last_logits`` are taken at each row's end marker. ``prefill`` runs one pass for all;
    ``sequential`` one pass per position over the whole batch. Values equal the one-by-one splices up to
    floating-point rounding.
    """
    if mode not in SPLICE_MODES:
        raise ConfigError(f"splice mode {mode!r} is not known (expected one of: {', '.join(SPLICE_MODES)})")
    rows = [[start_id, *map(int, t), end_id] for t in texts]
    if not rows:
        raise ValueError("splice_batch needs at least one text")
    width = max(len(r) for r in rows)
    limit = context_limit(lm)
    if prefix.length + width > limit:
        raise SpliceTooLongError(
            f"the longest splice text is {width - 2} tokens, too long for the model's context: prefix "
            f"{prefix.length} + markers 2 + text must be at most {limit} positions"
        )
    k = len(rows)
    cache = copy.deepcopy(prefix.cache)
    cache.batch_repeat_interleave(k)
    ids = torch.full((k, width), pad_id, dtype=torch.long)
    real = torch.zeros((k, width), dtype=torch.bool)
    for i, row in enumerate(rows):
        ids[i, : len(row)] = torch.tensor(row)
        real[i, : len(row)] = True
    key_mask = torch.cat([torch.ones((k, prefix.length), dtype=torch.bool), real], dim=1)
    hidden, logits = _run_batch(lm, cache, ids, key_mask, prefix.length, mode)
    last = torch.tensor([len(r) - 1 for r in rows])
    rows_idx = torch.arange(k)
    return DecoderState(cache, hidden[rows_idx, last], logits[rows_idx, last], prefix.length + width,
                        tuple(rows[0]), key_mask)


def _run_batch(lm, cache, ids, key_mask, prefix_len, mode):
    mask = key_mask.long()
    if mode == "prefill":
        out = lm(input_ids=ids, attention_mask=mask, past_key_values=cache, use_cache=True,
                 output_hidden_states=True)
        return out.hidden_states[-1], out.logits
    hiddens, logits = [], []
    for t in range(ids.shape[1]):
        out = lm(input_ids=ids[:, t : t + 1], attention_mask=mask[:, : prefix_len + t + 1],
                 past_key_values=cache, use_cache=True, output_hidden_states=True)
        hiddens.append(out.hidden_states[-1])
        logits.append(out.logits)
    return torch.cat(hiddens, dim=1), torch.cat(logits, dim=1)


def kv_digest(state: DecoderState, extra: Sequence[torch.Tensor] = ()) -> str:
    """SHA-256 over every key and value in the cache (shape, dtype and bytes), plus ``extra`` tensors.

    Two states have the same digest exactly when their caches are bit-identical (barring a hash
    collision): this is what selfsplice compares.
    """
    h = hashlib.sha256()
    tensors = [t for kv in state.keys_values() for t in kv] + list(extra)
    for tensor in tensors:
        array = tensor.detach().contiguous().cpu().numpy()
        h.update(f"{array.dtype}{array.shape}".encode())
        h.update(array.tobytes())
    return h.hexdigest()


def cache_difference(a: DecoderState, b: DecoderState) -> float:
    """Largest absolute difference between two caches (``inf`` if their shapes differ)."""
    worst = 0.0
    for (ka, va), (kb, vb) in zip(a.keys_values(), b.keys_values(), strict=True):
        if ka.shape != kb.shape or va.shape != vb.shape:
            return float("inf")
        worst = max(worst, float((ka - kb).abs().max()), float((va - vb).abs().max()))
    return worst


def torch_generator(rng: np.random.Generator) -> torch.Generator:
    """A ``torch.Generator`` seeded with one draw from ``rng`` (the benchmark's pinned numpy stream).

    Calling this at the same point of the same pinned stream gives the same torch noise, so the baseline
    and every spliced condition of a step sample their action head identically.
    """
    generator = torch.Generator()
    generator.manual_seed(int(rng.integers(0, 2**63 - 1)))
    return generator


def _check_fits(lm: torch.nn.Module, length: int, what: str) -> None:
    limit = context_limit(lm)
    if length > limit:
        raise SpliceTooLongError(f"{what} of {length} positions exceeds the model's context of {limit} positions")
