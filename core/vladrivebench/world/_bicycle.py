"""Kinematic bicycle model of the ego vehicle, shared by every simulator and controller.

A PID-style control (throttle, steer, brake) becomes a longitudinal acceleration and a front-wheel angle:

    acceleration = THROTTLE_ACCEL * throttle - BRAKE_DECEL * brake      (speed never below 0)
    wheel angle  = MAX_WHEEL_ANGLE * steer                              (steer in [-1, 1])
    yaw rate     = speed * tan(wheel angle) / WHEELBASE

The ego's reference point is the centre of its box; the slip angle is neglected (rear-axle form), which is
accurate at the low speeds of the benchmark (under 10 m/s). One step integrates the motion exactly for a
constant acceleration and wheel angle: the vehicle moves along a circular arc whose length is the distance
covered under that acceleration (stopping early if the speed reaches zero).
"""

from __future__ import annotations

import math

from vladrivebench.errors import ModelOutputError
from vladrivebench.records import Control, EgoState

DT = 0.1
"""Simulation step (s): 10 Hz."""
WHEELBASE = 2.9
"""Distance between the axles (m)."""
THROTTLE_ACCEL = 3.0
"""Acceleration at full throttle (m/s²)."""
BRAKE_DECEL = 8.0
"""Deceleration at full brake (m/s²)."""
MAX_WHEEL_ANGLE = 0.6
"""Front-wheel angle at steer = ±1 (rad)."""
EGO_LENGTH = 4.7
EGO_WIDTH = 1.9

_STRAIGHT_EPS = 1e-9


def clip(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


def acceleration(throttle: float, brake: float) -> float:
    """Longitudinal acceleration (m/s²) of a throttle / brake pair, both clipped to [0, 1]."""
    return THROTTLE_ACCEL * clip(throttle, 0.0, 1.0) - BRAKE_DECEL * clip(brake, 0.0, 1.0)


def wheel_angle(steer: float) -> float:
    """Front-wheel angle (rad) of a normalised steer command, clipped to [-1, 1]."""
    return MAX_WHEEL_ANGLE * clip(steer, -1.0, 1.0)


def yaw_rate(speed: float, steer: float) -> float:
    """Yaw rate (rad/s) at ``speed`` with the normalised ``steer`` command."""
    return speed * math.tan(wheel_angle(steer)) / WHEELBASE


def travelled(speed: float, accel: float, dt: float) -> tuple[float, float]:
    """(distance, final speed) after ``dt`` s at constant ``accel``; the vehicle never reverses."""
    final = speed + accel * dt
    if final >= 0.0:
        return (speed + final) * 0.5 * dt, final
    # Stops within the step: distance to standstill only.
    return speed * speed / (2.0 * -accel), 0.0


def advance(ego: EgoState, throttle: float, steer: float, brake: float, dt: float = DT) -> EgoState:
    """The ego after ``dt`` s of the given control (see the module docstring for the model)."""
    for name, value in (("throttle", throttle), ("steer", steer), ("brake", brake)):
        if not math.isfinite(value):
            raise ModelOutputError(f"control: {name} must be a finite number, got {value!r}")
    distance, speed = travelled(max(ego.speed, 0.0), acceleration(throttle, brake), dt)
    curvature = math.tan(wheel_angle(steer)) / WHEELBASE
    turn = distance * curvature
    if abs(turn) < _STRAIGHT_EPS:
        x = ego.x + distance * math.cos(ego.yaw)
        y = ego.y + distance * math.sin(ego.yaw)
    else:
        radius = 1.0 / curvature
        x = ego.x + radius * (math.sin(ego.yaw + turn) - math.sin(ego.yaw))
        y = ego.y - radius * (math.cos(ego.yaw + turn) - math.cos(ego.yaw))
    yaw = _wrap(ego.yaw + turn)
    return EgoState(x, y, yaw, speed, clip(steer, -1.0, 1.0), ego.length, ego.width)


def apply_control(ego: EgoState, control: Control, dt: float = DT) -> EgoState:
    """The ego after one step of ``control``: placed at ``control.next_state`` when an MPC-style
    controller set it, otherwise integrated through the bicycle model."""
    target = control.next_state
    if target is None:
        return advance(ego, control.throttle, control.steer, control.brake, dt)
    values = (target.x, target.y, target.yaw, target.speed)
    if not all(math.isfinite(v) for v in values):
        raise ModelOutputError(f"control.next_state must be finite, got {values}")
    return EgoState(target.x, target.y, _wrap(target.yaw), max(target.speed, 0.0),
                    clip(target.steer, -1.0, 1.0), ego.length, ego.width)


def _wrap(angle: float) -> float:
    """Angle in (-π, π]."""
    wrapped = math.remainder(angle, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped
