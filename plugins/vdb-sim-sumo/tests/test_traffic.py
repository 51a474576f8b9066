"""Background traffic (SUMO's own vehicles and pedestrians), SUMO's junction logic, and determinism: the same
seed gives the same episode, also after other episodes in the same process."""

from __future__ import annotations

import numpy as np
from sumo_episodes import actor_trace, drive, suite_scenario
from vdb_sim_sumo.simulator import EGO_ID

TRAFFIC = dict(background_vehicles_per_hour=1500.0, background_pedestrians_per_hour=1500.0,
               background_warmup_s=20.0)


def background(obs):
    return [a for a in obs.ground_truth.actors if a.actor_id.startswith("bg.")]


def test_background_road_users_are_in_the_ground_truth_and_move(sumo_sim):
    sim = sumo_sim(**TRAFFIC)
    seen = drive(sim, suite_scenario("C.2"), 4, 80)
    users = [a for obs in seen for a in background(obs)]
    kinds = {a.kind for a in users}
    assert kinds == {"car", "pedestrian"}
    cars = [a for a in users if a.kind == "car"]
    assert all((a.length, a.width) == (4.6, 1.9) for a in cars)
    assert max(a.speed for a in cars) > 5.0
    assert not seen[0].ground_truth.collisions  # the warm-up traffic was cleared where the ego appears


def test_the_same_seed_gives_the_same_episode_and_another_seed_another_traffic(sumo_sim):
    sim = sumo_sim(**TRAFFIC)
    first = actor_trace(drive(sim, suite_scenario("TL.1-green"), 7, 60))
    drive(sim, suite_scenario("P.4"), 2, 30)  # another episode in between: the simulation is reloaded
    again = actor_trace(drive(sim, suite_scenario("TL.1-green"), 7, 60))
    other = actor_trace(drive(sim, suite_scenario("TL.1-green"), 8, 60))
    assert again == first
    assert other != first


def test_a_new_simulator_in_the_same_process_repeats_the_episode(sumo_sim):
    sim = sumo_sim(**TRAFFIC)
    first = actor_trace(drive(sim, suite_scenario("C.2"), 5, 40))
    sim.close()
    assert actor_trace(drive(sumo_sim(**TRAFFIC), suite_scenario("C.2"), 5, 40)) == first


def crossings_of_the_stop_line(sim, scenario, seed, steps):
    """Background vehicles whose front crossed the ego's stop line from the ego's lane, and all seen."""
    route, line = None, scenario.light.stop_line
    last_s: dict[str, float] = {}
    crossed, seen = set(), set()

    def watch(obs):
        nonlocal route
        route = sim.road.route
        for vid in sim.libsumo.vehicle.getIDList():
            if vid == EGO_ID:
                continue
            seen.add(vid)
            x, y = sim.libsumo.vehicle.getPosition(vid)
            s, offset = route.project(np.array([[x, y]]), 0.0, line + 30.0)
            if abs(offset[0]) > 1.0:
                last_s.pop(vid, None)
                continue
            if last_s.get(vid, np.inf) < line <= s[0]:
                crossed.add(vid)
            last_s[vid] = float(s[0])

    drive(sim, scenario, seed, steps, on_step=watch)
    return crossed, seen


def test_background_traffic_stops_at_the_frozen_red_light_and_drives_through_the_green(sumo_sim):
    sim = sumo_sim(background_vehicles_per_hour=2000.0, background_warmup_s=40.0)
    red, seen_red = crossings_of_the_stop_line(sim, suite_scenario("TL.1-red"), 1, 150)
    green, _ = crossings_of_the_stop_line(sim, suite_scenario("TL.1-green"), 1, 150)
    assert len(seen_red) > 10
    assert red == set()
    assert green  # the same watch sees cars cross on green: it can fail


def test_background_traffic_stops_at_the_stop_junction(sumo_sim):
    sim = sumo_sim(background_vehicles_per_hour=2000.0, background_warmup_s=10.0)
    sumo = sim.libsumo
    approach_speeds: dict[str, list[float]] = {}
    entered = set()

    def watch(obs):
        for vid in sumo.vehicle.getIDList():
            lane = sumo.vehicle.getLaneID(vid)
            if vid == EGO_ID:
                continue
            if lane.startswith(":J_"):
                entered.add(vid)
            elif ".in.0_" in lane and sumo.lane.getLength(lane) - sumo.vehicle.getLanePosition(vid) < 6.0:
                approach_speeds.setdefault(vid, []).append(sumo.vehicle.getSpeed(vid))

    drive(sim, suite_scenario("S.3"), 2, 200, on_step=watch)
    through = [v for v in entered if v in approach_speeds]
    assert len(through) >= 3
    assert all(min(approach_speeds[v]) < 1.0 for v in through)
