"""Cross-check: on every scenario of the suite, the SUMO and kinematic runs of the scripted model agree on the
ground truth the metrics use.

Documented tolerance (default ``pedestrians="scripted"``): the ego's pose equal to 1e-9 m, every scenario
road user's pose within 1 mm, ``distance_to_critical`` within 1 mm, and ``blocking``, ``light_state`` (also
the colour SUMO's own traffic light shows the ego), ``collisions``, ``violations`` and ``terminal`` equal at
every step; SUMO's own copy of each placed road user (a SUMO person or vehicle) within 10 cm of it (SUMO
maps a placed person onto its walking path). Horizon: the first 200 steps (20 s) of each episode — the run-up, the approach and the
critical event of every scenario (a stop at the light, the stop sign crossed, the pedestrian's crossing) —
to keep the file fast; the episode runs in lockstep (one model, the same controls to both simulators),
which is the closed loop on both as long as they agree, which is what is asserted.
"""

from __future__ import annotations

import numpy as np
import pytest
from sumo_episodes import lockstep, suite, truth_differences
from vdb_model_scripted.plugin import make_scripted
from vdb_sim_kinematic.plugin import make_simulator as make_kinematic
from vladrivebench.episodes import build_component

HORIZON = 200
DISTANCE_TOL = 1e-3
POSE_TOL = 1e-3
SUMO_COPY_TOL = 0.1


@pytest.mark.parametrize("scenario", suite(), ids=lambda s: s.id)
def test_sumo_and_kinematic_agree_on_the_ground_truth(scenario, sumo_sim):
    kinematic, sumo = make_kinematic(render=False), sumo_sim()
    def check(obs_k, obs_s):
        where = f"{scenario.id} step {obs_k.step}"
        assert obs_s.step == obs_k.step
        ego_k, ego_s = obs_k.ego, obs_s.ego
        assert abs(ego_k.x - ego_s.x) + abs(ego_k.y - ego_s.y) + abs(ego_k.speed - ego_s.speed) < 1e-9, where
        gt_k, gt_s = obs_k.ground_truth, obs_s.ground_truth
        assert truth_differences(gt_k, gt_s, DISTANCE_TOL) == [], where
        for actor in gt_k.actors:
            twin = gt_s.actor(actor.actor_id)
            assert twin is not None and twin.kind == actor.kind, f"{where}: {actor.actor_id} missing in SUMO"
            assert abs(twin.x - actor.x) < POSE_TOL and abs(twin.y - actor.y) < POSE_TOL, where
            if scenario.actor(actor.actor_id) is not None:  # SUMO's own copy of a placed road user
                copy = sumo.sumo_pose(actor.actor_id)
                assert abs(copy.x - actor.x) < SUMO_COPY_TOL and abs(copy.y - actor.y) < SUMO_COPY_TOL, where
        assert len(gt_s.actors) == len(gt_k.actors), where
        assert sumo.light_colour() == gt_k.light_state, where

    pairs = lockstep(scenario, 3, kinematic, sumo, make_scripted(), build_component("controller", "pid"), HORIZON, check)
    distances = [k.ground_truth.distance_to_critical for k, _ in pairs]
    if scenario.critical is not None:  # the horizon reaches the critical event: passed, or stopped near it
        assert min(distances) < 12.0, f"{scenario.id}: still {min(distances):.1f} m from the critical feature"


@pytest.mark.parametrize("scenario_id", ["P.2", "TL.1-red"])
def test_the_camera_sees_the_same_image_in_both_simulators(scenario_id, sumo_sim):
    from sumo_episodes import suite_scenario

    kinematic, sumo = make_kinematic(render=True), sumo_sim(render=True)
    images = []

    def check(obs_k, obs_s):
        if obs_k.step % 10 == 0:
            images.append(obs_k.step)
            assert np.array_equal(obs_k.image, obs_s.image), f"{scenario_id} step {obs_k.step}"

    lockstep(suite_scenario(scenario_id), 3, kinematic, sumo, make_scripted(), build_component("controller", "pid"), 150, check)
    assert len(images) == 15
