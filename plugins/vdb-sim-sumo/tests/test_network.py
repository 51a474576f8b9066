"""The SUMO network reproduces the shared geometry: planning properties (no SUMO needed) and, for every
suite scenario, the network netconvert built (the ego's lanes lie on the route, stop lines where the
scenario puts them)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sumo_episodes import suite
from vdb_sim_sumo.network import CROSSING_WIDTH, build_network, junction_shape, plan_network
from vdb_sim_sumo.session import import_libsumo, netconvert_binary, sumo_version
from vladrivebench.world import build_road, junction_arms, parse_scenario


def straight_scenario(length, lanes, lane, sidewalk, light_at, crossing_at):
    data = {"id": "T", "title": "t", "family": "baseline" if light_at is None and crossing_at is None
            else "intervention", "group": "g", "layout": "straight", "command": "follow_lane",
            "max_time_s": 10.0, "road": {"approach_length": length, "lanes": lanes, "sidewalk_width": sidewalk},
            "ego": {"lane": lane, "cruise_onset": 0.0}}
    if light_at is not None:
        data["light"] = {"state": "red", "stop_line": light_at}
    if crossing_at is not None:
        data["actors"] = [{"id": "p", "kind": "pedestrian", "s": crossing_at, "offset": 6.0, "motion": "cross",
                           "speed": 1.5, "end_offset": -3.0}]
    return parse_scenario(data, "generated.toml")


@st.composite
def straight_scenarios(draw):
    length = draw(st.floats(60.0, 300.0))
    lanes = draw(st.integers(1, 3))
    light = draw(st.one_of(st.none(), st.floats(10.0, length - 5.0)))
    crossing = draw(st.one_of(st.none(), st.floats(10.0, length)))
    return straight_scenario(length, lanes, draw(st.integers(0, lanes - 1)), draw(st.sampled_from([0.0, 2.0, 3.0])),
                             light, crossing)


@settings(max_examples=60, deadline=None)
@given(straight_scenarios())
def test_a_straight_road_is_one_chain_of_edges_with_nodes_where_the_features_are(scenario):
    plan = plan_network(scenario, build_road(scenario))
    nodes = {n.id: n for n in plan.nodes}
    edges = {e.id: e for e in plan.edges}
    xs = [n.x for n in plan.nodes]
    assert xs == sorted(xs) and len(set(xs)) == len(xs)
    chain = [edges[e] for e in plan.route]
    assert chain[0].start == plan.nodes[0].id and chain[-1].end == plan.nodes[-1].id
    assert all(a.end == b.start for a, b in zip(chain[:-1], chain[1:], strict=True))
    assert plan.ego_lane == scenario.ego.lane + (1 if scenario.road.sidewalk_width > 0 else 0)
    for n in plan.nodes:  # every split node's shape spans the road and its sidewalks
        if n.shape:
            ys = [p[1] for p in n.shape]
            assert min(ys) == pytest.approx(-(scenario.road.lanes * scenario.road.lane_width
                                              + scenario.road.sidewalk_width))
    if plan.tls is not None:  # SUMO's stop line (where the approach edge ends) is the scenario's
        assert min(p[0] for p in nodes[plan.tls].shape) == pytest.approx(scenario.light.stop_line)
        assert edges[plan.feature_approach].end == plan.tls
    for actor_id, node_id in plan.crossing_nodes.items():
        shape_x = [p[0] for p in nodes[node_id].shape]
        actor = scenario.actor(actor_id)
        half = CROSSING_WIDTH / 2
        assert min(shape_x) - half - 1e-9 <= actor.s <= max(shape_x) + half + 1e-9
        assert max(shape_x) - min(shape_x) >= CROSSING_WIDTH - 1e-9


@st.composite
def junction_scenarios(draw):
    layout = draw(st.sampled_from(["four_way", "t_junction"]))
    road = {"approach_length": draw(st.floats(30.0, 150.0)), "exit_length": draw(st.floats(10.0, 60.0)),
            "lanes": draw(st.integers(1, 3)), "corner_radius": draw(st.floats(0.0, 12.0))}
    command = "straight"
    if layout == "t_junction":
        road["junction_side"] = draw(st.sampled_from(["through", "dead_end"]))
        command = "left" if road["junction_side"] == "dead_end" else "straight"
        if road["junction_side"] == "through":
            road["stem_side"] = draw(st.sampled_from(["left", "right"]))
    else:
        command = draw(st.sampled_from(["straight", "left", "right"]))
    data = {"id": "J", "title": "t", "family": "traffic_light", "group": "g", "layout": layout, "command": command,
            "max_time_s": 10.0, "critical": "tl0", "road": road, "light": {"state": "green"}}
    return parse_scenario(data, "generated.toml")


def polygon_area(points):
    p = np.asarray(points)
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


@settings(max_examples=60, deadline=None)
@given(junction_scenarios())
def test_the_junction_outline_cuts_every_arm_at_the_stop_line(scenario):
    road = build_road(scenario)
    names = junction_arms(scenario)
    shape = junction_shape(road, names)
    jx, jy = road.junction
    half, box = road.half_width, road.junction_half
    assert polygon_area(shape) > 0  # counter-clockwise
    assert all(max(abs(x - jx), abs(y - jy)) <= box + 1e-6 for x, y in shape)
    directions = {"east": (1, 0), "north": (0, 1), "west": (-1, 0), "south": (0, -1)}
    for name in names:  # both ends of each arm's cut line are corners of the outline
        dx, dy = directions[name]
        for side in (-1, 1):
            corner = (jx + dx * box - dy * side * half, jy + dy * box + dx * side * half)
            assert any(math.hypot(corner[0] - x, corner[1] - y) < 1e-6 for x, y in shape), (name, side)
    plan = plan_network(scenario, road)
    assert plan.route[0].startswith("west.in.") and plan.tls == "J" and plan.feature_approach == "west.in.0"


@pytest.mark.parametrize("scenario", suite(), ids=lambda s: s.id)
def test_the_built_network_puts_the_ego_lane_on_the_route_and_the_stop_line_on_the_scenarios(scenario, net_cache):
    import sumolib

    road = build_road(scenario)
    plan = plan_network(scenario, road)
    path = build_network(plan, netconvert_binary(), sumo_version(import_libsumo()), net_cache, scenario.id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        net = sumolib.net.readNet(str(path))
    for edge_id in plan.route:
        lane = net.getEdge(edge_id).getLane(plan.ego_lane)
        assert lane.getWidth() == pytest.approx(scenario.road.lane_width)
        s, offset = road.route.project(np.array(lane.getShape()))
        assert np.all(np.abs(offset) < 0.01), f"{edge_id}: the ego lane is off the route by {np.abs(offset).max()}"
    if scenario.light is not None or scenario.stop_sign is not None:
        line = (scenario.light or scenario.stop_sign).stop_line
        end = net.getEdge(plan.feature_approach).getLane(plan.ego_lane).getShape()[-1]
        s, _ = road.route.project(np.array([end]))
        assert s[0] == pytest.approx(line, abs=0.01)
    if plan.has_sidewalks:  # the sidewalk lies beside the lanes, as drawn
        sidewalk = net.getEdge(plan.route[0]).getLane(0)
        assert sidewalk.allows("pedestrian") and not sidewalk.allows("passenger")
        _, offset = road.route.project(np.array(sidewalk.getShape()[:1]))
        expected = -(scenario.ego.lane + 0.5) * scenario.road.lane_width - scenario.road.sidewalk_width / 2
        assert offset[0] == pytest.approx(expected, abs=0.01)
