"""The shipped weights see and act: open-loop checks on camera frames of the scenario suite.

These are regression tests of the trained bundles (a retrained model that no longer sees red lights or a
blocking car fails here), on a few frames each so they stay fast. The frames come from the kinematic
simulator with the ego driven towards the critical object at a steady speed.
"""

from __future__ import annotations

import numpy as np
import pytest
from vladrivebench.plugins import get_registry
from vladrivebench.records import Control
from vladrivebench.scenarios import load_suite

DISTANCES = (18.0, 13.0, 8.0)  # within 3 s of driving on at 7 m/s
SPEED = 7.0


def approach(scenario_id: str, distance: float):
    """The observation when the ego, driving at ~7 m/s, is first within ``distance`` of the critical object."""
    simulator = get_registry().create("simulator", "kinematic", {"width": 160, "height": 80})
    obs = simulator.reset(load_suite()[scenario_id], 0)
    while obs.ground_truth.distance_to_critical > distance:
        throttle = 0.6 if obs.ego.speed < SPEED else 0.0
        obs = simulator.step(Control(throttle=throttle, steer=0.0, brake=0.0, v_des=SPEED))
    simulator.close()
    return obs


@pytest.fixture(scope="module")
def frames():
    scenarios = ("TL.1-red", "TL.3-red", "TL.1-green", "C.1", "C.2")
    return {sid: [approach(sid, d) for d in DISTANCES] for sid in scenarios}


@pytest.fixture(scope="module")
def models():
    from vdb_model_neural.kv_model import KVModel
    from vdb_model_neural.qa_model import QAModel

    return {"kv": KVModel(), "qa": QAModel()}


def stops_short(model, obs) -> tuple[bool, str]:
    """(does the 3 s plan end before the critical object — the stop line, the car's rear?, the CoT)."""
    rng = np.random.default_rng(0)
    cot = model.generate_cot(obs, rng)
    travelled = model.decode_action(obs, cot, rng).path_length(3.0)
    return travelled < obs.ground_truth.distance_to_critical, cot.text


QA_RUNS_RED = pytest.mark.xfail(strict=True, reason="qa's planner runs red lights while its answers say red "
                                "(README: closed-loop driving); strict, so a qa that learns it fails here")


@pytest.mark.parametrize("name, scenario_id", [
    ("kv", "TL.1-red"), ("kv", "TL.3-red"), ("kv", "C.1"), ("qa", "TL.1-red"), ("qa", "C.1"),
    pytest.param("qa", "TL.3-red", marks=QA_RUNS_RED),
])
def test_the_models_stop_for_a_red_light_and_a_blocking_car(models, frames, name, scenario_id):
    results = [stops_short(models[name], obs) for obs in frames[scenario_id]]
    assert sum(short for short, _ in results) >= 2, results


@pytest.mark.parametrize("name", ["kv", "qa"])
@pytest.mark.parametrize("scenario_id", ["TL.1-green", "C.2"])
def test_the_models_keep_going_for_a_green_light_and_a_car_beside_the_lane(models, frames, name, scenario_id):
    results = [stops_short(models[name], obs) for obs in frames[scenario_id]]
    assert sum(not short for short, _ in results) >= 2, results


@pytest.mark.parametrize("name", ["kv", "qa"])
@pytest.mark.parametrize("scenario_id, word", [("TL.1-red", "red"), ("TL.3-red", "red"), ("C.1", "car")])
def test_the_models_say_what_they_should_stop_for(models, frames, name, scenario_id, word):
    texts = [stops_short(models[name], obs)[1].lower() for obs in frames[scenario_id]]
    assert sum(word in text for text in texts) >= 2, texts


@pytest.mark.parametrize("scenario_id", ["TL.1-red", "C.1"])
def test_kv_drives_up_to_a_red_light_and_a_blocking_car_closed_loop_and_stops(models, scenario_id):
    """Closed loop (the frames above are open loop): a model whose reading flickers as it approaches, or
    whose steering drifts so the car seems to be in the other lane, runs the light or hits the car here."""
    import dataclasses

    from vladrivebench.controllers import MPCController
    from vladrivebench.runner import run_episode

    scenario = dataclasses.replace(load_suite()[scenario_id], max_time_s=25.0)  # long enough to get there
    simulator = get_registry().create("simulator", "kinematic", {"width": 160, "height": 80})
    result = run_episode(models["kv"], simulator, MPCController(), scenario, 0)
    simulator.close()
    assert result.collisions == 0 and result.violations == 0, result
    assert result.mean_speed > 1.0, result  # it drove there rather than standing still
