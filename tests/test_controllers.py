"""The PID and MPC trajectory trackers, driven through the simulators' bicycle model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench import _builtins as builtins
from vladrivebench._builtins.controllers import (
    MAX_CURVATURE,
    MAX_SPEED,
    MPCController,
    PIDController,
    desired_speed,
)
from vladrivebench._engine.registry import Registry
from vladrivebench.errors import ModelOutputError
from vladrivebench.records import EgoState, Trajectory
from vladrivebench.world._bicycle import BRAKE_DECEL, DT, THROTTLE_ACCEL, apply_control

TIMES = DT * np.arange(1, 31)
CONTROLLERS = [PIDController, MPCController]


def line_trajectory(ego: EgoState, speed: float) -> Trajectory:
    """Waypoints along the world line y = 0 (heading east) at ``speed``, from the ego's projection on it."""
    points = [ego.to_ego_frame(ego.x + speed * t, 0.0) for t in TIMES]
    return Trajectory(TIMES.copy(), np.array(points))


def drive(controller, ego: EgoState, speed: float, steps: int) -> tuple[EgoState, list]:
    controls = []
    for _ in range(steps):
        control = controller.control(line_trajectory(ego, speed), ego, DT)
        controls.append(control)
        ego = apply_control(ego, control, DT)
    return ego, controls


def standing_trajectory() -> Trajectory:
    return Trajectory(TIMES.copy(), np.zeros((len(TIMES), 2)))


@st.composite
def trajectories(draw) -> Trajectory:
    """Arbitrary drivable-looking trajectories: speeds up to 15 m/s and headings that wander."""
    speeds = np.array(draw(st.lists(st.floats(0.0, 15.0), min_size=30, max_size=30)))
    turns = np.array(draw(st.lists(st.floats(-0.3, 0.3), min_size=30, max_size=30)))
    headings = np.cumsum(turns)
    steps = np.stack([np.cos(headings), np.sin(headings)], axis=1) * (speeds * DT)[:, None]
    offset = np.array([0.0, draw(st.floats(-2.0, 2.0))])
    return Trajectory(TIMES.copy(), np.cumsum(steps, axis=0) + offset)


egos = st.builds(EgoState, x=st.floats(-100, 100), y=st.floats(-100, 100), yaw=st.floats(-3.1, 3.1),
                 speed=st.floats(0.0, 8.5))


@pytest.mark.parametrize("make", CONTROLLERS)
@settings(max_examples=8, deadline=None)
@given(start_speed=st.floats(0.0, 8.0), target=st.floats(1.0, MAX_SPEED), offset=st.floats(-1.0, 1.0),
       yaw=st.floats(-0.2, 0.2))
def test_tracking_a_constant_speed_straight_trajectory_converges(make, start_speed, target, offset, yaw):
    ego, controls = drive(make(), EgoState(0.0, offset, yaw, start_speed), target, 250)
    assert ego.speed == pytest.approx(target, abs=0.05)
    assert abs(ego.y) < 0.05 and abs(ego.yaw) < 0.01
    assert controls[-1].v_des == pytest.approx(target, abs=0.05)


@pytest.mark.parametrize("make", CONTROLLERS)
@given(speed=st.floats(0.0, MAX_SPEED))
@settings(max_examples=25, deadline=None)
def test_a_stopping_trajectory_brakes_and_commands_a_stop(make, speed):
    ego = EgoState(0.0, 0.0, 0.0, speed)
    control = make().control(standing_trajectory(), ego, DT)
    assert control.v_des < 0.05
    assert control.throttle == 0.0
    assert control.brake > 0.0


@pytest.mark.parametrize("make", CONTROLLERS)
def test_a_decelerating_trajectory_brings_the_ego_to_a_stop(make):
    controller, ego = make(), EgoState(0.0, 0.0, 0.0, 6.5)
    for _ in range(80):
        remaining = max(20.0 - ego.x, 0.0)  # stop line 20 m ahead, replanned every step
        decel = max(ego.speed**2 / (2 * remaining), 0.5) if remaining > 0 else 8.0
        speeds = np.maximum(ego.speed - decel * TIMES, 0.0)
        xs = np.minimum(np.cumsum(speeds * DT), remaining)
        control = controller.control(Trajectory(TIMES.copy(), np.stack([xs, 0 * xs], 1)), ego, DT)
        ego = apply_control(ego, control, DT)
    assert ego.speed < 0.05
    assert ego.x == pytest.approx(20.0, abs=1.5)
    assert control.v_des < 0.05 and control.brake > 0.0


@pytest.mark.parametrize("make", CONTROLLERS)
def test_never_exceeds_the_speed_limit(make):
    ego, controls = drive(make(), EgoState(0.0, 0.0, 0.0, 0.0), 15.0, 120)
    assert max(c.v_des for c in controls) <= MAX_SPEED
    assert ego.speed <= MAX_SPEED + 1e-9
    assert ego.speed == pytest.approx(MAX_SPEED, abs=0.1)


@pytest.mark.parametrize("make", CONTROLLERS)
@given(trajectory=trajectories(), ego=egos)
@settings(max_examples=60, deadline=None)
def test_outputs_are_within_bounds(make, trajectory, ego):
    control = make().control(trajectory, ego, DT)
    values = (control.throttle, control.steer, control.brake, control.v_des)
    assert all(math.isfinite(v) for v in values)
    assert 0.0 <= control.throttle <= (0.75 if make is PIDController else 1.0)
    assert 0.0 <= control.brake <= 1.0
    assert -1.0 <= control.steer <= 1.0
    assert not (control.throttle > 0 and control.brake > 0)
    assert 0.0 <= control.v_des <= MAX_SPEED


@given(trajectory=trajectories(), ego=egos)
@settings(max_examples=60, deadline=None)
def test_mpc_next_state_respects_the_vehicle_limits(trajectory, ego):
    control = MPCController().control(trajectory, ego, DT)
    nxt = control.next_state
    assert nxt is not None
    assert 0.0 <= nxt.speed <= MAX_SPEED + 1e-9
    assert -BRAKE_DECEL * DT - 1e-9 <= nxt.speed - ego.speed <= THROTTLE_ACCEL * DT + 1e-9
    moved = math.hypot(nxt.x - ego.x, nxt.y - ego.y)
    assert moved <= max(ego.speed, nxt.speed) * DT + 1e-9
    turned = abs(math.remainder(nxt.yaw - ego.yaw, 2 * math.pi))
    # A circular arc of radius R ≥ 1/κmax turning by θ has the chord 2R sin(θ/2).
    assert moved >= 2.0 * math.sin(turned / 2.0) / MAX_CURVATURE - 1e-9
    assert (nxt.length, nxt.width) == (ego.length, ego.width)


@pytest.mark.parametrize("make", CONTROLLERS)
@given(trajectory_list=st.lists(trajectories(), min_size=2, max_size=5), ego=egos)
@settings(max_examples=15, deadline=None)
def test_same_calls_give_the_same_controls_and_reset_forgets(make, trajectory_list, ego):
    first, second = make(), make()
    a = [first.control(t, ego, DT) for t in trajectory_list]
    b = [second.control(t, ego, DT) for t in trajectory_list]
    assert a == b
    first.reset()
    assert first.control(trajectory_list[0], ego, DT) == a[0]


def test_pid_follows_a_curve():
    radius, controller, ego = 20.0, PIDController(), EgoState(0.0, 0.0, 0.0, 5.0)
    for _ in range(150):
        start = math.atan2(ego.y - radius, ego.x)
        points = [ego.to_ego_frame(radius * math.cos(start + 5.0 * t / radius),
                                   radius + radius * math.sin(start + 5.0 * t / radius)) for t in TIMES]
        ego = apply_control(ego, controller.control(Trajectory(TIMES.copy(), np.array(points)), ego, DT), DT)
    assert abs(math.hypot(ego.x, ego.y - radius) - radius) < 0.2


def test_desired_speed_reads_the_window():
    trajectory = Trajectory(TIMES.copy(), np.stack([4.0 * TIMES, 0 * TIMES], 1))
    assert desired_speed(trajectory, 0.5, 1.0) == pytest.approx(4.0)
    assert desired_speed(trajectory, 2.5, 9.0) == pytest.approx(4.0)  # clipped to the horizon


@pytest.mark.parametrize("make", CONTROLLERS)
def test_a_malformed_trajectory_is_a_one_line_model_error(make):
    bad = Trajectory(TIMES.copy(), np.full((30, 2), np.nan))
    with pytest.raises(ModelOutputError, match="cannot track") as info:
        make().control(bad, EgoState(0, 0, 0, 1.0), DT)
    assert "\n" not in str(info.value)


def test_controllers_are_registered_by_the_core_plugin():
    registry = Registry([("core", builtins)], entry_points=False)
    assert {"pid", "mpc"} <= set(registry.names("controller"))
    assert isinstance(registry.create("controller", "pid", {"aim_distance": 5.0}), PIDController)
    assert isinstance(registry.create("controller", "mpc", {"horizon_steps": 10}), MPCController)


def accelerating_trajectory(accel: float) -> Trajectory:
    """From the ego at rest, straight ahead at constant acceleration ``accel``."""
    return Trajectory(TIMES.copy(), np.stack([0.5 * accel * TIMES**2, np.zeros_like(TIMES)], axis=1))


@settings(max_examples=60, deadline=None)
@given(creep=st.floats(0.0, 0.2), speed=st.floats(0.0, 0.099), x=st.floats(-50, 50), yaw=st.floats(-3.1, 3.1))
def test_mpc_holds_a_standstill_against_a_creeping_plan(creep, speed, x, yaw):
    """A nearly stopped ego whose plan covers under 0.25 m in its first second stops at once and stays put."""
    controller, ego = MPCController(), EgoState(x, 1.0, yaw, speed)
    stopped_at = None
    for _ in range(20):
        creeping = Trajectory(TIMES.copy(), np.stack([creep * TIMES, np.zeros_like(TIMES)], axis=1))
        control = controller.control(creeping, ego, DT)
        assert control.brake == 1.0 and control.throttle == 0.0
        assert control.next_state.speed == 0.0
        ego = control.next_state
        stopped_at = stopped_at or (ego.x, ego.y)
        assert (ego.x, ego.y) == stopped_at


@settings(max_examples=30, deadline=None)
@given(accel=st.floats(0.6, 3.0))
def test_mpc_leaves_the_hold_for_a_plan_that_pulls_away(accel):
    ego = EgoState(0.0, 0.0, 0.0, 0.0)
    control = MPCController().control(accelerating_trajectory(accel), ego, DT)
    assert control.next_state.speed > 0.0 and control.throttle > 0.0


def test_mpc_without_the_hold_follows_a_creeping_plan():
    creeping = Trajectory(TIMES.copy(), np.stack([0.05 * TIMES, np.zeros_like(TIMES)], axis=1))
    ego = EgoState(0.0, 0.0, 0.0, 0.0)
    for _ in range(30):
        ego = MPCController(hold_speed=0.0).control(creeping, ego, DT).next_state
    assert ego.x > 0.0


@pytest.mark.parametrize("option", [{"hold_speed": -1.0}, {"start_distance": "far"}, {"start_window": 0.0}])
def test_mpc_rejects_bad_hold_options(option):
    with pytest.raises(ValueError, match=next(iter(option))):
        MPCController(**option)
