"""Road layouts: route arc length and frames, junction routes following the command, ground materials."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._scenarios.spec import parse_scenario
from vladrivebench.world._roads import (
    GRASS,
    KERB,
    MARK_WHITE,
    MARK_YELLOW,
    ROAD,
    ROUTE_STEP,
    SIDEWALK,
    build_road,
)


def scenario(layout="straight", command="follow_lane", **road):
    data = {"id": "T", "title": "t", "family": "intervention", "group": "g", "layout": layout,
            "command": command, "max_time_s": 30.0, "road": {"approach_length": 60.0, **road}}
    return parse_scenario(data, "test.toml")


JUNCTIONS = [
    ("four_way", "straight", {}), ("four_way", "left", {}), ("four_way", "right", {}),
    ("t_junction", "straight", {"junction_side": "through"}),
    ("t_junction", "left", {"junction_side": "through", "stem_side": "left"}),
    ("t_junction", "right", {"junction_side": "through", "stem_side": "right"}),
    ("t_junction", "left", {"junction_side": "dead_end"}), ("t_junction", "right", {"junction_side": "dead_end"}),
]


@pytest.mark.parametrize("layout,command,road", JUNCTIONS)
def test_junction_route_turns_as_commanded_and_stays_on_the_road(layout, command, road):
    geometry = build_road(scenario(layout, command, **road, exit_length=30.0))
    route = geometry.route
    turn = math.remainder(float(route.heading(route.length)) - float(route.heading(0.0)), 2 * math.pi)
    expected = {"straight": 0.0, "left": math.pi / 2, "right": -math.pi / 2}[command]
    assert turn == pytest.approx(expected, abs=1e-9)
    s = np.arange(0.0, route.length, 0.5)
    for side in (-0.95, 0.0, 0.95):  # the ego's whole width stays on the road
        points = route.to_world(s, side)
        assert np.all(geometry.road_offset(points[:, 0], points[:, 1]) <= 0.0)
    # Right-hand traffic: after the junction the route runs in the right half of its road.
    exit_point = route.position(route.length)
    assert geometry.road_offset(*route.to_world(route.length, -1.75 - 0.05)) > 0  # kerb just to the right
    assert np.isfinite(exit_point).all()


def test_route_arc_length_matches_the_geometry():
    geometry = build_road(scenario("four_way", "left", exit_length=30.0))
    box = geometry.junction_half
    radius = box + geometry.lane_width / 2  # left turn from the right lane: B - ego_lane_y
    assert geometry.route.length == pytest.approx(60.0 + radius * math.pi / 2 + 30.0)
    steps = np.diff(geometry.route.s)
    assert steps.max() <= ROUTE_STEP + 1e-9
    chords = np.hypot(*np.diff(geometry.route.points, axis=0).T)
    assert np.allclose(chords, steps, rtol=1e-3)


@given(st.floats(0.0, 120.0), st.floats(-3.0, 3.0))
@settings(max_examples=60, deadline=None)
def test_project_inverts_to_world(s, offset):
    geometry = build_road(scenario("four_way", "right", exit_length=30.0))
    route = geometry.route
    point = route.to_world(s, offset)
    ps, po = route.project(point[None, :], s - 5.0, s + 5.0)
    # The route is a polyline with vertices ROUTE_STEP apart: beside a vertex on a tight turn, the nearest
    # polyline point is the vertex itself, so s can be off by up to |offset| * ROUTE_STEP / (2 * radius).
    assert ps[0] == pytest.approx(s, abs=0.05)
    assert po[0] == pytest.approx(offset, abs=0.02)


def test_straight_road_cross_section():
    geometry = build_road(scenario(lanes=1, lane_width=3.5, sidewalk_width=3.0))
    y = np.array([-0.5, -0.13, 0.13, 2.0, 3.6, 4.0, 8.0, 12.0])
    materials = geometry.classify(np.full(len(y), 30.0), -y)
    assert materials.tolist() == [ROAD, MARK_YELLOW, MARK_YELLOW, ROAD, KERB, SIDEWALK, GRASS, GRASS]
    assert geometry.ego_lane_y == -1.75


def test_two_lane_road_has_dashed_lane_dividers_and_stop_lines_are_painted():
    data = {"id": "T", "title": "t", "family": "traffic_light", "group": "g", "layout": "straight",
            "command": "follow_lane", "max_time_s": 30.0, "critical": "tl0",
            "road": {"approach_length": 80.0, "lanes": 2}, "light": {"state": "red", "stop_line": 50.0}}
    geometry = build_road(parse_scenario(data, "t.toml"))
    along = np.arange(0.0, 18.0, 0.5)
    divider = geometry.classify(along, np.full(len(along), -3.5))
    assert (divider == MARK_WHITE).any() and (divider == ROAD).any()  # dashed
    assert geometry.classify(np.array([49.8]), np.array([-2.0]))[0] == MARK_WHITE
    assert geometry.classify(np.array([49.8]), np.array([2.0]))[0] == ROAD  # only across the ego's direction


def test_junction_corners_are_rounded_kerbs():
    geometry = build_road(scenario("four_way", "straight"))
    jx, _ = geometry.junction
    box, half = geometry.junction_half, geometry.half_width
    # The fillet: points of the corner square far from its outer corner are road, near it are not.
    assert geometry.classify(np.array([jx - half - 0.5]), np.array([half + 0.5]))[0] == ROAD
    radius = geometry.corner_radius
    for dist, material in ((radius - 1.0, SIDEWALK), (radius - 0.1, KERB), (radius + 0.5, ROAD)):
        d = dist / math.sqrt(2)  # along the diagonal from the NW corner's centre into the junction
        assert geometry.classify(np.array([jx - box + d]), np.array([box - d]))[0] == material
    # A T-junction without a south arm has a straight kerb where the arm would be.
    t = build_road(scenario("t_junction", "straight", junction_side="through", stem_side="left"))
    assert t.classify(np.array([jx]), np.array([-half - 1.0]))[0] == SIDEWALK
    assert t.classify(np.array([jx]), np.array([half + 1.0]))[0] == ROAD


def test_scenery_is_deterministic_and_off_the_road():
    urban = build_road(scenario(scenery="urban"))
    again = build_road(scenario(scenery="urban"))
    assert urban.props == again.props and len(urban.props) > 5
    xs = np.array([p.x for p in urban.props])
    ys = np.array([p.y for p in urban.props])
    assert np.all(urban.road_offset(xs, ys) > urban.sidewalk_width)
    assert build_road(scenario(scenery="plain")).props == ()
