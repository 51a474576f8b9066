"""Lockstep batches: B episodes' CoTs in one padded, batched KV cache (``vdb run --batch B``).

:class:`LockstepDecoder` holds B rows of a decoder that advance together, one forward pass per *column*
(one token per row, or padding for a row that has nothing to feed). Rows keep their own positions
(explicit ``position_ids``: plain positions, or for a Qwen-VL family model the row's cache length plus its
own multimodal rope delta on all three axes) and an attention mask that hides every padding position, so a
row's real keys and values are what it would compute alone, up to floating point.
:meth:`LockstepDecoder.row_state` cuts one row out as an ordinary batch-1
:class:`~vdb_adapter_transformers.toolkit.DecoderState`.

Two ways to start a batch:

* :meth:`LockstepDecoder.from_embeddings` — a decoder-only LM over B prefix embeddings of one length;
* :meth:`LockstepDecoder.from_states` — B batch-1 prefix states of any lengths (e.g. from
  :func:`encode_inputs_batch`, B VLM prompts with their images in one pass), right-padded into one cache.

:func:`generate_lockstep` and :func:`splice_lockstep` feed exactly the same columns for the same texts —
start marker, the tokens, end marker, padding, then any common suffix — so within a batch a spliced copy of
the batch's own CoTs is bit-identical to the generated one (the selfsplice gate). :func:`padded_cache`
lays B batch-1 states out for an action head that attends over all of them at once.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import torch
from transformers import DynamicCache

from . import toolkit

#: ``pick_rows(logits (B, V), banned_ids, picking)`` → one token per row; rows with ``picking[i]`` False
#: must draw nothing from their streams (their pick is ignored).
RowPicker = Callable[[torch.Tensor, list[int], list[bool]], list[int]]


class LockstepDecoder:
    """B decoder rows advanced column by column over one padded cache.

    ``mask`` is ``(B, width)`` with ``True`` at each row's real positions; ``lengths`` the real positions
    per row; ``rope_deltas`` ``None`` (plain positions) or ``(B, 1)`` (multimodal RoPE); ``hidden`` and
    ``logits`` those of each row's last real position.
    """

    def __init__(self, lm: torch.nn.Module, cache: DynamicCache, mask: torch.Tensor, hidden: torch.Tensor,
                 logits: torch.Tensor, pad_id: int, rope_deltas: torch.Tensor | None = None):
        self.lm, self.cache, self.mask, self.pad_id = lm, cache, mask, int(pad_id)
        self.hidden, self.logits, self.rope_deltas = hidden, logits, rope_deltas
        self.device = mask.device
        self.lengths = mask.sum(dim=1).to(torch.long)
        self.limit = toolkit.context_limit(lm)

    @classmethod
    @torch.no_grad()
    def from_embeddings(cls, lm: torch.nn.Module, embeds: torch.Tensor, pad_id: int) -> LockstepDecoder:
        """B rows over prefix embeddings ``(B, P, hidden)`` of a decoder-only LM, at plain positions."""
        rows, prefix = embeds.shape[:2]
        out = lm(inputs_embeds=embeds, cache=toolkit.new_cache(lm), use_cache=True, output_hidden_states=True)
        mask = torch.ones((rows, prefix), dtype=torch.bool, device=embeds.device)
        return cls(lm, out.cache, mask, out.hidden_states[-1][:, -1], out.logits[:, -1], pad_id)

    @classmethod
    def from_states(cls, lm: torch.nn.Module, states: Sequence[toolkit.DecoderState], pad_id: int
                    ) -> LockstepDecoder:
        """B rows from batch-1 prefix states (any lengths), right-padded into one cache. The states must all
        have plain positions or all have rope deltas."""
        if not states:
            raise ValueError("a lockstep batch needs at least one row")
        if len({s.rope_deltas is None for s in states}) != 1:
            raise ValueError("a lockstep batch cannot mix plain positions and multimodal rope deltas")
        layers, mask = padded_cache(states)
        cache = cache_of(layers)
        hidden = torch.cat([s.last_hidden for s in states])
        logits = torch.cat([s.last_logits for s in states])
        deltas = None if states[0].rope_deltas is None else torch.cat([s.rope_deltas for s in states]).to(mask.device)
        return cls(lm, cache, mask, hidden, logits, pad_id, deltas)

    @property
    def rows(self) -> int:
        return int(self.mask.shape[0])

    @torch.no_grad()
    def feed(self, column: Sequence[int | None]) -> None:
        """One pass: row i appends ``column[i]``, or padding (masked, no position used) when it is ``None``."""
        real = torch.tensor([t is not None for t in column], dtype=torch.bool, device=self.device)
        ids = torch.tensor([[self.pad_id if t is None else int(t)] for t in column], device=self.device)
        self._run(ids, real[:, None], self.lengths[:, None])
        self.lengths = self.lengths + real.long()

    @torch.no_grad()
    def feed_block(self, tokens: Sequence[int]) -> None:
        """One pass: every row appends the same ``tokens`` (a prompt or question)."""
        width = len(tokens)
        ids = torch.tensor([list(tokens)] * self.rows, device=self.device)
        real = torch.ones((self.rows, width), dtype=torch.bool, device=self.device)
        self._run(ids, real, self.lengths[:, None] + torch.arange(width, device=self.device))
        self.lengths = self.lengths + width

    def _run(self, ids: torch.Tensor, real: torch.Tensor, positions: torch.Tensor) -> None:
        if self.rope_deltas is not None:
            positions = (positions + self.rope_deltas.view(-1, 1)).unsqueeze(0).expand(3, -1, -1)
        furthest = int(self.lengths.max()) + ids.shape[1]
        if furthest > self.limit:
            raise toolkit.SpliceTooLongError(
                f"a lockstep batch needs {furthest} positions, more than the model's context of {self.limit}")
        mask = torch.cat([self.mask, real], dim=1)
        out = self.lm(input_ids=ids, attention_mask=mask.long(), position_ids=positions, cache=self.cache,
                      use_cache=True, output_hidden_states=True)
        self.mask = mask
        fed = real.any(dim=1)[:, None]
        self.hidden = torch.where(fed, out.hidden_states[-1][:, -1], self.hidden)
        self.logits = torch.where(fed, out.logits[:, -1], self.logits)

    def row_state(self, row: int, tokens: Sequence[int] = ()) -> toolkit.DecoderState:
        """Row ``row`` alone: its real cache positions as a batch-1 state (padding removed)."""
        keep = self.mask[row].nonzero().squeeze(1)
        cache = DynamicCache()
        for layer, (keys, values) in enumerate((lay.keys, lay.values) for lay in self.cache.layers):
            cache.update(keys[row:row + 1, :, keep].contiguous(), values[row:row + 1, :, keep].contiguous(), layer)
        deltas = None if self.rope_deltas is None else self.rope_deltas[row:row + 1].clone()
        return toolkit.DecoderState(cache, self.hidden[row:row + 1].clone(), self.logits[row:row + 1].clone(),
                                    int(keep.numel()), tuple(tokens), None, deltas)


def generate_lockstep(decoder: LockstepDecoder, start_id: int, end_id: int, max_tokens: int,
                      banned: Sequence[int] = (), pick_rows: RowPicker | None = None) -> list[list[int]]:
    """Text between markers for every row at once; each row stops at its own end marker.

    Like :func:`toolkit.generate_between_markers` per row: the start marker, tokens (``banned`` never
    picked), the end marker (fed anyway after ``max_tokens``). Greedy without ``pick_rows``; with it, the
    model's own picker chooses every row's token (rows not picking must draw nothing). Returns each row's
    tokens.
    """
    decoder.feed([start_id] * decoder.rows)
    banned_list = sorted(set(banned) - {end_id})
    banned_ids = torch.tensor(banned_list, dtype=torch.long, device=decoder.device)
    texts: list[list[int]] = [[] for _ in range(decoder.rows)]
    open_rows = [True] * decoder.rows
    while any(open_rows):
        if pick_rows is None:
            picks = _greedy(decoder.logits, banned_ids)
        else:
            picks = pick_rows(decoder.logits, banned_list,
                              [open_rows[i] and len(t) < max_tokens for i, t in enumerate(texts)])
        column: list[int | None] = []
        for i, text in enumerate(texts):
            if not open_rows[i]:
                column.append(None)
            elif len(text) >= max_tokens or picks[i] == end_id:
                column.append(end_id)
                open_rows[i] = False
            else:
                text.append(picks[i])
                column.append(picks[i])
        decoder.feed(column)
    return texts


def splice_lockstep(decoder: LockstepDecoder, texts: Sequence[Sequence[int]], start_id: int, end_id: int) -> None:
    """Feed each row's ``texts[i]`` between the markers, column by column as :func:`generate_lockstep` does."""
    rows = [[start_id, *map(int, t), end_id] for t in texts]
    for k in range(max(len(r) for r in rows)):
        decoder.feed([r[k] if k < len(r) else None for r in rows])


def _greedy(logits: torch.Tensor, banned: torch.Tensor) -> list[int]:
    logits = logits.clone()
    if len(banned):
        logits[:, banned] = float("-inf")
    return [int(t) for t in torch.argmax(logits, dim=-1).tolist()]  # one conversion, not one per row


@torch.no_grad()
def encode_inputs_batch(model: torch.nn.Module, rows: Sequence[Mapping[str, torch.Tensor]]
                        ) -> list[toolkit.DecoderState]:
    """B prompts (each its own processor outputs, batch 1, as for :func:`toolkit.encode_inputs`) in one
    forward pass: right-padded, every row's images through the vision tower together, positions from the
    model's own multimodal RoPE index with the padding masked. Returns one batch-1 state per row (its real
    positions only), equal to :func:`toolkit.encode_inputs` of that row up to floating point."""
    rows = [toolkit.with_type_ids(model, r) for r in rows]
    for r in rows:
        if "input_ids" not in r or r["input_ids"].dim() != 2 or r["input_ids"].shape[0] != 1:
            raise ValueError("encode_inputs_batch needs processor outputs with input_ids of shape (1, P) per row")
    lengths = [int(r["input_ids"].shape[1]) for r in rows]
    for length in lengths:
        toolkit._check_fits(model, length, what="prefix")
    batch = _stack_rows(rows, lengths, _pad_id(model))
    positions, deltas = toolkit.prefix_positions(model, batch)
    out = model(**batch, position_ids=positions, cache=toolkit.new_cache(model), use_cache=True,
                output_hidden_states=True)
    hidden, logits = out.hidden_states[-1], out.logits
    states = []
    for i, length in enumerate(lengths):
        cache = DynamicCache()
        for index, layer in enumerate(out.cache.layers):
            cache.update(layer.keys[i:i + 1, :, :length].contiguous(), layer.values[i:i + 1, :, :length].contiguous(),
                         index)
        row_deltas = None if deltas is None else deltas[i:i + 1].clone()
        states.append(toolkit.DecoderState(cache, hidden[i:i + 1, length - 1].clone(),
                                           logits[i:i + 1, length - 1].clone(), length, (), None, row_deltas))
    return states


#: Per-token processor outputs, right-padded; everything else (pixels, grids) is per image and concatenated.
_TOKEN_KEYS = ("input_ids", "attention_mask", "mm_token_type_ids")


def _stack_rows(rows: Sequence[Mapping[str, torch.Tensor]], lengths: Sequence[int], pad_id: int
                ) -> dict[str, torch.Tensor]:
    width = max(lengths)
    ids = rows[0]["input_ids"]
    batch = {"input_ids": torch.full((len(rows), width), pad_id, dtype=ids.dtype, device=ids.device),
             "attention_mask": torch.zeros((len(rows), width), dtype=torch.long, device=ids.device)}
    types = [r.get("mm_token_type_ids") for r in rows]
    if all(t is not None for t in types):
        batch["mm_token_type_ids"] = torch.zeros((len(rows), width), dtype=types[0].dtype, device=ids.device)
    for i, (r, length) in enumerate(zip(rows, lengths, strict=True)):
        batch["input_ids"][i, :length] = r["input_ids"][0]
        batch["attention_mask"][i, :length] = 1 if r.get("attention_mask") is None else r["attention_mask"][0]
        if "mm_token_type_ids" in batch:
            batch["mm_token_type_ids"][i, :length] = r["mm_token_type_ids"][0]
    keys = {k for r in rows for k, v in r.items() if k not in _TOKEN_KEYS and v is not None}
    for key in sorted(keys):
        parts = [r.get(key) for r in rows]
        if any(p is None for p in parts):
            raise ValueError(f"encode_inputs_batch: {key} is in some rows' processor outputs but not in others")
        batch[key] = torch.cat(parts)
    return batch


def _pad_id(model: torch.nn.Module) -> int:
    pad = getattr(toolkit.text_config(model), "pad_token_id", None)
    return int(pad) if pad is not None else 0


def padded_cache(states: Sequence[toolkit.DecoderState]) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], torch.Tensor]:
    """Batch-1 states → per layer ``(keys, values)`` ``(B, heads, L, dim)`` right-padded with zeros, and the
    ``(B, L)`` key mask (``True`` at real positions) an action head attends with."""
    width = max(s.length for s in states)
    device = states[0].last_hidden.device
    mask = torch.zeros((len(states), width), dtype=torch.bool, device=device)
    for i, state in enumerate(states):
        mask[i, : state.length] = True
    layers = []
    for per_state in zip(*(s.keys_values() for s in states), strict=True):
        keys = torch.cat([_pad(k, width) for k, _ in per_state])
        values = torch.cat([_pad(v, width) for _, v in per_state])
        layers.append((keys, values))
    return layers, mask


def cache_of(layers: Sequence[tuple[torch.Tensor, torch.Tensor]]) -> DynamicCache:
    """A cache holding per layer ``(keys, values)`` (e.g. those of :func:`padded_cache`)."""
    cache = DynamicCache()
    for index, (keys, values) in enumerate(layers):
        cache.update(keys, values, index)
    return cache


def _pad(tensor: torch.Tensor, width: int) -> torch.Tensor:
    missing = width - tensor.shape[2]
    if missing == 0:
        return tensor
    return torch.nn.functional.pad(tensor, (0, 0, 0, missing))
