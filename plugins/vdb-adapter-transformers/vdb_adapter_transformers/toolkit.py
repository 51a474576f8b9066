"""Adapter toolkit for transformers-based VLAs: CoT between marker tokens, and CoT splicing into the KV cache.

A VLA built on a transformers decoder usually works like this: encode a *prefix* (camera frames, ego-state
tokens, a prompt), generate the chain-of-thought between a start and an end marker token, then let an
action head read the resulting KV cache or a hidden state. Two kinds of decoder are supported:

* a decoder-only LM (``LlamaForCausalLM`` or any ``*ForCausalLM``) fed with prefix embeddings
  (:func:`encode_prefix`) — plain positions ``0, 1, 2, …``;
* a vision-language model fed with its own processor's outputs (:func:`encode_inputs`: ``input_ids``,
  ``pixel_values``, ``image_grid_thw``, ``mm_token_type_ids`` …) — positions from the model's own logic:
  for the Qwen2-VL / Qwen2.5-VL / Qwen3-VL families the multimodal RoPE index (``get_rope_index``), whose
  *rope delta* places every later text token at ``cache length + delta``.

The pieces:

* :func:`encode_prefix` / :func:`encode_inputs` — one pass over the prefix; the returned
  :class:`DecoderState` carries the cache, the rope delta and the positions so far, and can be forked
  (:func:`fork`) so that generation and every spliced condition start from the very same cache.
* :func:`feed_token` / :func:`feed_tokens` — append tokens at the right positions.
* :func:`generate_between_markers` — the model's own CoT, one forward pass per token (greedy, or sampled
  from a pinned ``torch.Generator``).
* :func:`splice_tokens` — the CoT the model *would* hold had it generated a given text: ``"sequential"``
  mode feeds one token per forward pass, exactly as generation did, so a selfsplice is bit-identical;
  ``"prefill"`` mode feeds the whole text in one batched pass (fast, equal to ~1e-7 but not bit for bit).
* :func:`splice_batch` — several conditions spliced at once over one shared prefix cache (right-padded,
  with the attention mask and a key mask for the action head).
* :func:`kv_digest` / :func:`cache_difference` — the selfsplice gate: a hash of the cache and the largest
  absolute difference between two caches.
* :func:`native_state` / :func:`native_difference` / :func:`native_generate` — the fidelity gate: the
  model's own ordinary forward pass over prefix + text (positions computed by the model itself) and its
  own ``generate()``, to compare a spliced state with what the model really computes.
* :func:`torch_generator` — a ``torch.Generator`` seeded from the ``numpy.random.Generator`` the benchmark
  passes in, so a sampled action head draws the same noise for the baseline and every spliced condition.

Every call uses the current transformers cache API (``cache=``, ``DynamicCache(config=…)``). Only torch
and transformers are needed; nothing here knows about driving.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from transformers import DynamicCache
from vladrivebench import ConfigError, VdbError

SPLICE_MODES = ("sequential", "prefill")
"""How :func:`splice_tokens` / :func:`feed_tokens` / :func:`splice_batch` feed a text: ``sequential`` (one
forward pass per token, the operations of generation, bit-identical to it) or ``prefill`` (one pass)."""

#: Processor outputs that describe images or videos; their presence selects the model's multimodal RoPE.
GRID_KEYS = ("image_grid_thw", "video_grid_thw")


class SpliceTooLongError(VdbError):
    """A splice text that does not fit in the model's context."""


@dataclass
class DecoderState:
    """A decoder's KV cache after some prefix and tokens, with what an action head may read from it.

    ``cache`` holds keys/values of every position so far (batch size 1, or K for :func:`splice_batch`);
    ``last_hidden`` is the final-layer hidden state of the last position, ``(B, hidden)``; ``last_logits``
    the next-token logits, ``(B, vocab)``; ``length`` the number of cached positions; ``tokens`` the token
    ids fed after the prefix (for a batch: those of the first row); ``key_mask`` (batched states only) is
    ``(B, length)`` with ``True`` for real positions and ``False`` for padding. ``rope_deltas`` is ``None``
    for plain positions (a decoder-only LM: the next token sits at position ``length``) and a ``(B, 1)``
    long tensor for multimodal RoPE (Qwen-VL families: the next text token sits at ``length + delta`` on
    all three rotary axes), as the model's own ``get_rope_index`` returned it for the prefix.

    Build one with :func:`encode_prefix` or :func:`encode_inputs`; the constructor is public so that an
    adapter can wrap a cache it computed itself.
    """

    cache: DynamicCache
    last_hidden: torch.Tensor
    last_logits: torch.Tensor
    length: int
    tokens: tuple[int, ...] = ()
    key_mask: torch.Tensor | None = None
    rope_deltas: torch.Tensor | None = None

    def keys_values(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per layer ``(keys, values)``, each ``(B, kv_heads, length, head_dim)``."""
        return [(layer.keys, layer.values) for layer in self.cache.layers]

    def next_position_ids(self, count: int, batch: int = 1) -> torch.Tensor:
        """Position ids of the next ``count`` tokens: ``(batch, count)`` for plain positions, ``(3, batch,
        count)`` for multimodal RoPE (cache position + rope delta on the temporal, height and width axes)."""
        positions = torch.arange(self.length, self.length + count, dtype=torch.long,
                                 device=self.last_hidden.device).view(1, count)
        if self.rope_deltas is None:
            return positions.expand(batch, count)
        shifted = positions + self.rope_deltas.to(positions.device, torch.long).view(-1, 1)
        return shifted.expand(batch, count).unsqueeze(0).expand(3, batch, count)


def text_config(model: torch.nn.Module):
    """The configuration of the model's text decoder (the model's own for a decoder-only LM)."""
    return model.config.get_text_config()


def context_limit(model: torch.nn.Module) -> int:
    """The longest sequence (prefix + CoT) the decoder was built for, from its text configuration."""
    return int(text_config(model).max_position_embeddings)


def new_cache(model: torch.nn.Module) -> DynamicCache:
    """An empty cache laid out for ``model`` (the current transformers cache API)."""
    return DynamicCache(config=model.config)


def _forward(model: torch.nn.Module, cache: DynamicCache, **inputs):
    return model(**inputs, cache=cache, use_cache=True, output_hidden_states=True)


def _state_from(out, length: int, tokens: tuple[int, ...], rope_deltas: torch.Tensor | None) -> DecoderState:
    return DecoderState(out.cache, out.hidden_states[-1][:, -1], out.logits[:, -1], length, tokens, None, rope_deltas)


@torch.no_grad()
def encode_prefix(lm: torch.nn.Module, embeds: torch.Tensor) -> DecoderState:
    """Run a decoder-only LM over prefix embeddings ``(1, P, hidden)`` (vision tokens, prompt …) in one pass,
    at plain positions ``0 … P-1``."""
    if embeds.dim() != 3:
        raise ValueError(f"prefix embeddings must be (batch, positions, hidden), got {tuple(embeds.shape)}")
    _check_fits(lm, embeds.shape[1], what="prefix")
    positions = torch.arange(embeds.shape[1], dtype=torch.long, device=embeds.device).view(1, -1).expand(embeds.shape[0], -1)
    out = _forward(lm, new_cache(lm), inputs_embeds=embeds, position_ids=positions)
    return _state_from(out, embeds.shape[1], (), None)


def rope_index_function(model: torch.nn.Module):
    """The model's own multimodal RoPE index (``get_rope_index`` of a Qwen-VL family model), or ``None``."""
    for owner in (model, getattr(model, "model", None)):
        function = getattr(owner, "get_rope_index", None)
        if callable(function):
            return function
    return None


def prefix_positions(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor]
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Position ids of the prefix and its rope deltas, from the model's own logic.

    A model with a multimodal RoPE index given image or video grids gets ``get_rope_index``'s answer
    (``(3, B, P)`` positions and ``(B, 1)`` deltas); everything else plain positions and ``None``.
    """
    ids = inputs["input_ids"]
    rope_index = rope_index_function(model)
    if rope_index is None or not any(inputs.get(k) is not None for k in GRID_KEYS):
        return torch.arange(ids.shape[1], dtype=torch.long, device=ids.device).view(1, -1).expand(ids.shape[0], -1), None
    extra = {k: inputs[k] for k in (*GRID_KEYS, "second_per_grid_ts", "attention_mask") if inputs.get(k) is not None}
    positions, deltas = rope_index(ids, mm_token_type_ids(model, inputs), **extra)
    return positions, deltas.to(torch.long).view(-1, 1)


def mm_token_type_ids(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """The processor's ``mm_token_type_ids`` (text 0, image 1, video 2), or the same from the config's
    image / video token ids when a processor did not return them."""
    if inputs.get("mm_token_type_ids") is not None:
        return inputs["mm_token_type_ids"]
    ids, config = inputs["input_ids"], model.config
    types = torch.zeros_like(ids, dtype=torch.int32)
    types[ids == getattr(config, "image_token_id", -1)] = 1
    types[ids == getattr(config, "video_token_id", -1)] = 2
    return types


def with_type_ids(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``inputs`` with ``mm_token_type_ids`` filled in when they describe images or videos."""
    out = {k: v for k, v in inputs.items() if v is not None}
    if any(k in out for k in GRID_KEYS):
        out["mm_token_type_ids"] = mm_token_type_ids(model, out)
    return out


@torch.no_grad()
def encode_inputs(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor]) -> DecoderState:
    """Run a model over its own processor's outputs (batch 1) in one pass: the prefix of a VLM.

    ``inputs`` is what the model's processor returned (``input_ids`` and, for a VLM, ``pixel_values``,
    ``image_grid_thw``, ``mm_token_type_ids`` …). Positions come from :func:`prefix_positions` and are
    passed explicitly, so the state never depends on rope deltas the model keeps as mutable state.
    """
    if "input_ids" not in inputs or inputs["input_ids"].dim() != 2 or inputs["input_ids"].shape[0] != 1:
        raise ValueError("encode_inputs needs processor outputs with input_ids of shape (1, P)")
    length = int(inputs["input_ids"].shape[1])
    _check_fits(model, length, what="prefix")
    positions, deltas = prefix_positions(model, inputs)
    out = _forward(model, new_cache(model), **with_type_ids(model, inputs), position_ids=positions)
    return _state_from(out, length, (), deltas)


def fork(state: DecoderState) -> DecoderState:
    """An independent copy of ``state``: feeding tokens to one never changes the other."""
    return DecoderState(
        copy.deepcopy(state.cache), state.last_hidden.clone(), state.last_logits.clone(), state.length,
        state.tokens, None if state.key_mask is None else state.key_mask.clone(),
        None if state.rope_deltas is None else state.rope_deltas.clone(),
    )


@torch.no_grad()
def feed_token(lm: torch.nn.Module, state: DecoderState, token_id: int) -> DecoderState:
    """Append one token with one forward pass (the autoregressive step) at the state's next position; the
    cache grows in place (fork first to keep the old state)."""
    _check_fits(lm, state.length + 1, what="sequence")
    ids = torch.tensor([[token_id]], dtype=torch.long, device=state.last_hidden.device)
    out = _forward(lm, state.cache, input_ids=ids, position_ids=state.next_position_ids(1))
    return _state_from(out, state.length + 1, state.tokens + (token_id,), state.rope_deltas)


@torch.no_grad()
def feed_tokens(lm: torch.nn.Module, state: DecoderState, token_ids: Sequence[int],
                mode: str = "sequential") -> DecoderState:
    """Append several tokens: one pass per token (``sequential``) or one pass for all (``prefill``)."""
    token_ids = [int(t) for t in token_ids]
    _check_mode(mode)
    if not token_ids:
        return state
    if mode == "sequential":
        for token_id in token_ids:
            state = feed_token(lm, state, token_id)
        return state
    _check_fits(lm, state.length + len(token_ids), what="sequence")
    ids = torch.tensor([token_ids], dtype=torch.long, device=state.last_hidden.device)
    out = _forward(lm, state.cache, input_ids=ids, position_ids=state.next_position_ids(len(token_ids)))
    return _state_from(out, state.length + len(token_ids), state.tokens + tuple(token_ids), state.rope_deltas)


def _check_mode(mode: str) -> None:
    if mode not in SPLICE_MODES:
        raise ConfigError(f"splice mode {mode!r} is not known (expected one of: {', '.join(SPLICE_MODES)})")


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
    pick: Callable[[torch.Tensor, list[int]], int] | None = None,
) -> tuple[list[int], DecoderState]:
    """The model's own CoT: feed ``start_id``, then pick and feed one token per pass until ``end_id``.

    Greedy when ``temperature`` is 0, else sampled from ``generator``; or, with ``pick``, the model's own
    picker: ``pick(last_logits_row, banned_ids)`` returns the token (e.g. top-p sampling from a pinned
    NumPy stream). If ``max_tokens`` are reached without the end marker, the end marker is fed anyway so the
    cache always ends like a finished CoT. ``banned`` token ids (e.g. other markers, padding) are never
    picked. Returns the CoT token ids (without markers) and the state after the end marker.
    """
    state = feed_token(lm, state, start_id)
    text: list[int] = []
    banned_list = sorted(set(banned) - {end_id})
    banned_ids = torch.tensor(banned_list, dtype=torch.long)
    while len(text) < max_tokens:
        token = (pick(state.last_logits[0], banned_list) if pick is not None
                 else _pick(state.last_logits[0], banned_ids, generator, temperature))
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
    check_splice_fits(lm, state.length, len(token_ids), what)
    return feed_tokens(lm, state, [start_id, *token_ids, end_id], mode)


def check_splice_fits(lm: torch.nn.Module, prefix_length: int, count: int, what: str = "splice text") -> None:
    """Raise :class:`SpliceTooLongError` naming the limit when ``count`` tokens between two markers do not
    fit after a prefix of ``prefix_length`` positions."""
    limit = context_limit(lm)
    if prefix_length + count + 2 > limit:
        raise SpliceTooLongError(
            f"{what} is {count} tokens, too long for the model's context: prefix {prefix_length} + "
            f"markers 2 + text must be at most {limit} positions (the text may have at most "
            f"{limit - prefix_length - 2} tokens)"
        )


@torch.no_grad()
def splice_batch(lm: torch.nn.Module, prefix: DecoderState, texts: Sequence[Sequence[int]], start_id: int,
                 end_id: int, pad_id: int, mode: str = "prefill", after: Sequence[int] = ()) -> DecoderState:
    """Splice K texts at once over one shared prefix cache; returns a batched state (batch K).

    The prefix cache is shared (copied K times along the batch, never recomputed); the texts are wrapped
    in markers and right-padded with ``pad_id``. Because attention is causal and the padding comes last,
    no real position ever attends to padding; ``key_mask`` marks real positions for the action head and
    ``last_hidden``/``last_logits`` are taken at each row's end marker. ``prefill`` runs one pass for all;
    ``sequential`` one pass per position over the whole batch. ``after`` are tokens every row gets right
    after its end marker (e.g. the marker an action head starts from). Values equal the one-by-one splices
    up to floating-point rounding.
    """
    _check_mode(mode)
    rows = [[start_id, *map(int, t), end_id, *map(int, after)] for t in texts]
    if not rows:
        raise ValueError("splice_batch needs at least one text")
    width = max(len(r) for r in rows)
    limit = context_limit(lm)
    if prefix.length + width > limit:
        raise SpliceTooLongError(
            f"the longest splice text is {width - 2 - len(after)} tokens, too long for the model's context: "
            f"prefix {prefix.length} + markers {2 + len(after)} + text must be at most {limit} positions"
        )
    k = len(rows)
    cache = copy.deepcopy(prefix.cache)
    cache.batch_repeat_interleave(k)
    device = prefix.last_hidden.device
    ids = torch.full((k, width), pad_id, dtype=torch.long)
    real = torch.zeros((k, width), dtype=torch.bool)
    for i, row in enumerate(rows):
        ids[i, : len(row)] = torch.tensor(row)
        real[i, : len(row)] = True
    ids, real = ids.to(device), real.to(device)
    key_mask = torch.cat([torch.ones((k, prefix.length), dtype=torch.bool, device=device), real], dim=1)
    positions = prefix.next_position_ids(width, batch=k)
    hidden, logits = _run_batch(lm, cache, ids, key_mask, positions, prefix.length, mode)
    last = torch.tensor([len(r) - 1 for r in rows], device=device)
    rows_idx = torch.arange(k, device=device)
    deltas = None if prefix.rope_deltas is None else prefix.rope_deltas.expand(k, 1).clone()
    return DecoderState(cache, hidden[rows_idx, last], logits[rows_idx, last], prefix.length + width,
                        tuple(rows[0]), key_mask, deltas)


def _run_batch(lm, cache, ids, key_mask, positions, prefix_len, mode):
    mask = key_mask.long()
    if mode == "prefill":
        out = _forward(lm, cache, input_ids=ids, attention_mask=mask, position_ids=positions)
        return out.hidden_states[-1], out.logits
    hiddens, logits = [], []
    for t in range(ids.shape[1]):
        out = _forward(lm, cache, input_ids=ids[:, t : t + 1], attention_mask=mask[:, : prefix_len + t + 1],
                       position_ids=positions[..., t : t + 1])
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


def _append_ids(inputs: Mapping[str, torch.Tensor], token_ids: Sequence[int]) -> dict[str, torch.Tensor]:
    """``inputs`` (processor outputs of a prefix) with ``token_ids`` appended as text."""
    out = dict(inputs)
    extra = torch.tensor([[int(t) for t in token_ids]], dtype=torch.long, device=inputs["input_ids"].device)
    out["input_ids"] = torch.cat([inputs["input_ids"], extra], dim=1)
    if inputs.get("attention_mask") is not None:
        out["attention_mask"] = torch.cat([inputs["attention_mask"], torch.ones_like(extra)], dim=1)
    if inputs.get("mm_token_type_ids") is not None:
        zeros = torch.zeros_like(extra, dtype=inputs["mm_token_type_ids"].dtype)
        out["mm_token_type_ids"] = torch.cat([inputs["mm_token_type_ids"], zeros], dim=1)
    return out


@torch.no_grad()
def native_state(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor], token_ids: Sequence[int],
                 embeds: torch.Tensor | None = None) -> DecoderState:
    """The model's own computation of prefix + ``token_ids``: one ordinary forward pass, no position ids
    passed, so the model computes every position (and its multimodal RoPE deltas) itself. The returned
    state carries the rope deltas the model stored during that pass, so whatever reads it next (an action
    expert) sits at the positions the model itself would use.

    ``inputs`` are the prefix's processor outputs (:func:`encode_inputs`); for a decoder-only LM fed with
    embeddings give ``embeds`` (the prefix embeddings of :func:`encode_prefix`) and ``inputs`` empty: the
    tokens' embeddings are then looked up with the model's own input embedding table.
    """
    if embeds is not None:
        table = model.get_input_embeddings()
        extra = table(torch.tensor([[int(t) for t in token_ids]], dtype=torch.long, device=embeds.device)).to(embeds.dtype)
        full = torch.cat([embeds, extra], dim=1)
        out = model(inputs_embeds=full, cache=new_cache(model), use_cache=True, output_hidden_states=True)
        return _state_from(out, full.shape[1], tuple(int(t) for t in token_ids), None)
    full = with_type_ids(model, _append_ids(inputs, token_ids))
    out = model(**full, cache=new_cache(model), use_cache=True, output_hidden_states=True)
    return _state_from(out, int(full["input_ids"].shape[1]), tuple(int(t) for t in token_ids),
                       _models_own_deltas(model, full))


def _models_own_deltas(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor]) -> torch.Tensor | None:
    """The rope deltas the model itself stored during its last forward pass over multimodal ``inputs``."""
    if not any(k in inputs for k in GRID_KEYS):
        return None
    for owner in (model, getattr(model, "model", None)):
        deltas = getattr(owner, "rope_deltas", None)
        if isinstance(deltas, torch.Tensor):
            return deltas.to(torch.long).view(-1, 1).clone()
    return None


def native_difference(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor], state: DecoderState,
                      embeds: torch.Tensor | None = None) -> float:
    """Largest absolute cache difference between ``state`` (generated or spliced) and the model's own
    forward pass over the same prefix and tokens (:func:`native_state`): the fidelity gate's number."""
    return cache_difference(state, native_state(model, inputs, state.tokens, embeds))


@torch.no_grad()
def native_generate(model: torch.nn.Module, inputs: Mapping[str, torch.Tensor], start_id: int, end_id: int,
                    max_tokens: int, banned: Sequence[int] = ()) -> list[int]:
    """The model's own greedy ``generate()`` after the prefix and the start marker: the CoT token ids up to
    (without) the end marker. Compared with :func:`generate_between_markers`' greedy tokens, it shows that
    the toolkit's positions and cache are the ones transformers' own decoding loop uses."""
    full = with_type_ids(model, _append_ids(inputs, [start_id]))
    suppress = sorted({int(t) for t in banned} - {int(end_id)})
    sequences = model.generate(**full, max_new_tokens=max_tokens, do_sample=False, eos_token_id=int(end_id),
                               pad_token_id=int(end_id), suppress_tokens=suppress or None)
    new = [int(t) for t in sequences[0, full["input_ids"].shape[1]:]]
    return new[: new.index(end_id)] if end_id in new else new


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
