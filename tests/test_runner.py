"""The episode loop: closed loop, pinned RNG, validation of model output, pluggable step policies."""

from __future__ import annotations

import json

import numpy as np
import pytest
import runner_fakes as fakes
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._engine.rng import step_rng
from vladrivebench._engine.runner import (
    EpisodeFailure,
    check_model_output,
    model_step,
    observation_from_step,
    own_cot_policy,
    run_episode,
)
from vladrivebench._logs.episodes import EpisodeWriter, read_episode
from vladrivebench.errors import ModelOutputError
from vladrivebench.records import CoT, Trajectory

EchoModel, ExplodingSimulator, FakeScenario = fakes.EchoModel, fakes.ExplodingSimulator, fakes.FakeScenario
LineSimulator, SpeedController = fakes.LineSimulator, fakes.SpeedController


ROAD = FakeScenario("road")


def drive(scenario=ROAD, seed=0, model=None, sim=None, **kw):
    steps = []
    result = run_episode(model or EchoModel(), sim or LineSimulator(), SpeedController(), scenario, seed,
                         model_name="echo", on_step=lambda *a: steps.append(a), **kw)
    return result, steps


def test_episode_runs_closed_loop_to_route_completion():
    result, steps = drive()
    assert result.terminal == "route_complete" and result.route_completion == 1.0
    assert result.steps == len(steps) and [s[0].step for s in steps] == list(range(len(steps)))
    assert steps[-1][0].ground_truth.terminal == "route_complete"
    speeds = [s[0].ego.speed for s in steps]
    assert result.mean_speed == pytest.approx(np.mean(speeds))
    assert result.duration == pytest.approx(steps[-1][0].time)
    assert speeds[-1] > speeds[0]  # the controller followed the model's cruise trajectory


def test_collision_ends_the_episode_and_is_counted():
    blind = EchoModel()
    blind.generate_cot = lambda obs, rng: CoT("go")  # never sees the car
    result, steps = drive(FakeScenario("car", length=40.0, car_at=12.0), model=blind)
    assert result.terminal == "collision"
    assert result.collisions == 1 and result.collision_events == ("car0",)
    assert steps[-1][0].ground_truth.collisions == ("car0",)
    assert 0 < result.route_completion < 1


def test_simulator_that_never_ends_is_stopped_at_the_step_limit():
    scenario = FakeScenario("slow", length=1e9, max_time_s=1.0)
    result, steps = drive(scenario, max_steps=5)
    assert result.terminal == "step_limit" and result.steps == 5


def test_every_draw_comes_from_the_pinned_streams():
    seen = []

    class Recorder(EchoModel):
        def generate_cot(self, obs, rng):
            seen.append(("cot", obs.step, obs.scenario_id, rng.bit_generator.state["state"]["state"]))
            return super().generate_cot(obs, rng)

        def decode_action(self, obs, cot, rng):
            seen.append(("action", obs.step, obs.scenario_id, rng.bit_generator.state["state"]["state"]))
            return super().decode_action(obs, cot, rng)

    drive(model=Recorder(), seed=7)
    assert seen
    for purpose, step, scope, state in seen:
        assert state == step_rng(7, step, purpose, scope).bit_generator.state["state"]["state"]


@given(st.integers(0, 2**31 - 1), st.integers(0, 10_000))
def test_scenarios_with_the_same_seed_draw_independently(seed, step):
    """Otherwise a sweep over scenarios would reuse one seed's draws in every scenario."""
    a = step_rng(seed, step, "cot", "P.1").random(4)
    b = step_rng(seed, step, "cot", "C.1").random(4)
    assert not (a == b).all()


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_same_seed_same_episode(seed):
    a, steps_a = drive(seed=seed)
    b, steps_b = drive(seed=seed)
    assert a == b
    assert [(s[1].text, s[2].to_json(), s[3]) for s in steps_a] == [(s[1].text, s[2].to_json(), s[3])
                                                                      for s in steps_b]


def test_different_seeds_differ():
    assert drive(seed=1)[0] != drive(seed=2)[0]


def test_policy_drives_and_its_extras_are_logged(tmp_path):
    def injected(model, obs, seed):
        own_cot, own_traj, _ = own_cot_policy(model, obs, seed)
        cot = model.splice_cot(obs, "stop now", step_rng(seed, obs.step, "condition", obs.scenario_id))
        traj = model.decode_action(obs, cot, step_rng(seed, obs.step, "action", obs.scenario_id))
        return cot, traj, {"shadow_v1": own_traj.forward_displacement(1.0), "own_text": own_cot.text}

    path = tmp_path / "ep.mcap"
    with EpisodeWriter(path, {"episode_id": "x", "model": {"name": "echo"}, "scenario": {"id": "road"},
                              "seed": 0}) as writer:
        result = run_episode(EchoModel(), LineSimulator(), SpeedController(), FakeScenario("road", max_time_s=2.0),
                             0, policy=injected, writer=writer)
        writer.finish(result.to_json())
    assert result.terminal == "timeout"  # the injected "stop" keeps the ego from completing the route
    episode = read_episode(path)
    assert all(s.cot["spliced"] and s.cot["text"] == "stop now" for s in episode.steps)
    assert all(s.extras["shadow_v1"] > 4 for s in episode.steps)
    assert all(s.extras["own_text"].startswith("the road is clear") for s in episode.steps)
    assert episode.result == result.to_json()


def test_models_can_log_internals_of_their_own_cot():
    class Introspective(EchoModel):
        def cot_extras(self, cot):
            return {"said_stop": cot.text.startswith("stop")}

    _, steps = drive(FakeScenario("car", length=40.0, car_at=30.0, max_time_s=6.0), model=Introspective())
    assert [s[4] for s in steps] == [{"said_stop": s[1].text.startswith("stop")} for s in steps]
    assert {s[4]["said_stop"] for s in steps} == {True, False}


def test_model_step_reproduces_a_closed_loop_step_from_its_log(tmp_path):
    path = tmp_path / "ep.mcap"
    with EpisodeWriter(path, {"episode_id": "x", "model": {"name": "echo"}, "scenario": {"id": "road"},
                              "seed": 4}) as writer:
        run_episode(EchoModel(), LineSimulator(), SpeedController(), FakeScenario("road"), 4, writer=writer)
        writer.finish({})
    model = EchoModel()
    model.reset(4)
    for record in read_episode(path).steps[::5]:
        obs = observation_from_step(record, scenario_id="road")  # the draws are scoped by scenario
        cot, traj, extras = model_step(model, obs, 4, model_name="echo")
        assert cot.text == record.cot.text
        assert traj == record.trajectory and extras == {}


@pytest.mark.parametrize(
    ("cot", "trajectory", "problem"),
    [
        ("stop", Trajectory(np.array([0.1]), np.zeros((1, 2))), "expected a CoT, got str"),
        (CoT(b"stop"), Trajectory(np.array([0.1]), np.zeros((1, 2))), "CoT text must be a str"),
        (CoT("x", slots={"a": 1}), Trajectory(np.array([0.1]), np.zeros((1, 2))), "slots must map"),
        (CoT("x"), [[0.0, 0.0]], "expected a Trajectory"),
        (CoT("x"), Trajectory(np.array([0.1, 0.2]), np.array([[0.0, np.nan], [1, 1]])), "NaN"),
        (CoT("x"), Trajectory(np.array([0.2, 0.1]), np.zeros((2, 2))), "strictly increasing"),
        (CoT("x"), Trajectory(np.array([0.1, 0.2]), np.zeros((3, 2))), "shape"),
        (CoT("x"), Trajectory(np.array(["a"]), np.zeros((1, 2))), "trajectory"),
    ],
)
def test_unusable_model_output_is_one_line_naming_model_and_step(cot, trajectory, problem):
    with pytest.raises(ModelOutputError, match=problem) as info:
        check_model_output(cot, trajectory, model_name="echo", step=12, where="P.1 seed 0")
    message = str(info.value)
    assert message.startswith("model 'echo' at step 12 of P.1 seed 0: ") and "\n" not in message


def test_nan_waypoint_fails_the_episode_at_its_step():
    with pytest.raises(EpisodeFailure) as info:
        drive(model=EchoModel(nan_at=[0, 6]))
    assert info.value.step == 6 and info.value.component == "model"
    assert str(info.value) == ("model 'echo' at step 6 of road seed 0: unusable trajectory: "
                               "contains NaN or infinite values")
    assert isinstance(info.value.__cause__, ModelOutputError)


def test_component_exceptions_say_who_failed_where_with_the_traceback_kept():
    with pytest.raises(EpisodeFailure) as info:
        drive(model=EchoModel(fail_at=[0, 3]))
    assert str(info.value) == ("model 'echo' step policy at step 3 of road seed 0 raised RuntimeError: "
                               "CUDA out of memory")
    assert "Traceback" in info.value.details and "decode_action" in info.value.details
    with pytest.raises(EpisodeFailure, match=r"simulator 'simulator' step at step 2 of road seed 0 raised "
                                             r"ValueError: physics diverged"):
        drive(sim=ExplodingSimulator(after=3))
    with pytest.raises(EpisodeFailure, match="simulator 'simulator' reset of road seed 0 raised RuntimeError"):
        drive(sim=LineSimulator(fail_reset_for="road"))


def test_controller_output_is_checked():
    class Broken(SpeedController):
        def control(self, trajectory, ego, dt):
            control = super().control(trajectory, ego, dt)
            return type(control)(float("nan"), 0.0, 0.0, control.v_des)

    with pytest.raises(EpisodeFailure, match="controller 'controller' control at step 0 .* non-finite"):
        run_episode(EchoModel(), LineSimulator(), Broken(), FakeScenario("road"), 0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 40), st.floats(-5, 200), st.sampled_from([(), ("car0",), ("a", "b")]),
                          st.sampled_from([(), ("red_light:tl0",)])), min_size=1, max_size=30),
       st.floats(0, 150), st.sampled_from(["timeout", "collision", "route_complete", "step_limit"]))
def test_episode_result_rules(steps, route_length, terminal):
    from vladrivebench._engine.runner import _Tally
    from vladrivebench.records import EgoState, GroundTruth, Observation

    tally = _Tally()
    for i, (speed, progress, collisions, violations) in enumerate(steps):
        gt = GroundTruth(step=i, time=i * 0.1, route_progress=progress, route_length=route_length,
                         collisions=collisions, violations=violations)
        tally.add(Observation(i, i * 0.1, np.zeros((1, 1, 3), np.uint8), EgoState(0, 0, 0, speed), "straight", gt))
    result = tally.result(terminal)
    assert result.steps == len(steps)
    assert result.mean_speed == pytest.approx(np.mean([s[0] for s in steps]))
    assert result.collisions == sum(len(s[2]) for s in steps) == len(result.collision_events)
    assert result.violations == sum(len(s[3]) for s in steps)
    assert 0.0 <= result.route_completion <= 1.0
    if terminal == "route_complete":
        assert result.route_completion == 1.0
    elif route_length > 0:
        assert result.route_completion == pytest.approx(min(1.0, max(0.0, steps[-1][1] / route_length)))
    assert result.duration == pytest.approx((len(steps) - 1) * 0.1)
    assert json.loads(json.dumps(result.to_json())) == result.to_json()
