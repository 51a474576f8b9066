"""Scripted road users: pedestrians, cars and animals that stand, walk along the lane or cross the road.

Road users live in route coordinates (s along the ego's route, offset to the left of the ego lane's
centre), so a scenario's calibration (trigger distances, lateral offsets) holds on any road layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from vladrivebench.records import Actor
from vladrivebench.scenarios import ActorSpec
from vladrivebench.world.roads import Route


@dataclass
class RoadUser:
    """One road user's state during an episode."""

    spec: ActorSpec
    s: float
    offset: float
    started: bool = False
    speed: float = 0.0

    @classmethod
    def start(cls, spec: ActorSpec, s_shift: float = 0.0) -> RoadUser:
        """A road user at its scenario position, shifted ``s_shift`` metres along the route."""
        return cls(spec, spec.s + s_shift, spec.offset, started=spec.motion != "static" and
                   spec.trigger_distance is None)

    @property
    def trigger_s(self) -> float:
        """The route position the ego's front must come within ``trigger_distance`` of."""
        return self.s

    def relative_heading(self) -> float:
        spec = self.spec
        if spec.motion == "static":
            return math.radians(spec.heading_deg)
        if spec.motion == "along":
            return 0.0 if spec.direction == "same" else math.pi
        return math.pi / 2 if spec.end_offset > spec.offset else -math.pi / 2

    def update_trigger(self, ego_front_s: float) -> None:
        spec = self.spec
        if not self.started and spec.motion != "static" and spec.trigger_distance is not None:
            self.started = self.trigger_s - ego_front_s <= spec.trigger_distance

    def proposed(self, dt: float) -> tuple[float, float, float]:
        """(s, offset, speed) after ``dt`` s of walking, before checking that the ego is not in the way."""
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
