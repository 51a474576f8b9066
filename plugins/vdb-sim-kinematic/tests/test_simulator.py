"""The kinematic simulator: protocol, determinism, calibrated scenarios, collisions, violations, options."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from kinematic_driving import drive, run
from vdb_sim_kinematic import plugin
from vdb_sim_kinematic.simulator import KinematicSimulator
from vladrivebench import ConfigError, Control, EgoState, ScenarioError, Simulator
from vladrivebench.testing import Registry, core_plugin
from vladrivebench.world import Box, load_suite, parse_scenario

BRAKE = Control(0.0, 0.0, 1.0, 0.0)


@pytest.fixture(scope="module")
def suite():
    return load_suite(Registry(plugins=[core_plugin()], entry_points=False))


@pytest.fixture(scope="module")
def fast():
    return KinematicSimulator(render=False)


def custom(actors=(), **extra):
    data = {"id": "K.1", "title": "t", "family": "intervention", "group": "g", "layout": "straight",
            "command": "follow_lane", "max_time_s": 20.0, "road": {"approach_length": 100.0},
            "actors": list(actors), **extra}
    return parse_scenario(data, "custom.toml")


# -- registration and options ---------------------------------------------------------------------


def test_registers_simulator_kinematic_with_its_options():
    registry = Registry(plugins=[("kinematic", plugin)], entry_points=False)
    assert registry.names("simulator") == ["kinematic"]
    sim = registry.create("simulator", "kinematic", {"width": 64, "height": 32, "render": True})
    assert isinstance(sim, Simulator) and sim.dt == 0.1
    with pytest.raises(ConfigError, match="does not take option 'colour'"):
        registry.create("simulator", "kinematic", {"colour": 1})


@pytest.mark.parametrize("options,needle", [
    ({"width": 4}, "option width must be a whole number between 8 and 4096, got 4"),
    ({"height": "tall"}, "option height must be a whole number"),
    ({"render": "yes"}, "option render must be true or false"),
    ({"hfov_deg": 200}, "option hfov_deg must be a number between 10 and 170"),
    ({"position_jitter": -1}, "option position_jitter must be a number between 0 and 2"),
])
def test_bad_options_are_one_line_config_errors(options, needle):
    with pytest.raises(ConfigError) as info:
        plugin.make_simulator(**options)
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_registration_imports_neither_the_simulator_nor_heavy_libraries():
    probe = ("import sys, vdb_sim_kinematic.plugin as p; from vladrivebench._engine.registry import Registry; "
             "Registry(plugins=[('k', p)], entry_points=False); "
             "print(sorted(m for m in ('vdb_sim_kinematic.simulator', 'torch', 'transformers', 'libsumo') "
             "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_a_feature_the_simulator_cannot_represent_is_a_scenario_error(fast):
    scenario = custom(requires=["weather:rain"])
    with pytest.raises(ScenarioError) as info:
        fast.reset(scenario, 0)
    message = str(info.value)
    assert message.startswith("scenario custom.toml: simulator 'kinematic' cannot represent 'weather:rain'")
    assert "\n" not in message


# -- observations ---------------------------------------------------------------------------------


def test_observation_fields(suite):
    sim = KinematicSimulator(width=96, height=48)
    obs = sim.reset(suite["TL.1-red"], 0)
    assert obs.step == 0 and obs.time == 0.0 and obs.scenario_id == "TL.1-red"
    assert obs.image.shape == (48, 96, 3) and obs.image.dtype == np.uint8
    assert obs.command == "straight"
    gt = obs.ground_truth
    assert gt.critical_id == "tl0" and gt.critical_kind == "traffic_light" and gt.light_state == "red"
    assert gt.distance_to_critical == pytest.approx(100.0)  # 20 m run-up + D = 80 m
    assert len(gt.route_ahead) == 50 and gt.route_length > 100.0
    obs = sim.step(drive(obs))
    assert obs.step == 1 and obs.time == pytest.approx(0.1)


def test_render_false_gives_a_blank_image_of_the_requested_size(suite):
    sim = KinematicSimulator(width=40, height=20, render=False)
    obs = sim.reset(suite["C.1"], 0)
    assert obs.image.shape == (20, 40, 3) and not obs.image.any()


@pytest.mark.parametrize("sid,distance", [("P.1", 70.0), ("P.2", 70.0), ("C.1", 80.0), ("TL.3-green", 100.0),
                                          ("S.2", 70.0), ("SAFE.car", 70.0)])
def test_initial_distance_is_run_up_plus_d(fast, suite, sid, distance):
    assert fast.reset(suite[sid], 0).ground_truth.distance_to_critical == pytest.approx(distance, abs=0.21)


def test_every_suite_scenario_runs(suite):
    sim = KinematicSimulator(width=32, height=16)
    for scenario in suite.values():
        obs = sim.reset(scenario, 1)
        for _ in range(5):
            obs = sim.step(drive(obs))
        assert obs.ground_truth.route_progress > 0.0


# -- determinism ----------------------------------------------------------------------------------


def test_same_scenario_and_seed_give_identical_episodes(suite):
    def episode():
        sim = KinematicSimulator(width=64, height=32)
        frames = run(sim, suite["P.4"], seed=7)
        return b"".join(f.image.tobytes() for f in frames), [f.ground_truth for f in frames]

    first, second = episode(), episode()
    assert first[0] == second[0]
    assert first[1] == second[1]


def test_seeds_only_jitter_pedestrian_starts_within_the_bound(fast, suite):
    starts = []
    for seed in range(6):
        actor = fast.reset(suite["P.1"], seed).ground_truth.actor("ped0")
        starts.append(actor.x)
    assert len(set(starts)) == 6 and max(starts) - min(starts) <= 0.4
    assert all(abs(x - 72.65) <= 0.2 for x in starts)
    cars = {fast.reset(suite["C.1"], seed).ground_truth.actor("car0").x for seed in range(4)}
    assert len(cars) == 1
    still = KinematicSimulator(render=False, position_jitter=0.0)
    assert {still.reset(suite["P.1"], seed).ground_truth.actor("ped0").x for seed in range(4)} == {72.65}


# -- calibrated crossing scenarios ------------------------------------------------------------------


def arrival(frames):
    """The frame where the ego's front reaches the crossing line."""
    return next(f for f in frames if f.ground_truth.distance_to_critical <= 0.5)


@pytest.mark.parametrize("sid,collides", [("P.2", True), ("P.3", False), ("P.4", True), ("P.5", False)])
def test_crossing_pedestrians_are_in_the_path_or_have_cleared_it_at_cruise(fast, suite, sid, collides):
    for seed in (0, 1, 2):
        frames = run(fast, suite[sid], seed=seed)
        terminal = frames[-1].ground_truth
        assert (terminal.terminal == "collision") is collides
        if collides:
            assert terminal.collisions == ("ped0",)
        else:
            assert terminal.terminal == "route_complete"
        assert arrival(frames).ground_truth.blocking is collides
        # It did cross the ego's lane in every case: blocking at some point while still ahead.
        assert any(f.ground_truth.blocking for f in frames)


def test_in_lane_pedestrians_block_until_passed(fast, suite):
    for sid in ("P.1", "P.6", "P.7"):
        frames = run(fast, suite[sid], stop_before=4.0)
        assert frames[-1].ground_truth.terminal == "timeout", sid
        assert all(f.ground_truth.blocking for f in frames)
        assert not any(f.ground_truth.collisions for f in frames)


def test_stopped_car_in_adjacent_lane_never_blocks(fast, suite):
    frames = run(fast, suite["C.2"])
    assert frames[-1].ground_truth.terminal == "route_complete"
    assert not any(f.ground_truth.blocking for f in frames)
    assert all(f.ground_truth.lead_gap is None for f in frames)


def test_a_pedestrian_waits_instead_of_walking_into_a_stopped_ego(fast):
    walker = {"id": "ped0", "kind": "pedestrian", "s": 12.0, "motion": "along", "speed": 1.5,
              "direction": "opposite"}
    obs = fast.reset(custom([walker], critical="ped0"), 0)
    while obs.ground_truth.terminal is None:
        obs = fast.step(BRAKE)
    gt = obs.ground_truth
    assert gt.terminal == "timeout" and not gt.collisions
    assert 0.0 <= gt.lead_gap < 0.2 and gt.actor("ped0").speed == 0.0


def test_driving_into_a_standing_pedestrian_is_a_collision_that_ends_the_episode(fast, suite):
    frames = run(fast, suite["SAFE.centre-ped"])
    last = frames[-1]
    assert last.ground_truth.terminal == "collision" and last.ground_truth.collisions == ("ped0",)
    assert all(f.ground_truth.terminal is None for f in frames[:-1])
    with pytest.raises(RuntimeError, match="the episode has ended"):
        fast.step(BRAKE)


def test_kerbside_pedestrian_is_hit_by_an_ego_keeping_its_lane(fast, suite):
    frames = run(fast, suite["SAFE.kerb-ped"])
    assert frames[-1].ground_truth.terminal == "collision"


# -- violations -------------------------------------------------------------------------------------


def violations(frames):
    return [v for f in frames for v in f.ground_truth.violations]


def test_running_a_red_light_is_recorded_and_stopping_is_not(fast, suite):
    assert violations(run(fast, suite["TL.1-red"])) == ["red_light:tl0"]
    stopped = run(fast, suite["TL.1-red"], stop_before=1.0)
    assert violations(stopped) == [] and stopped[-1].ground_truth.terminal == "timeout"
    assert stopped[-1].ego.speed < 0.05 and 0.0 < stopped[-1].ground_truth.distance_to_critical < 2.0
    assert violations(run(fast, suite["TL.1-green"])) == []


def test_stop_sign_needs_a_stop_within_five_metres(fast, suite):
    assert violations(run(fast, suite["S.1"])) == ["stop_sign:stop0"]
    sim, scenario = fast, suite["S.1"]
    obs = sim.reset(scenario, 0)
    stopped_for = 0
    while obs.ground_truth.terminal is None:
        if stopped_for < 10:
            control = drive(obs, stop_before=1.0)
            stopped_for += obs.ego.speed < 0.05 and obs.ground_truth.distance_to_critical < 3.0
        else:
            control = drive(obs)
        obs = sim.step(control)
        assert not obs.ground_truth.violations
    assert obs.ground_truth.terminal == "route_complete"


# -- routes and control -----------------------------------------------------------------------------


@pytest.mark.parametrize("sid", ["TL.2-green", "TL.3-green", "S.3", "E.2"])
def test_junction_routes_can_be_driven_on_the_road(fast, suite, sid):
    frames = run(fast, suite[sid], speed=5.0)
    assert frames[-1].ground_truth.terminal == "route_complete"
    road = fast.road
    for f in frames[::5]:
        corners = Box.of_ego(f.ego).corners()
        assert np.all(road.road_offset(corners[:, 0], corners[:, 1]) <= 0.3), (sid, f.step)
    start, end = frames[0].ego.yaw, frames[-1].ego.yaw
    turn = math.degrees(math.remainder(end - start, 2 * math.pi))
    expected = {"straight": 0, "left": 90, "right": -90}[suite[sid].command]
    assert turn == pytest.approx(expected, abs=5)


def test_next_state_places_the_ego(fast, suite):
    obs = fast.reset(suite["BASE"], 0)
    target = EgoState(obs.ego.x + 0.7, obs.ego.y, 0.0, 7.0)
    obs = fast.step(Control(0.0, 0.0, 0.0, 7.0, next_state=target))
    assert (obs.ego.x, obs.ego.speed) == (target.x, 7.0)


def test_episode_lengths_and_timeout(fast, suite):
    frames = run(fast, suite["BASE"])
    assert frames[-1].ground_truth.terminal == "route_complete"
    assert frames[-1].ground_truth.route_progress == pytest.approx(frames[-1].ground_truth.route_length)
    obs = fast.reset(suite["BASE"], 0)
    steps = 0
    while obs.ground_truth.terminal is None:
        obs = fast.step(BRAKE)
        steps += 1
    assert steps == suite["BASE"].max_steps == 300 and obs.ground_truth.terminal == "timeout"


def test_distance_to_a_crossing_pedestrian_uses_its_jittered_crossing_line(fast, suite):
    for seed in range(3):
        obs = fast.reset(suite["P.2"], seed)
        walker = obs.ground_truth.actor("ped0")
        front = obs.ego.x + obs.ego.length / 2
        assert obs.ground_truth.distance_to_critical == pytest.approx(walker.x - front, abs=1e-9)
