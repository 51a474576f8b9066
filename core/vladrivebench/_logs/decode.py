"""Logged JSON → the public records of :mod:`vladrivebench.records` (the read side of an episode log).

Each decoder takes the JSON value one channel logged for one step and returns the frozen record it was
written from. Unknown keys are ignored (a newer writer may add fields); a missing required key or a value
of the wrong type raises :class:`ValueError` naming the key, which the reader turns into a
:class:`~vladrivebench.errors.LogError` naming the file and the step. Numbers are kept as logged (an
integer stays an integer), so what readers compute from a record is what they computed from the dict.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from vladrivebench.records import Actor, Control, CoT, EgoState, GroundTruth, Trajectory

_EGO_NUMBERS = ("x", "y", "yaw", "speed", "steer", "length", "width")
_ACTOR_NUMBERS = ("x", "y", "yaw", "length", "width", "height", "speed")
_TRUTH_OPTIONAL_NUMBERS = ("distance_to_critical", "lead_gap", "lead_speed")
_TRUTH_OPTIONAL_TEXTS = ("critical_id", "critical_kind", "light_state", "terminal")


def _mapping(value: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ValueError(f"{what} is {type(value).__name__}, expected a JSON object")
    return value


def _number(value: Any, what: str) -> float | int:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{what} is {value!r}, expected a number")
    return value


def _text(value: Any, what: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{what} is {value!r}, expected a string")
    return value


def _optional(value: Any, check, what: str) -> Any:
    return None if value is None else check(value, what)


def _numbers(data: Mapping[str, Any], names: tuple[str, ...], what: str, required: tuple[str, ...]) -> dict:
    out = {}
    for name in names:
        if name in data:
            out[name] = _number(data[name], f"{what}.{name}")
        elif name in required:
            raise ValueError(f"{what} lacks {name!r}")
    return out


def ego_from_json(value: Any, what: str = "ego") -> EgoState:
    """An :class:`EgoState` from its logged fields (``x``, ``y``, ``yaw``, ``speed`` required)."""
    data = _mapping(value, what)
    return EgoState(**_numbers(data, _EGO_NUMBERS, what, required=("x", "y", "yaw", "speed")))


def actor_from_json(value: Any, what: str = "actor") -> Actor:
    """An :class:`Actor` from its logged fields (``actor_id``, ``kind``, ``x``, ``y`` required)."""
    data = _mapping(value, what)
    for name in ("actor_id", "kind"):
        if name not in data:
            raise ValueError(f"{what} lacks {name!r}")
    return Actor(actor_id=_text(data["actor_id"], f"{what}.actor_id"), kind=_text(data["kind"], f"{what}.kind"),
                 state=_optional(data.get("state"), _text, f"{what}.state"),
                 **_numbers(data, _ACTOR_NUMBERS, what, required=("x", "y")))


def _list(value: Any, what: str) -> list:
    if not isinstance(value, (list, tuple)):
        raise ValueError(f"{what} is {type(value).__name__}, expected a JSON array")
    return list(value)


def _point(value: Any, what: str) -> tuple:
    point = _list(value, what)
    if len(point) != 2:
        raise ValueError(f"{what} has {len(point)} coordinates, expected 2")
    return tuple(_number(v, what) for v in point)


def ground_truth_from_json(value: Any, what: str = "ground_truth") -> GroundTruth:
    """A :class:`GroundTruth` (actors as :class:`Actor` tuples) from its logged fields."""
    data = _mapping(value, what)
    for name in ("step", "time"):
        if name not in data:
            raise ValueError(f"{what} lacks {name!r}")
    fields: dict[str, Any] = {"step": _number(data["step"], f"{what}.step"),
                              "time": _number(data["time"], f"{what}.time")}
    fields["actors"] = tuple(actor_from_json(a, f"{what}.actors[{i}]")
                             for i, a in enumerate(_list(data.get("actors", []), f"{what}.actors")))
    for name in _TRUTH_OPTIONAL_NUMBERS:
        fields[name] = _optional(data.get(name), _number, f"{what}.{name}")
    for name in _TRUTH_OPTIONAL_TEXTS:
        fields[name] = _optional(data.get(name), _text, f"{what}.{name}")
    for name in ("route_progress", "route_length"):
        if name in data:
            fields[name] = _number(data[name], f"{what}.{name}")
    for name in ("collisions", "violations"):
        fields[name] = tuple(_text(v, f"{what}.{name}") for v in _list(data.get(name, []), f"{what}.{name}"))
    fields["route_ahead"] = tuple(_point(p, f"{what}.route_ahead")
                                  for p in _list(data.get("route_ahead", []), f"{what}.route_ahead"))
    fields["blocking"] = bool(data.get("blocking", False))
    return GroundTruth(**fields)


def cot_from_json(value: Any, what: str = "cot") -> CoT:
    """A :class:`CoT` (text, slots, spliced); a log without ``text`` gets its slots joined."""
    data = _mapping(value, what)
    slots = {_text(k, f"{what}.slots"): _text(v, f"{what}.slots.{k}")
             for k, v in _mapping(data.get("slots") or {}, f"{what}.slots").items()}
    text = data.get("text")
    if not isinstance(text, str):
        text = CoT.join_slots(slots) if slots else ""
    return CoT(text=text, slots=slots, spliced=bool(data.get("spliced", False)))


def trajectory_from_json(value: Any, what: str = "trajectory") -> Trajectory:
    """A :class:`Trajectory` with float arrays ``times`` (T,) and ``xy`` (T, 2)."""
    import numpy as np

    data = _mapping(value, what)
    times = [_number(t, f"{what}.times") for t in _list(data.get("times", []), f"{what}.times")]
    xy = [_point(p, f"{what}.xy") for p in _list(data.get("xy", []), f"{what}.xy")]
    return Trajectory(times=np.asarray(times, dtype=float), xy=np.asarray(xy, dtype=float).reshape(len(xy), 2))


def control_from_json(value: Any, what: str = "control") -> Control:
    """A :class:`Control` (``next_state`` an :class:`EgoState` or ``None``)."""
    data = _mapping(value, what)
    numbers = _numbers(data, ("throttle", "steer", "brake", "v_des"), what,
                       required=("throttle", "steer", "brake", "v_des"))
    next_state = data.get("next_state")
    return Control(**numbers, next_state=None if next_state is None else ego_from_json(next_state,
                                                                                       f"{what}.next_state"))
