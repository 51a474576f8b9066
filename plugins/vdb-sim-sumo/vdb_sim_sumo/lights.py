"""Traffic lights frozen to one colour for the ego, from the programs SUMO generated for the junction.

SUMO's own program gives every link of the junction a state in each phase; freezing picks the phase in
which the ego's links have the wanted colour (for red: the phase with the most other traffic flowing),
so the rest of the junction stays consistent (cross traffic green while the ego has red, protected
pedestrian crossings, permissive left turns as SUMO laid them out), and holds it for the whole episode.
"""

from __future__ import annotations

from collections.abc import Sequence

_GREEN = "Gg"


def frozen_state(phases: Sequence[str], ego_links: Sequence[int], colour: str) -> str:
    """The signal state string that shows ``colour`` on ``ego_links`` (indices) for as long as it is set.

    ``phases`` are the state strings of the junction's program. Red takes the phase where all ego links are
    red and the most other links are green; green (and yellow) the phase where all ego links are green
    with the most priority greens (``G``) among them. Without such a phase, the first phase is used with the
    ego's links overwritten.
    """
    if not phases:
        raise ValueError("the traffic light has no program phases")
    if not ego_links:
        raise ValueError("no link of the traffic light starts on the ego's lane")
    if colour == "red":
        candidates = [p for p in phases if all(p[i] == "r" for i in ego_links)]
        chosen = max(candidates, key=lambda p: sum(ch in _GREEN for ch in p)) if candidates else phases[0]
        return _overwrite(chosen, ego_links, "r")
    candidates = [p for p in phases if all(p[i] in _GREEN for i in ego_links)]
    chosen = max(candidates, key=lambda p: sum(p[i] == "G" for i in ego_links)) if candidates else phases[0]
    if colour == "yellow":
        return _overwrite(chosen, ego_links, "y")
    if colour != "green":
        raise ValueError(f"unknown light colour {colour!r}")
    return "".join("G" if i in ego_links and ch not in _GREEN else ch for i, ch in enumerate(chosen))


def _overwrite(state: str, links: Sequence[int], char: str) -> str:
    chosen = set(links)
    return "".join(char if i in chosen else ch for i, ch in enumerate(state))


def ego_colour(state: str, ego_links: Sequence[int]) -> str:
    """The colour the ego sees in a signal state: red if any of its links is red, else yellow, else green."""
    chars = {state[i] for i in ego_links}
    if chars & set("rus"):
        return "red"
    if chars & set("yY"):
        return "yellow"
    return "green"
