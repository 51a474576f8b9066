"""Cutting a chain-of-thought to its first k %: pure functions, no model, no numpy.

A CoT is a sequence of *segments* (one for a sentence format, one per slot in the model's slot order) read
as one stream of words. ``truncate(segments, k)`` keeps the first ``floor(k / 100 · W)`` of its ``W`` words
(at most k %) and cuts each segment right after its last kept word, so the kept text is character for
character the CoT's own beginning; segments after the cut become empty, and ``k = 100`` returns the
segments unchanged. With ``count`` (a tokenizer's ``count_tokens``) the budget is ``floor(k / 100 · T)``
of the CoT's ``T`` tokens instead, and the cut is the longest word prefix within that budget.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence

_WORD = re.compile(r"\S+")


def word_ends(text: str) -> list[int]:
    """The offset just after each whitespace-separated word of ``text``."""
    return [m.end() for m in _WORD.finditer(text)]


def cut(text: str, words: int) -> str:
    """The beginning of ``text`` up to and including its ``words``-th word (all of it when ``words`` ≥ its
    word count, ``""`` for 0)."""
    ends = word_ends(text)
    if words >= len(ends):
        return text
    return text[:ends[words - 1]] if words > 0 else ""


def share(level: float, total: int) -> int:
    """``floor(level / 100 · total)``: how many of ``total`` units the first ``level`` % holds."""
    return min(total, max(0, math.floor(level * total / 100.0 + 1e-9)))


def cut_words(segments: Sequence[str], words: int) -> list[str]:
    """The segments with only the first ``words`` words of their concatenation kept."""
    out, left = [], words
    for text in segments:
        n = len(word_ends(text))
        out.append(cut(text, min(left, n)))
        left = max(0, left - n)
    return out


def truncate(segments: Sequence[str], level: float,
             count: Callable[[str], int] | None = None) -> tuple[list[str], int, int]:
    """``(kept segments, units kept, units in all)`` for the first ``level`` % of the CoT.

    Units are words, or tokens counted by ``count``. ``level`` ≥ 100 keeps everything unchanged.
    """
    total_words = sum(len(word_ends(t)) for t in segments)
    if count is None:
        if level >= 100:
            return list(segments), total_words, total_words
        keep = share(level, total_words)
        return cut_words(segments, keep), keep, total_words
    total = sum(count(t) for t in segments)
    if level >= 100:
        return list(segments), total, total
    budget = share(level, total)
    words, used = 0, 0
    while words < total_words:
        cost = sum(count(t) for t in cut_words(segments, words + 1) if t)
        if cost > budget:
            break
        words, used = words + 1, cost
    return cut_words(segments, words), used, total
