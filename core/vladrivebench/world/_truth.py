"""Ground truth shared by every simulator: what is true at each step, computed the same way everywhere.

A simulator supplies the ego's pose and the road users' poses each step; :class:`TruthTracker` turns
them into a :class:`~vladrivebench.records.GroundTruth`. Conventions:

* Positions along the route are measured from the ego's *front bumper* (``s_front = s_centre + length/2``).
* ``distance_to_critical``: to the stop line for a traffic light or stop sign, to the crossing line for a
  crossing pedestrian, and to the near edge (along the route) of any other critical actor; negative once
  the front bumper has passed it.
* ``blocking``: the critical road user currently overlaps the ego's lane corridor (the lane's width,
  centred on the route) at or ahead of the front bumper. Lights and stop signs never block.
* ``lead_gap`` / ``lead_speed``: the nearest road user overlapping the lane corridor ahead, within
  :data:`LEAD_RANGE` m (gap bumper to near edge; speed along the route, negative when approaching).
* Red-light violation: the front bumper crosses the stop line while the light is red. Stop-sign
  violation: it crosses the stop line without the ego having been below :data:`STOP_SPEED` within the
  last :data:`STOP_WINDOW` m before the line. Each is recorded once, on the step it happens.
* ``terminal``: ``collision`` (any collision this step), else ``route_complete`` (the ego's centre reached
  the route's end), else ``timeout`` (the scenario's ``max_steps`` reached).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from vladrivebench._scenarios.spec import Scenario
from vladrivebench.records import Actor, EgoState, GroundTruth
from vladrivebench.world._boxes import Box
from vladrivebench.world._camera import SIGN_PLATE_SIZE
from vladrivebench.world._roads import RoadGeometry

LEAD_RANGE = 100.0
STOP_SPEED = 0.1
STOP_WINDOW = 5.0
ROUTE_AHEAD_STEP = 1.0
ROUTE_AHEAD_LENGTH = 50.0
LIGHT_TOP = 5.2
SIGN_TOP = 2.4
_SEARCH_BEHIND, _SEARCH_AHEAD = 6.0, 12.0


def feature_actors(scenario: Scenario, road: RoadGeometry) -> tuple[Actor, ...]:
    """The scenario's traffic light and stop sign as actors (pose of the head / plate)."""
    out = []
    if scenario.light is not None and road.light_pose is not None:
        p = road.light_pose
        out.append(Actor(scenario.light.id, "traffic_light", p.x, p.y, p.yaw, 0.35, 0.45, LIGHT_TOP,
                         0.0, scenario.light.state))
    if scenario.stop_sign is not None and road.stop_sign_pose is not None:
        p = road.stop_sign_pose
        out.append(Actor(scenario.stop_sign.id, "stop_sign", p.x, p.y, p.yaw, 0.05, SIGN_PLATE_SIZE, SIGN_TOP))
    return tuple(out)


@dataclass(frozen=True)
class RouteExtent:
    """An actor's footprint in route coordinates: the range of s and of the lateral offset of its corners."""

    s_min: float
    s_max: float
    d_min: float
    d_max: float


def route_extent(road: RoadGeometry, actor: Actor) -> RouteExtent:
    """Where an actor's corners lie in route coordinates (nearest points of the whole route)."""
    s, d = road.route.project(Box.of_actor(actor).corners())
    return RouteExtent(float(s.min()), float(s.max()), float(d.min()), float(d.max()))


class TruthTracker:
    """Computes each step's ground truth for one episode of ``scenario`` on ``road``; create one per
    episode (the stop-sign rule remembers where the ego was slow)."""

    def __init__(self, scenario: Scenario, road: RoadGeometry, crossing_s: Mapping[str, float] | None = None):
        """``crossing_s`` overrides the crossing line of crossing actors (a simulator that jittered their
        start passes where they actually cross)."""
        self.scenario, self.road = scenario, road
        self.features = feature_actors(scenario, road)
        self.route_length = road.route.length
        self.corridor = road.lane_width / 2
        self._s_centre: float | None = None
        self._prev_front: float | None = None
        self._stopped_before_sign = False
        self._last_extents: dict[Actor, RouteExtent] = {}
        self._last_ego_s: tuple[float | None, EgoState, float] | None = None
        critical = scenario.actor(scenario.critical) if scenario.critical else None
        self.critical_fixed_s: float | None = None
        if scenario.light is not None and scenario.critical == scenario.light.id:
            self.critical_fixed_s = scenario.light.stop_line
        elif scenario.stop_sign is not None and scenario.critical == scenario.stop_sign.id:
            self.critical_fixed_s = scenario.stop_sign.stop_line
        elif critical is not None and critical.motion == "cross":
            self.critical_fixed_s = (crossing_s or {}).get(critical.id, critical.s)

    def ego_s(self, ego: EgoState) -> float:
        """Route position of the ego's centre, searched near the previous one (routes may pass close to
        themselves in a junction)."""
        prev = self._s_centre
        last = self._last_ego_s
        if last is not None and last[1] is ego and last[0] == prev:
            return last[2]  # asked again within a step (the simulator moves its road users by it first)
        lo = None if prev is None else prev - _SEARCH_BEHIND
        hi = None if prev is None else prev + _SEARCH_AHEAD + ego.speed
        s, _ = self.road.route.project(np.array([[ego.x, ego.y]]), lo, hi)
        self._last_ego_s = (prev, ego, float(s[0]))
        return float(s[0])

    def _extent(self, actor: Actor) -> RouteExtent:
        """:func:`route_extent`, reused from the previous step for an actor that has not changed (parked)."""
        extent = self._last_extents.get(actor)
        return extent if extent is not None else route_extent(self.road, actor)

    def observe(self, step: int, ego: EgoState, actors: Sequence[Actor],
                collisions: Sequence[str] = ()) -> GroundTruth:
        """The ground truth after the ego and ``actors`` (road users, without features) reached this state."""
        s_centre = self.ego_s(ego)
        front = s_centre + ego.length / 2
        extents = {a.actor_id: self._extent(a) for a in actors}
        self._last_extents = {a: extents[a.actor_id] for a in actors}
        critical = self.scenario.critical
        distance = blocking = None
        if critical is not None:
            if self.critical_fixed_s is not None:
                distance = self.critical_fixed_s - front
            if critical in extents:
                ext = extents[critical]
                distance = ext.s_min - front if distance is None else distance
                blocking = self._in_corridor(ext, front)
        lead_gap, lead_speed = self._lead(actors, extents, front)
        violations = self._violations(front, ego.speed)
        self._s_centre, self._prev_front = s_centre, front
        terminal = None
        if collisions:
            terminal = "collision"
        elif s_centre >= self.route_length:
            terminal = "route_complete"
        elif step >= self.scenario.max_steps:
            terminal = "timeout"
        return GroundTruth(
            step=step,
            time=round(step * 0.1, 10),
            actors=tuple(actors) + self.features,
            critical_id=critical,
            critical_kind=self.scenario.critical_kind,
            distance_to_critical=None if distance is None else float(distance),
            blocking=bool(blocking),
            light_state=self.scenario.light.state if self.scenario.light else None,
            lead_gap=lead_gap,
            lead_speed=lead_speed,
            route_progress=float(min(max(s_centre, 0.0), self.route_length)),
            route_length=float(self.route_length),
            collisions=tuple(collisions),
            violations=violations,
            terminal=terminal,
            route_ahead=self.route_ahead(ego, s_centre),
        )

    def _in_corridor(self, ext: RouteExtent, front: float) -> bool:
        return ext.d_max >= -self.corridor and ext.d_min <= self.corridor and ext.s_max >= front

    def _lead(self, actors: Sequence[Actor], extents: dict[str, RouteExtent], front: float) -> tuple[
            float | None, float | None]:
        best: tuple[float, float] | None = None
        for actor in actors:
            ext = extents[actor.actor_id]
            gap = ext.s_min - front
            if not self._in_corridor(ext, front) or gap > LEAD_RANGE:
                continue
            if best is None or gap < best[0]:
                heading = float(self.road.route.heading((ext.s_min + ext.s_max) / 2))
                best = (max(gap, 0.0), actor.speed * math.cos(actor.yaw - heading))
        return (None, None) if best is None else (float(best[0]), float(best[1]))

    def _violations(self, front: float, speed: float) -> tuple[str, ...]:
        out = []
        prev = self._prev_front
        light, sign = self.scenario.light, self.scenario.stop_sign
        if light is not None and light.state == "red" and _crossed(prev, front, light.stop_line):
            out.append(f"red_light:{light.id}")
        if sign is not None:
            line = sign.stop_line
            if line - STOP_WINDOW <= front <= line and speed < STOP_SPEED:
                self._stopped_before_sign = True
            if _crossed(prev, front, line) and not self._stopped_before_sign:
                out.append(f"stop_sign:{sign.id}")
        return tuple(out)

    def route_ahead(self, ego: EgoState, s_centre: float) -> tuple[tuple[float, float], ...]:
        """Ego-frame points of the lane centre along the route every metre up to 50 m ahead."""
        ahead = s_centre + np.arange(ROUTE_AHEAD_STEP, ROUTE_AHEAD_LENGTH + 1e-9, ROUTE_AHEAD_STEP)
        pts = self.road.route.position(ahead)
        c, s = math.cos(ego.yaw), math.sin(ego.yaw)
        dx, dy = pts[:, 0] - ego.x, pts[:, 1] - ego.y
        ex, ey = c * dx + s * dy, -s * dx + c * dy
        return tuple((float(a), float(b)) for a, b in zip(ex.tolist(), ey.tolist(), strict=True))


def _crossed(prev: float | None, now: float, line: float) -> bool:
    return prev is not None and prev < line <= now
