"""Kinematic bicycle invariants (hypothesis)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench.errors import ModelOutputError
from vladrivebench.records import Control, EgoState
from vladrivebench.world._bicycle import (
    BRAKE_DECEL,
    DT,
    MAX_WHEEL_ANGLE,
    THROTTLE_ACCEL,
    WHEELBASE,
    advance,
    apply_control,
    yaw_rate,
)

speeds = st.floats(0.0, 20.0)
pedal = st.floats(-0.5, 1.5)  # out-of-range commands are clipped, never trusted
steers = st.floats(-1.5, 1.5)
angles = st.floats(-math.pi, math.pi)
coords = st.floats(-1e3, 1e3)


def ego(x=0.0, y=0.0, yaw=0.0, speed=0.0) -> EgoState:
    return EgoState(x, y, yaw, speed)


@given(coords, coords, angles, speeds, pedal, steers, pedal)
def test_speed_is_never_negative(x, y, yaw, speed, throttle, steer, brake):
    after = advance(ego(x, y, yaw, speed), throttle, steer, brake)
    assert after.speed >= 0.0
    assert math.isfinite(after.x) and math.isfinite(after.y)


@given(angles, speeds, st.floats(0.0, 1.0))
def test_zero_steer_moves_in_a_straight_line(yaw, speed, throttle):
    after = advance(ego(0.0, 0.0, yaw, speed), throttle, 0.0, 0.0)
    assert after.yaw == pytest.approx(yaw, abs=1e-12) or abs(abs(after.yaw) - math.pi) < 1e-12
    lateral = -math.sin(yaw) * after.x + math.cos(yaw) * after.y
    forward = math.cos(yaw) * after.x + math.sin(yaw) * after.y
    assert lateral == pytest.approx(0.0, abs=1e-9)
    assert forward == pytest.approx((speed + after.speed) / 2 * DT, abs=1e-9)


@given(st.floats(0.1, 15.0), st.floats(-1.0, 1.0))
def test_yaw_rate_is_v_tan_delta_over_wheelbase(speed, steer):
    after = advance(ego(speed=speed), 0.0, steer, 0.0)  # constant speed: no pedals
    expected = speed * math.tan(MAX_WHEEL_ANGLE * steer) / WHEELBASE
    assert after.speed == pytest.approx(speed)
    assert after.yaw / DT == pytest.approx(expected, abs=1e-9)
    assert yaw_rate(speed, steer) == pytest.approx(expected)


@given(st.floats(0.5, 10.0), st.floats(0.05, 1.0).map(lambda v: v * (1 if v > 0.5 else -1)))
@settings(max_examples=30)
def test_constant_steer_drives_a_circle_of_radius_l_over_tan_delta(speed, steer):
    radius = WHEELBASE / math.tan(MAX_WHEEL_ANGLE * steer)
    state = ego(speed=speed)
    for _ in range(50):
        state = advance(state, 0.0, steer, 0.0)
    # The centre of the circle is at (0, radius) for a start at the origin heading east.
    assert math.hypot(state.x, state.y - radius) == pytest.approx(abs(radius), rel=1e-9)


@given(speeds, st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_acceleration_constants(speed, throttle, brake):
    after = advance(ego(speed=speed), throttle, 0.0, brake)
    accel = THROTTLE_ACCEL * throttle - BRAKE_DECEL * brake
    assert after.speed == pytest.approx(max(speed + accel * DT, 0.0), abs=1e-12)


def test_braking_to_a_stop_covers_the_stopping_distance_only():
    after = advance(ego(speed=0.4), 0.0, 0.0, 1.0)  # stops after 0.05 s
    assert after.speed == 0.0
    assert after.x == pytest.approx(0.4**2 / (2 * BRAKE_DECEL))


def test_next_state_places_the_ego_and_clamps_speed():
    target = EgoState(3.0, 1.0, 0.2, -1.0)
    after = apply_control(ego(), Control(0.0, 0.0, 0.0, 0.0, next_state=target))
    assert (after.x, after.y, after.yaw, after.speed) == (3.0, 1.0, 0.2, 0.0)
    assert after.length == ego().length


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_controls_are_model_output_errors(bad):
    with pytest.raises(ModelOutputError, match="throttle"):
        advance(ego(), bad, 0.0, 0.0)
    with pytest.raises(ModelOutputError, match="next_state"):
        apply_control(ego(), Control(0, 0, 0, 0, next_state=EgoState(bad, 0.0, 0.0, 1.0)))
