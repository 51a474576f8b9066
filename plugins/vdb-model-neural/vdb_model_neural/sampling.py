"""Token sampling for the reference models' CoTs: temperature and nucleus (top-p), one draw per token from
the benchmark's pinned ``cot`` stream — like the real counterparts (ORION samples its answers at
temperature 0.1, top-p 0.75; Alpamayo its CoT at temperature 0.6, top-p 0.98).

A pick is made in float64 from the row's logits: softmax at the temperature, the smallest set of most
probable tokens whose probability reaches ``top_p`` (ties broken by token id), and one uniform draw
``rng.random()`` through its cumulative distribution. A batched row draws from its own row's stream, so a
lockstep batch picks what its episodes pick alone (up to the rounding of the logits). Temperature 0 is
greedy and draws nothing.

A sampled sequence need not be the tokenizer's own encoding of its text, so :class:`TokenMemo` remembers
the tokens a model sampled for a text: splicing that text back (the selfsplice control, a harvested CoT)
feeds exactly the sampled tokens, and the spliced cache is bit-identical to the generated one.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from vladrivebench import ConfigError

MAX_TEMPERATURE = 10.0


@dataclass(frozen=True)
class Sampler:
    """How a model picks its CoT tokens: ``temperature`` (0 = greedy) and ``top_p`` (nucleus mass)."""

    temperature: float
    top_p: float

    @classmethod
    def checked(cls, model: str, temperature: object, top_p: object) -> Sampler:
        """The sampler for model options ``temperature`` and ``top_p``, else a one-line :class:`ConfigError`."""
        return cls(_number(model, "temperature", temperature, 0.0, MAX_TEMPERATURE, "between 0 (greedy) and 10"),
                   _number(model, "top_p", top_p, 0.0, 1.0, "in (0, 1]", open_low=True))

    @property
    def greedy(self) -> bool:
        return self.temperature == 0.0

    def picker(self, rng: np.random.Generator):
        """A ``pick`` for :func:`toolkit.generate_between_markers`: each token drawn from ``rng``."""
        return lambda logits, banned: self.pick(logits, banned, rng)

    def pick(self, logits, banned: Sequence[int], rng: np.random.Generator) -> int:
        """One token from a row of logits (a 1-D tensor or array); ``banned`` ids are never picked."""
        values = np.asarray(_to_numpy(logits), dtype=np.float64)[None]
        if self.greedy:
            return self.pick_rows(values, banned, [True])[0]  # draws nothing: any non-None stands in
        return self.pick_rows(values, banned, [rng])[0]

    def pick_rows(self, logits, banned: Sequence[int], rngs: Sequence[np.random.Generator | None]) -> list[int]:
        """One token per row of ``(B, V)`` logits, row i drawing once from ``rngs[i]``; a row whose stream is
        ``None`` draws nothing and gets -1. Row i's pick is what :meth:`pick` gives for that row alone
        (every reduction runs along the row, so the batch never changes a row's arithmetic)."""
        values = np.array(_to_numpy(logits), dtype=np.float64, ndmin=2)
        if len(banned):
            values[:, np.asarray(banned, dtype=np.int64)] = -np.inf
        if self.greedy:
            return [int(t) if rng is not None else -1 for t, rng in zip(np.argmax(values, axis=1), rngs, strict=True)]
        probs = np.exp((values - values.max(axis=1, keepdims=True)) / self.temperature)
        probs /= probs.sum(axis=1, keepdims=True)
        order = np.argsort(-probs, axis=1, kind="stable")  # most probable first, ties by id
        mass = np.cumsum(np.take_along_axis(probs, order, axis=1), axis=1)
        keep = np.count_nonzero(mass < (self.top_p * mass[:, -1])[:, None], axis=1) + 1
        picks = []
        for row, rng in enumerate(rngs):
            if rng is None:
                picks.append(-1)
                continue
            kept = mass[row, : keep[row]]
            index = int(np.count_nonzero(kept <= rng.random() * kept[-1]))
            picks.append(int(order[row, min(index, keep[row] - 1)]))
        return picks


class TokenMemo:
    """The tokens last sampled for each text (bounded), so splicing a sampled text feeds its own tokens."""

    def __init__(self, capacity: int = 4096):
        self.capacity = capacity
        self._tokens: OrderedDict[str, tuple[int, ...]] = OrderedDict()

    def remember(self, text: str, tokens: Sequence[int], canonical: Sequence[int]) -> None:
        """Keep ``tokens`` for ``text`` when they differ from the tokenizer's ``canonical`` encoding."""
        tokens = tuple(int(t) for t in tokens)
        if tokens == tuple(canonical):
            self._tokens.pop(text, None)
            return
        self._tokens[text] = tokens
        self._tokens.move_to_end(text)
        while len(self._tokens) > self.capacity:
            self._tokens.popitem(last=False)

    def clear(self) -> None:
        """Forget every text (a model does at each episode's reset, so an episode never depends on which
        episodes the same model object ran before it)."""
        self._tokens.clear()

    def tokens(self, text: str, encode) -> list[int]:
        """The tokens to feed for ``text``: the sampled ones if this model sampled it, else ``encode(text)``."""
        known = self._tokens.get(text)
        return list(known) if known is not None else list(encode(text))


def _to_numpy(logits):
    if hasattr(logits, "detach"):
        return logits.detach().to("cpu").double().numpy()
    return logits


def _number(model: str, name: str, value: object, low: float, high: float, expected: str,
            open_low: bool = False) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (low < value if open_low else low <= value) and value <= high
    if not ok:
        raise ConfigError(f"model {model!r} option {name} must be a number {expected}, got {value!r}")
    return float(value)
