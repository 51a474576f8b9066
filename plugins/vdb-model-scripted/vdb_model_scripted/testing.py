"""Hand-built observations for tests of the scripted model and of metrics calibrated against it.

The ego stands at the world origin heading east (so the world frame is the ego frame) on a straight road
whose lane centre is the x axis; the critical feature is placed to match ``distance`` (front bumper to the
feature's stop line or near edge, as the ground truth measures it).
"""

from __future__ import annotations

import numpy as np
from vladrivebench import Actor, EgoState, GroundTruth, Observation

EGO_HALF_LENGTH = EgoState(0.0, 0.0, 0.0, 0.0).length / 2.0
STRAIGHT_ROUTE = tuple((float(i), 0.0) for i in range(1, 51))
"""The lane centre every metre up to 50 m straight ahead, as ``GroundTruth.route_ahead`` gives it."""


def critical_actor(kind: str, distance: float, *, blocking: bool = True, light: str | None = None,
                   speed: float = 0.0, actor_id: str = "crit") -> Actor:
    """The critical feature ``distance`` metres ahead of the ego's front bumper (ego at the origin)."""
    x = distance + EGO_HALF_LENGTH
    if kind == "pedestrian":
        return Actor(actor_id, kind, x + 0.25, 0.0 if blocking else -3.2, speed=speed)
    if kind == "car":
        return Actor(actor_id, kind, x + 2.3, 0.0 if blocking else 3.5, length=4.6, width=1.9, height=1.5,
                     speed=speed)
    if kind == "animal":
        return Actor(actor_id, kind, x + 0.5, 0.0 if blocking else -3.2, length=1.0, width=0.4, height=0.8)
    if kind == "traffic_light":
        return Actor(actor_id, kind, x + 3.0, -5.0, length=0.35, width=0.45, height=5.2, state=light)
    if kind == "stop_sign":
        return Actor(actor_id, kind, x + 1.0, -4.5, length=0.05, width=0.75, height=2.4)
    raise ValueError(f"unknown critical kind {kind!r}")


def make_observation(*, speed: float = 6.5, step: int = 0, kind: str | None = None, distance: float | None = None,
                     blocking: bool = True, light: str | None = None, actor_speed: float = 0.0,
                     route: tuple[tuple[float, float], ...] = STRAIGHT_ROUTE, extra_actors: tuple[Actor, ...] = (),
                     ego: EgoState | None = None) -> Observation:
    """An observation with at most one critical feature of ``kind`` at ``distance`` (see module docstring).

    A blocking road user is also the lead (gap = ``distance``, speed = ``actor_speed``).
    """
    actors = tuple(extra_actors)
    gt_kwargs: dict = {}
    if kind is not None:
        if distance is None:
            raise ValueError("a critical feature needs a distance")
        road_user = kind in ("pedestrian", "car", "animal")
        actor = critical_actor(kind, distance, blocking=blocking, light=light, speed=actor_speed)
        actors = (actor, *actors)
        gt_kwargs = {"critical_id": actor.actor_id, "critical_kind": kind, "distance_to_critical": distance,
                     "blocking": bool(blocking and road_user), "light_state": light if kind == "traffic_light" else None}
        if road_user and blocking:
            gt_kwargs.update(lead_gap=max(distance, 0.0), lead_speed=actor_speed)
    gt = GroundTruth(step=step, time=round(step * 0.1, 10), actors=actors, route_ahead=route, **gt_kwargs)
    return Observation(step=step, time=gt.time, image=np.zeros((4, 8, 3), np.uint8),
                       ego=ego or EgoState(0.0, 0.0, 0.0, speed), command="follow_lane", ground_truth=gt)
