"""Ground truth shared by every simulator: distances, blocking, lead, violations, terminal states."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._scenarios.spec import parse_scenario
from vladrivebench.records import Actor, EgoState
from vladrivebench.world._roads import build_road
from vladrivebench.world._truth import LEAD_RANGE, TruthTracker

LANE_Y = -1.75


def make(layout="straight", command="follow_lane", actors=(), critical=None, family="intervention", **extra):
    data = {"id": "T", "title": "t", "family": family, "group": "g", "layout": layout, "command": command,
            "max_time_s": 20.0, "road": {"approach_length": 120.0, **extra.pop("road", {})},
            "actors": list(actors), **extra}
    if critical:
        data["critical"] = critical
    scenario = parse_scenario(data, "t.toml")
    return scenario, build_road(scenario)


def ego_at(x, speed=5.0, y=LANE_Y, yaw=0.0):
    return EgoState(x, y, yaw, speed)


def pedestrian(s, offset=0.0, **kw):
    return Actor("ped0", "pedestrian", s, LANE_Y + offset, math.pi / 2, 0.5, 0.6, 1.75, **kw)


PED = {"id": "ped0", "kind": "pedestrian", "s": 50.0}


@given(st.floats(0.0, 110.0), st.floats(5.0, 100.0))
@settings(max_examples=60, deadline=None)
def test_distance_to_a_standing_actor_is_front_bumper_to_near_edge(ego_x, ped_x):
    scenario, road = make(actors=[PED], critical="ped0", family="pedestrian")
    truth = TruthTracker(scenario, road).observe(0, ego_at(ego_x), [pedestrian(ped_x)])
    # Facing across the road, the pedestrian's near edge is 0.3 m (half its width) before its centre.
    assert truth.distance_to_critical == pytest.approx(ped_x - 0.3 - (ego_x + 2.35), abs=1e-6)
    assert truth.blocking == (ped_x + 0.3 >= ego_x + 2.35)


def test_distance_decreases_as_the_ego_drives_and_turns_negative_once_passed():
    scenario, road = make(actors=[PED], critical="ped0", family="pedestrian")
    tracker = TruthTracker(scenario, road)
    distances = [tracker.observe(i, ego_at(2.0 * i), [pedestrian(50.0)]).distance_to_critical for i in range(40)]
    assert all(b < a for a, b in zip(distances, distances[1:], strict=False))
    assert distances[0] > 40 and distances[-1] < 0


@pytest.mark.parametrize("offset,blocking", [(0.0, True), (-1.9, True), (-2.1, False), (3.5, False)])
def test_blocking_means_overlapping_the_lane_corridor(offset, blocking):
    scenario, road = make(actors=[PED], critical="ped0", family="pedestrian")
    truth = TruthTracker(scenario, road).observe(0, ego_at(0.0), [pedestrian(40.0, offset)])
    assert truth.blocking is blocking  # the pedestrian is 0.5 m deep across the road: edges at offset ± 0.25


def test_crossing_pedestrian_distance_is_to_the_crossing_line():
    cross = {"id": "ped0", "kind": "pedestrian", "s": 60.0, "offset": 5.0, "motion": "cross", "speed": 1.5,
             "end_offset": -3.0, "trigger_distance": 20.0}
    scenario, road = make(actors=[cross], critical="ped0", family="pedestrian")
    walker = Actor("ped0", "pedestrian", 61.0, LANE_Y + 4.0, -math.pi / 2, 0.5, 0.6, 1.75, 1.5)
    truth = TruthTracker(scenario, road).observe(0, ego_at(10.0), [walker])
    assert truth.distance_to_critical == pytest.approx(60.0 - 12.35)
    assert not truth.blocking


def test_lead_gap_and_speed_of_the_nearest_actor_in_the_lane():
    scenario, road = make()
    tracker = TruthTracker(scenario, road)
    ahead = Actor("car", "car", 40.0, LANE_Y, 0.0, 4.6, 1.9, 1.5, 2.0)
    oncoming = Actor("walker", "pedestrian", 25.0, LANE_Y + 0.3, math.pi, 0.5, 0.6, 1.75, 1.5)
    beside = Actor("parked", "car", 15.0, LANE_Y + 3.5, 0.0, 4.6, 1.9, 1.5)
    truth = tracker.observe(0, ego_at(0.0), [ahead, oncoming, beside])
    assert truth.lead_gap == pytest.approx(25.0 - 0.25 - 2.35)
    assert truth.lead_speed == pytest.approx(-1.5)
    truth = TruthTracker(scenario, road).observe(0, ego_at(0.0), [ahead, beside])
    assert truth.lead_gap == pytest.approx(40.0 - 2.3 - 2.35) and truth.lead_speed == pytest.approx(2.0)
    far = Actor("far", "car", 2.35 + LEAD_RANGE + 5.0, LANE_Y, 0.0, 4.6, 1.9, 1.5)
    truth = TruthTracker(scenario, road).observe(0, ego_at(0.0), [beside, far])
    assert truth.lead_gap is None and truth.lead_speed is None


def drive_through(tracker, speeds, start=80.0):
    """Drive along the straight road with the given speed per step; return each step's violations."""
    x, out = start, []
    for step, speed in enumerate(speeds):
        x += speed * 0.1
        out.append(tracker.observe(step, ego_at(x, speed=speed), []).violations)
    return out


@pytest.mark.parametrize("state,expected", [("red", ["red_light:tl0"]), ("green", []), ("yellow", [])])
def test_red_light_violation_is_recorded_once_when_the_front_crosses_the_line(state, expected):
    scenario, road = make(light={"state": state, "stop_line": 100.0}, critical="tl0", family="traffic_light")
    violations = drive_through(TruthTracker(scenario, road), [6.0] * 60)
    assert [v for step in violations for v in step] == expected
    if expected:
        crossing = next(i for i, v in enumerate(violations) if v)
        front = [80.0 + 0.6 * (i + 1) + 2.35 for i in range(60)]
        assert front[crossing] >= 100.0 > front[crossing - 1]


def stop_sign_scenario():
    return make(stop_sign={"stop_line": 100.0}, critical="stop0", family="stop_sign")


def test_rolling_through_a_stop_sign_is_a_violation():
    scenario, road = stop_sign_scenario()
    violations = drive_through(TruthTracker(scenario, road), [2.0] * 200)
    assert [v for step in violations for v in step] == ["stop_sign:stop0"]


def test_stopping_within_five_metres_of_the_line_is_not_a_violation():
    scenario, road = stop_sign_scenario()
    # Front starts at 82.35: 120 steps at 1.25 m/s reach 97.35 (2.65 m before the line), stop, then go.
    speeds = [1.25] * 120 + [0.0] * 10 + [1.0] * 60
    assert not any(drive_through(TruthTracker(scenario, road), speeds))


def test_stopping_too_early_then_creeping_over_the_line_is_a_violation():
    scenario, road = stop_sign_scenario()
    speeds = [1.0] * 100 + [0.0] * 10 + [0.5] * 200  # stops 7.65 m before the line, then creeps at 0.5 m/s
    assert [v for step in drive_through(TruthTracker(scenario, road), speeds) for v in step] == ["stop_sign:stop0"]


def test_terminal_states_in_order_of_precedence():
    scenario, road = make(road={"approach_length": 50.0})
    tracker = TruthTracker(scenario, road)
    assert tracker.observe(0, ego_at(10.0), []).terminal is None
    assert tracker.observe(1, ego_at(50.0), [], collisions=("x",)).terminal == "collision"
    assert TruthTracker(scenario, road).observe(1, ego_at(50.0), []).terminal == "route_complete"
    assert TruthTracker(scenario, road).observe(scenario.max_steps, ego_at(10.0), []).terminal == "timeout"
    truth = TruthTracker(scenario, road).observe(3, ego_at(60.0), [])
    assert truth.route_progress == truth.route_length == 50.0


def test_route_ahead_follows_the_route_through_a_left_turn():
    scenario, road = make("four_way", "left", road={"exit_length": 40.0})
    route = road.route
    s = 100.0  # a few metres before the junction entry (120)
    x, y = route.position(s)
    truth = TruthTracker(scenario, road).observe(0, EgoState(float(x), float(y), 0.0, 5.0), [])
    points = truth.route_ahead
    assert len(points) == 50
    assert points[0] == pytest.approx((1.0, 0.0), abs=1e-6)
    assert points[15][1] == pytest.approx(0.0, abs=1e-6)  # still straight up to the junction
    assert points[-1][1] > 20.0  # then it bends left, into the north arm
    steps = [math.dist(a, b) for a, b in zip(points, points[1:], strict=False)]
    assert max(steps) <= 1.0 + 1e-6 and min(steps) > 0.95


def test_features_are_actors_with_the_light_colour():
    scenario, road = make(light={"state": "red", "stop_line": 100.0}, stop_sign={"stop_line": 60.0},
                          critical="tl0", family="traffic_light")
    truth = TruthTracker(scenario, road).observe(0, ego_at(0.0), [])
    kinds = {a.actor_id: (a.kind, a.state) for a in truth.actors}
    assert kinds == {"tl0": ("traffic_light", "red"), "stop0": ("stop_sign", None)}
    assert truth.light_state == "red" and truth.critical_kind == "traffic_light"
    assert truth.distance_to_critical == pytest.approx(100.0 - 2.35)


@given(st.lists(st.sampled_from([0.0, 0.05, 0.5, 1.0, 2.0, 4.0]), min_size=20, max_size=80),
       st.floats(85.0, 99.0))
@settings(max_examples=40, deadline=None)
def test_stop_sign_rule_matches_its_definition(speeds, start_front):
    """Violation iff the front crosses the line without a speed below 0.1 m/s within 5 m before it."""
    scenario, road = stop_sign_scenario()
    tracker = TruthTracker(scenario, road)
    front, seen = start_front, []
    recorded = []
    for step, speed in enumerate(speeds):
        previous = front
        front += speed * 0.1
        seen.append((front, speed))
        recorded += tracker.observe(step, ego_at(front - 2.35, speed=speed), []).violations
        if step > 0 and previous < 100.0 <= front:
            stopped = any(95.0 <= f <= 100.0 and v < 0.1 for f, v in seen)
            assert recorded == ([] if stopped else ["stop_sign:stop0"])
            return
    assert recorded == []
