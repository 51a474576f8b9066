"""A small test driver: pure pursuit on the route ahead, with a speed target and an optional stop point."""

from __future__ import annotations

import math

from vladrivebench import Control, Observation
from vladrivebench.world import MAX_WHEEL_ANGLE, WHEELBASE


def drive(obs: Observation, speed: float = 6.5, stop_before: float | None = None, decel: float = 3.0) -> Control:
    """Track the lane at ``speed``; if ``stop_before`` is set, come to rest that many metres before the
    critical feature (while it is ahead)."""
    target = speed
    distance = obs.ground_truth.distance_to_critical
    if stop_before is not None and distance is not None and distance > -1.0:
        target = min(speed, math.sqrt(2 * decel * max(distance - stop_before, 0.0)))
    error = target - obs.ego.speed
    throttle = min(max(error * 0.8, 0.0), 0.75)
    brake = min(max(-error * 0.5, 0.0), 1.0) if target < obs.ego.speed - 0.05 or target == 0.0 else 0.0
    return Control(throttle, steer_to_route(obs), brake, target)


def steer_to_route(obs: Observation) -> float:
    points = obs.ground_truth.route_ahead
    if not points:
        return 0.0
    lookahead = max(4.0, 0.8 * obs.ego.speed + 3.0)
    x, y = points[min(int(round(lookahead)) - 1, len(points) - 1)]
    alpha = math.atan2(y, x)
    delta = math.atan2(2.0 * WHEELBASE * math.sin(alpha), math.hypot(x, y))
    return max(-1.0, min(1.0, delta / MAX_WHEEL_ANGLE))


def run(sim, scenario, seed: int = 0, **driver) -> list[Observation]:
    """One episode under :func:`drive`; returns every observation."""
    obs = sim.reset(scenario, seed)
    frames = [obs]
    while obs.ground_truth.terminal is None:
        obs = sim.step(drive(obs, **driver))
        frames.append(obs)
    return frames
