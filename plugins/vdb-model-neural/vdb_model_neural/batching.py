"""Lockstep batching for the reference models, on the adapter toolkit's :mod:`~vdb_adapter_transformers.lockstep`.

The decoder, the splice and the padded cache are the toolkit's (the same code any transformers-based
adapter batches with); what is the reference models' own is their sampler: row i's tokens are drawn from
``rngs[i]`` exactly as the row's episode draws alone (one draw per picked token).
"""

from __future__ import annotations

from collections.abc import Sequence

from vdb_adapter_transformers.lockstep import LockstepDecoder, padded_cache, splice_lockstep
from vdb_adapter_transformers.lockstep import generate_lockstep as _generate

__all__ = ["LockstepDecoder", "generate_lockstep", "padded_cache", "splice_lockstep"]


def generate_lockstep(decoder: LockstepDecoder, start_id: int, end_id: int, max_tokens: int,
                      banned: Sequence[int] = (), sampler=None, rngs: Sequence | None = None) -> list[list[int]]:
    """:func:`vdb_adapter_transformers.lockstep.generate_lockstep` with the models' sampler: greedy without
    one (or a greedy one); else row i's picks draw from ``rngs[i]``, and a row not picking draws nothing."""
    if sampler is None or sampler.greedy:
        return _generate(decoder, start_id, end_id, max_tokens, banned)

    def pick_rows(logits, banned_ids, picking):
        return sampler.pick_rows(logits, banned_ids, [rng if p else None for rng, p in zip(rngs, picking, strict=True)])

    return _generate(decoder, start_id, end_id, max_tokens, banned, pick_rows=pick_rows)
