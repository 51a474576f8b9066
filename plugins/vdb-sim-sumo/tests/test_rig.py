"""The SUMO simulator renders the camera rig as the kinematic one: named cameras, frame and pose history,
route text, and one-line errors for bad rig options."""

from __future__ import annotations

import numpy as np
import pytest
from sumo_episodes import suite_scenario
from vdb_sim_kinematic.simulator import KinematicSimulator
from vladrivebench import ConfigError, Control

RIG = {"rig": "alpamayo", "width": 32, "height": 18, "frames": 2, "frame_rate_hz": 5, "poses": 3}
COAST = Control(0.0, 0.0, 0.0, 5.0)


def test_sumo_renders_every_camera_with_history_like_the_kinematic_simulator(sumo_sim):
    sumo, kinematic = sumo_sim(render=True, **RIG), KinematicSimulator(**RIG)
    scenario = suite_scenario("C.1")
    pair = [(sumo.reset(scenario, 0), kinematic.reset(scenario, 0))]
    for _ in range(3):
        pair.append((sumo.step(COAST), kinematic.step(COAST)))
    obs, reference = pair[-1]
    assert list(obs.cameras) == ["front_wide", "front_tele", "cross_left", "cross_right"]
    for name, view in obs.cameras.items():
        assert view.times == pytest.approx((0.0, 0.2)) and view.latest.shape == (18, 32, 3)
        assert np.array_equal(view.latest, reference.cameras[name].latest)  # the same world, the same camera
    assert obs.pose_history.times == pytest.approx((0.1, 0.2, 0.3))
    assert obs.pose_history.states[-1] == obs.ego and obs.route_text == reference.route_text


def test_sumo_refuses_a_bad_rig_option_in_one_line(sumo_sim):
    with pytest.raises(ConfigError) as info:
        sumo_sim(rig="bogus")
    assert str(info.value) == "simulator 'sumo': option rig must be one of alpamayo, front, got 'bogus'"
    with pytest.raises(ConfigError, match="option frame_rate_hz must be 10 Hz divided by a whole number"):
        sumo_sim(frame_rate_hz=7)
