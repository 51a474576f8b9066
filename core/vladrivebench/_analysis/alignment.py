"""Action alignment between a CoT's stated intent and the action head, exactly as the paper's Appendix B.

Both sides are mapped to *ordered sets* of action classes (the first element is the primary action):

- the CoT: its stated-action group (maintaining / accelerating / decelerating / keep distance), resolved
  by the ego speed ``v`` (and, for keep distance, the time-to-collision with the lead vehicle);
- the action head: the desired speed ``v_des`` commanded for the next step compared with ``v``.

*Relaxed* alignment: the sets overlap. *Strict* alignment: the primary elements match. Steps are
aggregated spatially: 1 m bins of cumulative travel distance, the fraction of aligned steps per bin, and
the unweighted mean over bins, so a stationary phase counts once, however long it lasts.

All functions are pure; thresholds are module constants and keyword arguments with the paper's values.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

ACCELERATE = "accelerate"
MAINTAIN = "maintain"
DECELERATE = "decelerate"
ACTION_CLASSES = (ACCELERATE, MAINTAIN, DECELERATE)
SHORT_NAMES = {ACCELERATE: "accel", MAINTAIN: "maint", DECELERATE: "slow"}
"""How the paper's tables print the classes."""

V_CRAWL = 1.0
"""Crawling speed (m/s): below it the ego is nearly stopped."""
V_CRUISE = 5.0
"""Cruising speed (m/s): at or above it "maintaining" is unambiguous."""
TTC_THRESHOLD = 2.0
"""Keep distance: a time-to-collision above this (s) is a safe gap (the two-second rule)."""
V_STOP = 0.05
"""A desired speed below this (m/s) is a commanded stop."""
EPS_RELATIVE = 0.1
"""Relative speed-change threshold above crawling speed."""
EPS_ABSOLUTE = 0.1
"""Absolute speed-change threshold (m/s) at or below crawling speed."""
BIN_METRES = 1.0
"""Width of the spatial aggregation bins along the cumulative travel distance."""

ActionSet = tuple[str, ...]


def time_to_collision(gap: float | None, v: float, lead_speed: float | None) -> float:
    """Seconds until the ego closes ``gap`` to the lead vehicle; ``inf`` when there is none or it is not closing."""
    if gap is None:
        return math.inf
    closing = v - (lead_speed or 0.0)
    if closing <= 0.0:
        return math.inf
    return max(gap, 0.0) / closing


def cot_action_set(stated_action: str, v: float, ttc: float = math.inf, *,
                   v_crawl: float = V_CRAWL, v_cruise: float = V_CRUISE,
                   ttc_threshold: float = TTC_THRESHOLD) -> ActionSet | None:
    """The action classes a CoT's stated action is consistent with at ego speed ``v`` (primary first).

    ``None`` for ``"none"`` (the CoT states no longitudinal intent: the step is not scored).
    """
    if stated_action == "maintaining":
        return (MAINTAIN, ACCELERATE) if v >= v_cruise else (ACCELERATE,)
    if stated_action == "accelerating":
        return (ACCELERATE, MAINTAIN) if v >= v_cruise else (ACCELERATE,)
    if stated_action == "decelerating":
        return (DECELERATE,) if v > v_crawl else (DECELERATE, MAINTAIN)
    if stated_action == "keep_distance":
        resolved = "maintaining" if ttc > ttc_threshold else "decelerating"
        return cot_action_set(resolved, v, v_crawl=v_crawl, v_cruise=v_cruise)
    if stated_action == "none":
        return None
    raise ValueError(f"unknown stated action {stated_action!r}")


def action_head_set(v: float, v_des: float, *, v_crawl: float = V_CRAWL, v_stop: float = V_STOP,
                    eps_relative: float = EPS_RELATIVE, eps_absolute: float = EPS_ABSOLUTE) -> ActionSet:
    """The action classes of the action head's command: ``v_des`` for the next step against speed ``v``."""
    if v_des < v_stop:
        return (DECELERATE,)
    if v > v_crawl:
        delta, eps = (v_des - v) / v, eps_relative
    else:
        delta, eps = v_des - v, eps_absolute
    if delta > eps:
        return (ACCELERATE,)
    if delta < -eps:
        return (DECELERATE,)
    if delta >= 0.0:
        return (MAINTAIN, ACCELERATE)
    return (MAINTAIN, DECELERATE)


def relaxed_aligned(cot_set: ActionSet, head_set: ActionSet) -> bool:
    """Relaxed alignment: the two sets have at least one action in common."""
    return not set(cot_set).isdisjoint(head_set)


def strict_aligned(cot_set: ActionSet, head_set: ActionSet) -> bool:
    """Strict alignment: the primary (first) actions match."""
    return cot_set[0] == head_set[0]


def cumulative_distance(xs: Sequence[float], ys: Sequence[float]) -> list[float]:
    """Distance travelled up to each step along the ego's positions (0 at the first step)."""
    if len(xs) != len(ys):
        raise ValueError(f"xs and ys differ in length ({len(xs)} vs {len(ys)})")
    total, out = 0.0, []
    for i in range(len(xs)):
        if i:
            total += math.hypot(xs[i] - xs[i - 1], ys[i] - ys[i - 1])
        out.append(total)
    return out


@dataclass(frozen=True)
class BinnedAlignment:
    """Per-bin aligned fractions of one stretch of driving; ``rate`` is their unweighted mean."""

    fractions: tuple[float, ...]
    steps: int

    @property
    def bins(self) -> int:
        return len(self.fractions)

    @property
    def rate(self) -> float | None:
        return math.fsum(self.fractions) / len(self.fractions) if self.fractions else None


def bin_fractions(distances: Sequence[float], aligned: Sequence[bool | None], *,
                  bin_metres: float = BIN_METRES) -> BinnedAlignment:
    """Spatial aggregation: the fraction of aligned steps in every 1 m bin of cumulative travel distance.

    ``aligned[i]`` is ``None`` for a step that is not scored (no stated action, no label): it is left
    out, and a bin holding only such steps is not a bin of the average.
    """
    if len(distances) != len(aligned):
        raise ValueError(f"distances and aligned differ in length ({len(distances)} vs {len(aligned)})")
    hits: dict[int, list[int]] = {}
    steps = 0
    for d, ok in zip(distances, aligned, strict=True):
        if ok is None:
            continue
        counts = hits.setdefault(math.floor(d / bin_metres), [0, 0])
        counts[0] += bool(ok)
        counts[1] += 1
        steps += 1
    fractions = tuple(hits[b][0] / hits[b][1] for b in sorted(hits))
    return BinnedAlignment(fractions, steps)


def spatial_alignment(distances: Sequence[float], aligned: Sequence[bool | None], *,
                      bin_metres: float = BIN_METRES) -> float | None:
    """The run-level alignment rate: unweighted mean over bins of each bin's aligned fraction."""
    return bin_fractions(distances, aligned, bin_metres=bin_metres).rate
