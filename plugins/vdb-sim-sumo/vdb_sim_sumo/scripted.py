"""The scenario's scripted motions, in route coordinates: stand, walk along the route, cross the road.

This is the scenario format's own semantics (see :class:`~vladrivebench.scenarios.ActorSpec`): a moving
road user starts once the ego's front bumper is within ``trigger_distance`` of it along the route (from
the first step without one); ``along`` walks at ``speed`` in the ego's direction or against it; ``cross``
walks from ``offset`` to ``end_offset`` across the route at ``s`` and stands there. A road user never
steps into the ego's box: it waits for the ego instead, so a collision is always the ego's doing. Every
simulator that poses the suite must follow these rules for its runs to be comparable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vladrivebench.records import Actor, EgoState
from vladrivebench.scenarios import ActorSpec
from vladrivebench.world.boxes import Box, overlap
from vladrivebench.world.roads import Route


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
        if abs(remaining) <= 1e-12:
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
