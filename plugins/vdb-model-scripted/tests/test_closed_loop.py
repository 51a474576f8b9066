"""The scripted model driving scenarios of the suite in the kinematic simulator, through the core's runner."""

from __future__ import annotations

import pytest
from vdb_model_scripted.model import ScriptedModel
from vdb_model_scripted.reading import named_kinds
from vdb_sim_kinematic.plugin import make_simulator  # a test dependency (the `test` extra)
from vladrivebench.episodes import build_component
from vladrivebench.testing import run_episode
from vladrivebench.world import load_suite


@pytest.fixture(scope="module")
def suite():
    return load_suite()


def drive(suite, scenario_id, model, controller=None, seed=0, max_steps=220):
    steps = []

    def on_step(obs, cot, trajectory, control, extras):
        steps.append((obs, cot, trajectory, control, extras))

    result = run_episode(model, make_simulator(render=False), controller or build_component("controller", "pid"), suite[scenario_id],
                         seed, on_step=on_step, max_steps=max_steps)
    return result, steps


def test_stops_for_the_pedestrian_and_says_so(suite):
    result, steps = drive(suite, "P.1", ScriptedModel(alpha=0.5))
    assert result.collisions == 0
    last_obs = steps[-1][0]
    assert last_obs.ego.speed < 0.05
    assert 2.5 < last_obs.ground_truth.distance_to_critical < 6.0
    for _, cot, _, control, extras in steps:
        truth = extras["scripted_truth"]
        if truth["mentioned"]:
            assert "pedestrian" in named_kinds(cot.text)
        assert control.v_des <= 8.5
    assert any(extras["scripted_truth"]["stated_action"] == "decelerating" for *_, extras in steps)


def test_stops_at_the_red_light_with_the_mpc_controller(suite):
    result, steps = drive(suite, "TL.1-red", ScriptedModel(alpha=1.0, cot_format="qa"), build_component("controller", "mpc"))
    assert result.collisions == 0 and not any(obs.ground_truth.violations for obs, *_ in steps)
    final = steps[-1][0]
    assert final.ego.speed < 0.05 and 0.0 < final.ground_truth.distance_to_critical < 3.0


def test_a_fully_coupled_model_that_misses_the_pedestrian_runs_into_it(suite):
    blind, _ = drive(suite, "P.1", ScriptedModel(alpha=1.0, miss_rate=1.0))
    assert blind.collisions > 0
    safe, _ = drive(suite, "P.1", ScriptedModel(alpha=0.0, miss_rate=1.0))
    assert safe.collisions == 0


def test_an_episode_is_reproduced_by_its_seed(suite):
    model = ScriptedModel(alpha=0.5, hallucination_rate=0.3, contradiction_rate=0.2, cot_format="qa")
    first = drive(suite, "S.1", model, seed=4, max_steps=120)[1]
    second = drive(suite, "S.1", model, seed=4, max_steps=120)[1]
    assert [s[1].text for s in first] == [s[1].text for s in second]
    assert all((a[2].xy == b[2].xy).all() for a, b in zip(first, second, strict=True))
    assert [s[3] for s in first] == [s[3] for s in second]
