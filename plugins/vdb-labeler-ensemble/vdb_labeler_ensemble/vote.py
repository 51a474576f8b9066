"""Majority vote per label, with a tie-breaker for splits (pure functions, no I/O).

For each label the value with the most votes wins. When several values share the top count (a three-way
split of three backends, or one-to-one when a backend failed) the split is *tied*: the tie-breaker
backend's answer picks the winner if it is one of the tied values; otherwise the label stays unresolved
and the item is unlabelled, with the split in the reason. Labels the ground truth settles are not voted:
``target_mentioned`` is ``None`` when the step has no critical feature, and ``mention_slot`` is voted only
for slotted CoTs, among the backends that agree the target is mentioned.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .answer import ANSWER_FIELDS

MISSING: Any = object()
"""Stands for "no tie-breaker answer" (``None`` is a legitimate answer value)."""


@dataclass(frozen=True)
class Resolution:
    """The outcome of one label's vote: a value and how it was decided, or the tied values."""

    value: Any = None
    decided_by: str = "majority"
    tied: tuple[Any, ...] = ()

    @property
    def resolved(self) -> bool:
        return not self.tied


def top_values(values: Sequence[Hashable]) -> list[Any]:
    """The values that share the highest count, in a stable order (empty for no votes)."""
    counts = Counter(values)
    if not counts:
        return []
    top = max(counts.values())
    return sorted((v for v, c in counts.items() if c == top), key=_order)


def resolve(values: Sequence[Hashable], tie_value: Any = MISSING) -> Resolution:
    """The winner among ``values``; ``tie_value`` picks among tied values and is ignored otherwise."""
    winners = top_values(values)
    if not winners:
        raise ValueError("resolve() needs at least one vote")
    if len(winners) == 1:
        return Resolution(winners[0], "majority")
    if tie_value is not MISSING and any(_same(tie_value, w) for w in winners):
        return Resolution(tie_value, "tie_breaker")
    return Resolution(tied=tuple(winners), decided_by="tied")


@dataclass(frozen=True)
class Decision:
    """The ensemble's labels for one CoT, or why there are none.

    ``values`` maps every field of :data:`~vdb_labeler_ensemble.answer.ANSWER_FIELDS` to its value when
    all were decided; ``tied`` maps each undecided field to its split (value → backends that voted it).
    """

    values: dict[str, Any] | None
    decided_by: dict[str, str] = field(default_factory=dict)
    tied: dict[str, dict[Any, list[str]]] = field(default_factory=dict)
    reason: str | None = None

    @property
    def needs_tie_breaker(self) -> bool:
        return self.values is None and bool(self.tied) and self.reason is None


def decide(
    answers: Mapping[str, Mapping[str, Any]],
    *,
    has_critical: bool,
    slotted: bool,
    min_votes: int,
    tie_answer: Mapping[str, Any] | None = None,
) -> Decision:
    """Combine the valid ``answers`` (backend name → answer) into labels.

    With fewer than ``min_votes`` answers nothing is decided. Without ``tie_answer`` a tied field leaves
    the decision pending (:attr:`Decision.needs_tie_breaker`); with it, a field the tie-breaker cannot
    settle makes the decision final and unlabelled.
    """
    needed = max(1, min_votes)
    if len(answers) < needed:
        return Decision(None, reason=f"too few valid answers: {len(answers)} (need {needed})")
    values: dict[str, Any] = {}
    decided_by: dict[str, str] = {}
    tied: dict[str, dict[Any, list[str]]] = {}
    for name in ANSWER_FIELDS:
        settled = _settled_by_ground_truth(name, values, tied, has_critical=has_critical, slotted=slotted)
        if settled is not None:
            values[name], decided_by[name] = None, settled
            continue
        voters = _voters(name, answers)
        if name == "mention_slot" and "target_mentioned" in tied:
            tied[name] = _split(name, voters)  # cannot be voted before target_mentioned is settled
            continue
        outcome = resolve([a[name] for a in voters.values()],
                          MISSING if tie_answer is None else tie_answer.get(name, MISSING))
        if outcome.resolved:
            values[name], decided_by[name] = outcome.value, outcome.decided_by
        else:
            tied[name] = _split(name, voters)
    if not tied:
        return Decision(values, decided_by)
    if tie_answer is None:
        return Decision(None, decided_by, tied)
    return Decision(None, decided_by, tied, reason=f"no majority for {describe_splits(tied)}")


def describe_splits(tied: Mapping[str, Mapping[Any, Sequence[str]]]) -> str:
    """``stated_action (decelerating: a; maintaining: b; none: c)`` for each tied field."""
    parts = []
    for name, split in tied.items():
        votes = "; ".join(f"{_show(value)}: {', '.join(backends)}" for value, backends in split.items())
        parts.append(f"{name} ({votes})")
    return " and ".join(parts)


def _settled_by_ground_truth(name: str, values: Mapping[str, Any], tied: Mapping[str, Any], *,
                             has_critical: bool, slotted: bool) -> str | None:
    if name == "target_mentioned" and not has_critical:
        return "ground_truth: no critical feature"
    if name == "mention_slot":
        if not has_critical:
            return "ground_truth: no critical feature"
        if not slotted:
            return "ground_truth: one-sentence CoT"
        if "target_mentioned" not in tied and values.get("target_mentioned") is not True:
            return "target not mentioned"
    return None


def _voters(name: str, answers: Mapping[str, Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    if name == "mention_slot":  # only those who say the target is mentioned say where
        return {b: a for b, a in answers.items() if a["target_mentioned"] is True}
    return dict(answers)


def _split(name: str, voters: Mapping[str, Mapping[str, Any]]) -> dict[Any, list[str]]:
    split: dict[Any, list[str]] = {}
    for backend, answer in sorted(voters.items()):
        split.setdefault(answer[name], []).append(backend)
    return dict(sorted(split.items(), key=lambda item: _order(item[0])))


def _same(a: Any, b: Any) -> bool:
    return type(a) is type(b) and a == b


def _order(value: Any) -> tuple[str, str]:
    return (type(value).__name__, repr(value))


def _show(value: Any) -> str:
    return "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
