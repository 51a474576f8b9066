"""SUMO-walked pedestrians (``pedestrians="sumo"``): crossing pedestrians are SUMO persons that walk from one
sidewalk over the crossing at their crossing line to the other, at the scenario's speed, triggered by the
ego's distance.

Documented tolerance against the scripted walk (the kinematic simulator, the same controls): the crossing
line within the position jitter (0.2 m); the pedestrian enters the ego's lane (``blocking``) within 2 s of
the scripted one — SUMO walks it through the walking area to the crossing first, about 1 m farther; it
ends on the other sidewalk, within a crossing width of its line along the road.
"""

from __future__ import annotations

import math

import pytest
from sumo_episodes import drive, lockstep, suite_scenario
from vdb_model_scripted.plugin import make_scripted
from vdb_sim_kinematic.plugin import make_simulator as make_kinematic
from vdb_sim_sumo.network import CROSSING_WIDTH
from vdb_sim_sumo.persons import PERSON_PREFIX
from vladrivebench.episodes import build_component

CROSSERS = ["P.2", "P.3", "P.4", "P.5"]
ENTRY_TOL_STEPS = 20


def first_blocking(observations):
    return next((o.step for o in observations if o.ground_truth.blocking), None)


@pytest.mark.parametrize("scenario_id", CROSSERS)
def test_a_crossing_pedestrian_is_walked_by_sumo_like_the_scripted_one(scenario_id, sumo_sim):
    scenario = suite_scenario(scenario_id)
    sim = sumo_sim(pedestrians="sumo")
    spec = scenario.actor("ped0")
    walked_by_sumo = []

    def check(obs_k, obs_s):
        walked_by_sumo.append(PERSON_PREFIX + "ped0" in sim.libsumo.person.getIDList())
        d_k, d_s = obs_k.ground_truth.distance_to_critical, obs_s.ground_truth.distance_to_critical
        assert abs(d_k - d_s) <= 0.2 + 1e-9

    pairs = lockstep(scenario, 1, make_kinematic(render=False), sim, make_scripted(), build_component("controller", "pid"), 260, check)
    assert any(walked_by_sumo)
    kinematic = [k for k, _ in pairs]
    sumo = [s for _, s in pairs]
    entry_k, entry_s = first_blocking(kinematic), first_blocking(sumo)
    assert entry_k is not None and entry_s is not None
    assert abs(entry_k - entry_s) <= ENTRY_TOL_STEPS  # measured: 1 to 13 steps later in SUMO
    assert not any(o.ground_truth.collisions for o in sumo)
    route = sim.road.route
    walked = [o.ground_truth.actor("ped0") for o in sumo]
    speeds = [a.speed for a in walked]
    assert max(speeds) == pytest.approx(spec.speed, abs=0.05)
    end = walked[-1]
    s_end, offset_end = route.project([[end.x, end.y]])
    start_side = math.copysign(1.0, spec.offset - spec.end_offset)
    assert offset_end[0] * start_side < 0  # it got to the other side
    assert sim.road.road_offset(end.x, end.y) >= -0.3  # ... onto the sidewalk, not in the road
    assert abs(s_end[0] - spec.s) <= CROSSING_WIDTH


def test_sumo_walked_pedestrians_mix_with_background_pedestrians(sumo_sim):
    sim = sumo_sim(pedestrians="sumo", background_pedestrians_per_hour=3000.0, background_warmup_s=20.0)
    seen = drive(sim, suite_scenario("P.4"), 3, 220)
    others = {a.actor_id for o in seen for a in o.ground_truth.actors if a.actor_id.startswith("bg.ped")}
    assert others
    assert any(o.ground_truth.actor("ped0").speed > 1.0 for o in seen)
