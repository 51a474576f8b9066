"""The scripted model's policies: decisions, speed profiles and placement along the route."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_model_scripted.policy import (
    BLEND_DISTANCE,
    MAX_SPEED,
    STEPS,
    Decision,
    World,
    arc_lengths,
    decide,
    place_along_route,
    plan_speeds,
    stop_for,
)
from vdb_model_scripted.reading import ACCELERATING, DECELERATING, KEEP_DISTANCE, MAINTAINING
from vdb_model_scripted.testing import STRAIGHT_ROUTE

speeds = st.floats(0.0, MAX_SPEED)


@st.composite
def decisions(draw):
    stop = draw(st.one_of(st.none(), st.floats(0.0, 120.0)))
    return Decision(DECELERATING if stop is not None else MAINTAINING, "test", None,
                    target=draw(st.floats(0.0, 9.0)), ramp=draw(st.floats(0.0, 3.0)), stop_at=stop,
                    decel=draw(st.floats(0.5, 8.0)))


@given(speed=speeds, decision=decisions())
def test_profiles_stay_within_limits_and_never_pass_the_stop(speed, decision):
    v = plan_speeds(speed, decision)
    assert v.shape == (STEPS,) and np.all(np.isfinite(v))
    assert np.all(v >= 0.0) and np.all(v <= MAX_SPEED)
    if decision.stop_at is not None and decision.stop_at >= 0.5 * speed * 0.1:
        assert arc_lengths(speed, v)[-1] <= decision.stop_at + 1e-9


@given(speed=speeds, target=st.floats(0.0, MAX_SPEED), ramp=st.floats(0.1, 3.0))
def test_without_a_stop_the_profile_moves_monotonically_to_the_target(speed, target, ramp):
    v = plan_speeds(speed, Decision(MAINTAINING, "test", None, target, ramp))
    steps = np.diff(np.concatenate([[speed], v]))
    assert np.all(steps >= -1e-12) or np.all(steps <= 1e-12)
    assert abs(v[-1] - target) <= abs(speed - target) + 1e-12


@given(speed=st.floats(0.5, MAX_SPEED), room=st.floats(0.0, 60.0), cruise=st.floats(3.0, MAX_SPEED))
def test_a_close_stop_decelerates_and_a_far_one_is_approached(speed, room, cruise):
    decision = stop_for("pedestrian", "blocking", room, speed, cruise)
    braking = speed * speed / 6.0
    if room <= braking + 8.0:
        assert decision.action == DECELERATING
        v = plan_speeds(speed, decision)
        assert v[0] <= speed + 1e-12
    else:
        assert decision.action in (MAINTAINING, ACCELERATING) and decision.situation == "approach"


def test_decisions_of_the_perception_policy():
    assert decide(World(), 6.5, 6.5).action == MAINTAINING
    assert decide(World(), 2.0, 6.5).action == ACCELERATING
    red = World("traffic_light", 10.0, light="red")
    assert decide(red, 6.5, 6.5).action == DECELERATING
    assert decide(World("traffic_light", 10.0, light="green"), 6.5, 6.5).action == MAINTAINING
    assert decide(World("traffic_light", 2.0, light="yellow"), 8.0, 6.5).action == MAINTAINING  # too late
    assert decide(World("stop_sign", 10.0), 6.5, 6.5).action == DECELERATING
    assert decide(World("stop_sign", 1.0, stop_made=True), 0.5, 6.5).action == ACCELERATING
    assert decide(World("stop_sign", 1.0), 0.0, 6.5).action == ACCELERATING  # standing at the line
    ped = World("pedestrian", 10.0, blocking=True, lead_kind="pedestrian", lead_gap=10.0, lead_speed=0.0)
    assert decide(ped, 6.5, 6.5).action == DECELERATING
    walking = World("pedestrian", 10.0, blocking=True, lead_kind="pedestrian", lead_gap=10.0, lead_speed=1.5)
    assert decide(walking, 6.5, 6.5).action == KEEP_DISTANCE
    assert decide(World("car", 10.0, blocking=False), 6.5, 6.5).situation == "clear_of_lane"


def test_missing_the_critical_feature_forgets_it_as_the_lead_too():
    ped = World("pedestrian", 10.0, blocking=True, lead_kind="pedestrian", lead_gap=10.0, lead_speed=0.0)
    assert ped.without_critical() == World()
    light = World("traffic_light", 10.0, light="red", lead_kind="car", lead_gap=30.0, lead_speed=5.0)
    assert light.without_critical().lead_gap == 30.0


@given(distances=st.lists(st.floats(0.0, 80.0), min_size=1, max_size=30).map(lambda d: np.sort(np.array(d))))
def test_straight_routes_and_no_route_place_points_straight_ahead(distances):
    for route in (STRAIGHT_ROUTE, ()):
        xy = place_along_route(route, distances)
        assert np.allclose(xy[:, 0], distances) and np.allclose(xy[:, 1], 0.0)


@given(radius=st.floats(15.0, 100.0), side=st.sampled_from([-1.0, 1.0]), offset=st.floats(-1.0, 1.0),
       distances=st.lists(st.floats(BLEND_DISTANCE, 45.0), min_size=2, max_size=10))
@settings(deadline=None)
def test_points_follow_a_curved_lane_and_merge_into_it(radius, side, offset, distances):
    route = tuple((radius * math.sin(s / radius), side * radius * (1 - math.cos(s / radius)) + offset)
                  for s in range(1, 51))
    xy = place_along_route(route, np.array(sorted(distances)))
    centre = np.array([0.0, side * radius + offset])
    assert np.allclose(np.hypot(*(xy - centre).T), radius, atol=0.05)  # on the lane centre past the blend
    start = place_along_route(route, np.array([0.0]))[0]
    assert np.allclose(start, 0.0, atol=1e-9)  # the trajectory starts at the ego


@pytest.mark.parametrize("speed", [0.0, 3.0, 8.5])
def test_arc_lengths_integrate_from_the_current_speed(speed):
    v = np.full(STEPS, 2.0)
    s = arc_lengths(speed, v)
    assert s[0] == pytest.approx(0.5 * (speed + 2.0) * 0.1)
    assert np.all(np.diff(s) == pytest.approx(0.2))
