"""A user's own SUMO network (here one made with SUMO's netgenerate: a 3×3 grid, 120 m blocks, sidewalks,
crossings, a signal at B1) with a route for the ego."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
from sumo_episodes import drive, suite_scenario
from vdb_sim_sumo.network import sumo_environment
from vdb_sim_sumo.session import netconvert_binary
from vladrivebench import ConfigError, ScenarioError
from vladrivebench.world import GRASS, MARK_WHITE, ROAD, SIDEWALK, parse_scenario

ROUTE = "A0A1,A1B1,B1C1"


@pytest.fixture(scope="module")
def grid_net(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("usernet") / "grid.net.xml"
    netgenerate = str(Path(netconvert_binary()).parent / "netgenerate")
    subprocess.run([netgenerate, "--grid", "--grid.number", "3", "--grid.length", "120", "--default.lanewidth",
                    "3.5", "--sidewalks.guess", "true", "--crossings.guess", "true", "--walkingareas", "true",
                    "--tls.set", "B1", "--no-turnarounds", "true", "--no-warnings", "true", "-o", str(path)],
                   check=True, capture_output=True, env=sumo_environment())
    return str(path)


def test_the_ego_drives_the_users_route_on_its_roads(grid_net, sumo_sim):
    sim = sumo_sim(net_file=grid_net, route=ROUTE, depart_pos=10.0)
    seen = drive(sim, suite_scenario("BASE"), 1, 400)
    road = sim.road
    xs = np.array([o.ego.x for o in seen])
    ys = np.array([o.ego.y for o in seen])
    assert np.all(np.isin(road.classify(xs, ys), [ROAD, MARK_WHITE]))  # always on the asphalt (or a zebra)
    assert seen[0].ego.yaw == pytest.approx(np.pi / 2, abs=1e-6)  # A0A1 runs north ...
    turned = [o for o in seen if abs(o.ego.yaw) < 0.1]
    assert turned and turned[-1].ego.x > 60.0  # ... then east along A1B1
    assert seen[-1].ground_truth.route_progress > 150.0
    assert not any(o.ground_truth.collisions for o in seen)


def test_the_users_ground_is_rasterised_for_the_camera(grid_net, sumo_sim):
    sim = sumo_sim(net_file=grid_net, route=ROUTE, render=True)
    obs = sim.reset(suite_scenario("BASE"), 0)
    road = sim.road
    points = road.route.position(np.arange(0.0, road.route.length, 5.0))
    assert np.all(np.isin(road.classify(points[:, 0], points[:, 1]), [ROAD, MARK_WHITE]))
    beside = road.route.to_world(50.0, -(road.lane_width / 2 + road.sidewalk_width / 2))
    assert road.classify(beside[0], beside[1]) == SIDEWALK
    assert road.classify(60.0, 60.0) == GRASS  # inside a block
    assert np.count_nonzero(road.grid == MARK_WHITE) > 100  # the crossings' zebra stripes
    assert obs.image.shape == (80, 160, 3) and len(np.unique(obs.image.reshape(-1, 3), axis=0)) > 10


def test_scenario_actors_are_placed_along_the_users_route(grid_net, sumo_sim):
    sim = sumo_sim(net_file=grid_net, route=ROUTE, position_jitter=0.0)
    scenario = suite_scenario("P.1")
    obs = sim.reset(scenario, 0)
    ped = obs.ground_truth.actor("ped0")
    expected = sim.road.route.to_world(scenario.actor("ped0").s, 0.0)
    assert (ped.x, ped.y) == pytest.approx(tuple(expected))
    assert obs.ground_truth.blocking
    # its near edge (it faces across the road: 0.6 m wide along it) to the ego's front bumper
    assert obs.ground_truth.distance_to_critical == pytest.approx(72.65 - 0.3 - 2.35)


def light_scenario(stop_line: float):
    return parse_scenario({"id": "U.tl", "title": "user light", "family": "traffic_light", "group": "g",
                           "layout": "straight", "command": "follow_lane", "max_time_s": 20.0,
                           "critical": "tl0", "road": {"approach_length": 250.0},
                           "light": {"id": "tl0", "state": "red", "stop_line": stop_line}}, "user-light.toml")


def test_a_scenario_light_is_the_networks_signal_frozen(grid_net, sumo_sim):
    sim = sumo_sim(net_file=grid_net, route=ROUTE, background_vehicles_per_hour=1500.0, background_warmup_s=30.0)
    sim.reset(suite_scenario("BASE"), 0)
    end = sim.libsumo.lane.getShape("A1B1_1")[-1]  # where B1's stop line is along the route
    s, _ = sim.road.route.project(np.array([end]))
    colours = []
    drive(sim, light_scenario(float(s[0])), 0, 120, on_step=lambda obs: colours.append(sim.light_colour()))
    assert set(colours) == {"red"}
    with pytest.raises(ScenarioError) as caught:
        sim.reset(light_scenario(40.0), 0)
    assert "matches no signal" in str(caught.value) and "B1 at s =" in str(caught.value)


@pytest.mark.parametrize("route, depart, expected", [
    ("A0A1,A1B9", 0.0, "edge 'A1B9' is not in"),
    ("A0A1,B1C1", 0.0, "edge 'B1C1' does not follow 'A0A1'"),
    ("A0A1", 500.0, "option depart_pos must be less than the length of edge 'A0A1'"),
])
def test_a_bad_route_is_one_line(grid_net, sumo_sim, route, depart, expected):
    with pytest.raises(ConfigError) as caught:
        sumo_sim(net_file=grid_net, route=route, depart_pos=depart)
    assert expected in str(caught.value) and "\n" not in str(caught.value)
