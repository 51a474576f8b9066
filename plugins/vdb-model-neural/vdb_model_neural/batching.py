"""Lockstep batching for the reference models: B episodes' CoTs in one padded, batched KV cache.

:class:`LockstepDecoder` holds B rows of a decoder that advance together, one forward pass per *column*
(one token per row, or padding for a row that has nothing to feed). Rows keep their own positions
(explicit ``position_ids``) and an attention mask that hides every padding position, so a row's real
keys and values are what it would compute alone, up to floating point. :meth:`LockstepDecoder.row_state`
cuts one row out as an ordinary batch-1 :class:`~vdb_adapter_transformers.toolkit.DecoderState`.

Generation (:func:`generate_lockstep`) and splicing (:func:`splice_lockstep`) feed exactly the same
columns for the same texts — start marker, the tokens, end marker, then padding — so within a batch a
spliced copy of the batch's own CoTs is bit-identical to the generated one (the selfsplice gate).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from transformers import DynamicCache
from vdb_adapter_transformers import toolkit


class LockstepDecoder:
    """B decoder rows over a prefix of B embeddings ``(B, P, hidden)``, advanced column by column."""

    @torch.no_grad()
    def __init__(self, lm: torch.nn.Module, embeds: torch.Tensor, pad_id: int):
        self.lm, self.pad_id = lm, int(pad_id)
        self.device = embeds.device
        rows, prefix = embeds.shape[:2]
        out = lm(inputs_embeds=embeds, cache=toolkit.new_cache(lm), use_cache=True, output_hidden_states=True)
        self.cache = out.cache
        self.mask = torch.ones((rows, prefix), dtype=torch.bool, device=self.device)
        self.lengths = torch.full((rows,), prefix, dtype=torch.long, device=self.device)
        self.hidden, self.logits = out.hidden_states[-1][:, -1], out.logits[:, -1]
        self.limit = toolkit.context_limit(lm)

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
        if self.mask.shape[1] + ids.shape[1] > self.limit:
            raise toolkit.SpliceTooLongError(
                f"a lockstep batch needs {self.mask.shape[1] + ids.shape[1]} cache positions, more than the "
                f"model's context of {self.limit}")
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
        return toolkit.DecoderState(cache, self.hidden[row:row + 1].clone(), self.logits[row:row + 1].clone(),
                                    int(keep.numel()), tuple(tokens))


def generate_lockstep(decoder: LockstepDecoder, start_id: int, end_id: int, max_tokens: int,
                      banned: Sequence[int] = (), sampler=None, rngs: Sequence | None = None) -> list[list[int]]:
    """Text between markers for every row at once; each row stops at its own end marker.

    Like :func:`toolkit.generate_between_markers` per row: the start marker, tokens (``banned`` never
    picked), the end marker (fed anyway after ``max_tokens``). Greedy without a ``sampler``
    (:class:`~vdb_model_neural.sampling.Sampler`); with one, row i's picks draw from ``rngs[i]`` exactly as
    the row's episode draws alone (one draw per picked token). Returns each row's tokens.
    """
    decoder.feed([start_id] * decoder.rows)
    banned_ids = torch.tensor(sorted(set(banned) - {end_id}), dtype=torch.long, device=decoder.device)
    texts: list[list[int]] = [[] for _ in range(decoder.rows)]
    open_rows = [True] * decoder.rows
    while any(open_rows):
        if sampler is None or sampler.greedy:
            picks = _greedy(decoder.logits, banned_ids)
        else:
            picks = _sampled(decoder.logits, banned_ids.tolist(), sampler, rngs,
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


def _sampled(logits: torch.Tensor, banned: list[int], sampler, rngs: Sequence, picking: list[bool]) -> list[int]:
    """Each picking row's token from its own stream; the other rows draw nothing (-1: not used)."""
    return sampler.pick_rows(logits, banned, [rng if pick else None for rng, pick in zip(rngs, picking, strict=True)])


def _greedy(logits: torch.Tensor, banned: torch.Tensor) -> list[int]:
    logits = logits.clone()
    if len(banned):
        logits[:, banned] = float("-inf")
    return [int(t) for t in torch.argmax(logits, dim=-1).tolist()]  # one conversion, not one per row


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


def _pad(tensor: torch.Tensor, width: int) -> torch.Tensor:
    missing = width - tensor.shape[2]
    if missing == 0:
        return tensor
    return torch.nn.functional.pad(tensor, (0, 0, 0, missing))
