"""Scripted road users and episode setup, shared by every simulator that poses the scenario suite.

The scripts are the scenario format's own semantics (see :class:`~vladrivebench._scenarios.spec.ActorSpec`),
in route coordinates (``s`` along the ego's route, ``offset`` to the left of the ego lane's centre), so a
scenario's calibration (trigger distances, lateral offsets) holds on any road layout:

* ``static``: the road user stands at ``(s, offset)`` facing ``heading_deg`` relative to the route (a
  stopped car, a standing pedestrian);
* ``along``: it walks along the route at ``speed``, in the ego's direction (``same``) or against it;
* ``cross``: it walks across the route at ``s``, from ``offset`` to ``end_offset``, and stands there.

A moving road user starts once the ego's front bumper is within ``trigger_distance`` of it along the
route (without one, from the first step). A road user never steps into the ego's box: it waits for the
ego instead, so a collision is always the ego's doing. Every simulator must follow these rules for its
runs to be comparable.

Seeds: :func:`scripted_users` shifts the along-route start of pedestrians and animals uniformly within
±``position_jitter`` metres, drawn from ``episode_rng(seed, "simulator")`` in scenario order; cars never
move. The same stream in every simulator makes them pose the same episode for a seed.

The rest is setup the suite's simulators share: the ego's start (:func:`ego_at_start`), the features the
shared world represents (:data:`WORLD_FEATURES`, :func:`check_supported`) and the camera and jitter
options (:func:`check_view_options`, :func:`blank_image`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from vladrivebench._engine.rng import episode_rng
from vladrivebench._scenarios.spec import ActorSpec, Scenario
from vladrivebench.errors import ConfigError, ScenarioError
from vladrivebench.records import Actor, EgoState
from vladrivebench.world import _bicycle as bicycle
from vladrivebench.world._boxes import Box, overlap
from vladrivebench.world._roads import Route

JITTERED_KINDS = ("pedestrian", "animal")
"""Road-user kinds whose start a seed shifts along the route."""

WORLD_FEATURES = frozenset(
    {f"layout:{name}" for name in ("straight", "t_junction", "four_way")}
    | {f"scenery:{name}" for name in ("plain", "suburban", "urban")}
    | {f"lanes:{n}" for n in (1, 2, 3, 4)}
    | {f"actor:{kind}" for kind in ("pedestrian", "car", "animal")}
    | {f"motion:{kind}" for kind in ("static", "along", "cross")}
    | {f"traffic_light:{colour}" for colour in ("red", "yellow", "green")}
    | {"stop_sign"}
)
"""Every scenario feature (see :meth:`Scenario.features`) the shared world represents: the roads of
:mod:`~vladrivebench.world._roads`, the road users' scripts of this module, lights and stop signs."""

_AT_REST = 1e-12
"""A crossing road user this close (m) to its end offset has arrived."""


@dataclass
class ScriptedUser:
    """One road user's scripted state during an episode: route position ``s``, lateral ``offset``."""

    spec: ActorSpec
    s: float
    offset: float
    started: bool = False
    speed: float = 0.0

    @classmethod
    def at_start(cls, spec: ActorSpec, s_shift: float = 0.0) -> ScriptedUser:
        """The road user at its scenario position, shifted ``s_shift`` metres along the route."""
        moving = spec.motion != "static"
        return cls(spec, spec.s + s_shift, spec.offset, started=moving and spec.trigger_distance is None)

    def relative_heading(self) -> float:
        """Heading relative to the route (rad): as specified when static, else where it walks."""
        spec = self.spec
        if spec.motion == "static":
            return math.radians(spec.heading_deg)
        if spec.motion == "along":
            return 0.0 if spec.direction == "same" else math.pi
        return math.pi / 2 if spec.end_offset > spec.offset else -math.pi / 2

    def check_trigger(self, ego_front_s: float) -> bool:
        """Start moving once the ego's front is within the trigger distance; True on the step it starts."""
        spec = self.spec
        if self.started or spec.motion == "static" or spec.trigger_distance is None:
            return False
        self.started = self.s - ego_front_s <= spec.trigger_distance
        return self.started

    def proposal(self, dt: float) -> tuple[float, float, float]:
        """(s, offset, speed) after ``dt`` seconds of its motion, before the ego is taken into account."""
        spec = self.spec
        if not self.started or spec.motion == "static":
            return self.s, self.offset, 0.0
        step = spec.speed * dt
        if spec.motion == "along":
            return self.s + (step if spec.direction == "same" else -step), self.offset, spec.speed
        remaining = spec.end_offset - self.offset
        if abs(remaining) <= _AT_REST:
            return self.s, self.offset, 0.0
        moved = math.copysign(min(step, abs(remaining)), remaining)
        return self.s, self.offset + moved, spec.speed * abs(moved) / step

    def advance(self, route: Route, ego: EgoState, dt: float) -> None:
        """Move one step unless that would put it into the ego's box (then it waits, speed 0)."""
        s, offset, speed = self.proposal(dt)
        if (s, offset) == (self.s, self.offset):
            self.speed = 0.0
            return
        ego_box = Box.of_ego(ego)
        moved = Box.of_actor(self.actor(route, s, offset, speed))
        # A road user already overlapping the ego (the ego drove into it) may walk out of the overlap.
        if overlap(ego_box, moved) and not overlap(ego_box, Box.of_actor(self.actor(route))):
            self.speed = 0.0
            return
        self.s, self.offset, self.speed = s, offset, speed

    def actor(self, route: Route, s: float | None = None, offset: float | None = None,
              speed: float | None = None) -> Actor:
        """The road user as a ground-truth :class:`Actor` (optionally at a proposed position)."""
        s = self.s if s is None else s
        offset = self.offset if offset is None else offset
        x, y = (float(v) for v in route.to_world(s, offset))
        yaw = math.remainder(float(route.heading(s)) + self.relative_heading(), 2 * math.pi)
        spec = self.spec
        return Actor(spec.id, spec.kind, x, y, yaw, spec.length, spec.width, spec.height,
                     self.speed if speed is None else speed)


def scripted_users(scenario: Scenario, seed: int, position_jitter: float) -> list[ScriptedUser]:
    """The scenario's road users at their start, in scenario order, pedestrians and animals shifted along
    the route by a seeded draw within ±``position_jitter`` m (see the module docstring)."""
    rng = episode_rng(seed, "simulator")
    users = []
    for spec in scenario.actors:
        shift = 0.0
        if spec.kind in JITTERED_KINDS and position_jitter > 0:
            shift = float(rng.uniform(-position_jitter, position_jitter))
        users.append(ScriptedUser.at_start(spec, shift))
    return users


def ego_at_start(route: Route, speed: float) -> EgoState:
    """The ego at the start of its route, heading along it at ``speed`` (m/s), with the bicycle's size."""
    x, y = (float(v) for v in route.position(0.0))
    return EgoState(x, y, float(route.heading(0.0)), speed, 0.0, bicycle.EGO_LENGTH, bicycle.EGO_WIDTH)


def check_supported(scenario: Scenario, simulator: str,
                    supported: frozenset[str] = WORLD_FEATURES) -> None:
    """Raise a one-line :class:`ScenarioError` if the scenario needs a feature the simulator lacks."""
    missing = sorted(scenario.features() - supported)
    if missing:
        where = scenario.source or scenario.id
        raise ScenarioError(
            f"scenario {where}: simulator {simulator!r} cannot represent {missing[0]!r} "
            f"(it supports: {', '.join(sorted(supported))})"
        )


VIEW_OPTIONS = (("hfov_deg", 10.0, 170.0), ("camera_height", 0.2, 10.0), ("pitch_deg", -30.0, 60.0),
                ("position_jitter", 0.0, 2.0))
"""(name, low, high) of the numeric camera and jitter options every suite simulator takes."""


def option_error(simulator: str, name: str, expected: str, value: Any) -> ConfigError:
    """The one-line error for a simulator option: ``simulator 'x': option n must be <expected>, got v``."""
    return ConfigError(f"simulator {simulator!r}: option {name} must be {expected}, got {value!r}")


def check_view_options(simulator: str, values: Mapping[str, Any]) -> None:
    """Raise an :func:`option_error` for the first bad camera or jitter option in ``values``: ``width`` and
    ``height`` (whole pixels, 8 to 4096), ``render`` (a bool), then :data:`VIEW_OPTIONS` in order."""
    for name in ("width", "height"):
        value = values[name]
        if isinstance(value, bool) or not isinstance(value, int) or not 8 <= value <= 4096:
            raise option_error(simulator, name, "a whole number between 8 and 4096", value)
    if not isinstance(values["render"], bool):
        raise option_error(simulator, "render", "true or false", values["render"])
    check_numbers(simulator, values, VIEW_OPTIONS)


def check_numbers(simulator: str, values: Mapping[str, Any],
                  ranges: tuple[tuple[str, float, float], ...]) -> None:
    """Raise an :func:`option_error` for the first ``values[name]`` that is not a number in its range."""
    for name, low, high in ranges:
        value = values[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
            raise option_error(simulator, name, f"a number between {low:g} and {high:g}", value)


def blank_image(width: int, height: int) -> np.ndarray:
    """The read-only black image a simulator returns when it does not render."""
    image = np.zeros((height, width, 3), dtype=np.uint8)
    image.flags.writeable = False
    return image
