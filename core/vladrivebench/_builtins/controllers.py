"""Trajectory-tracking controllers: ego-frame waypoints → control for the next step, with ``v_des``.

Two styles, as in the paper's Appendix F:

- :class:`PIDController` — Bench2Drive-style: a desired speed read off the trajectory over a short window,
  a longitudinal PID on the speed error (throttle, or brake when the desired speed is a stop or well below
  the current speed) and a lateral PID on the heading to an aim point a few metres along the trajectory.
  The simulator integrates (throttle, steer, brake) through its bicycle model.
- :class:`MPCController` — AlpaSim-style: a receding-horizon optimisation of accelerations and path
  curvatures (box-bounded linear least squares) that tracks the trajectory's timed positions; it returns
  ``next_state``, the ego pose and speed after one step, and the simulator places the ego there.

``v_des`` is the desired speed commanded for the next step, which the action-alignment metric compares with
the current speed: for PID the desired speed it tracks, for MPC the trajectory's target speed over the next
step. Steering is positive to the left (counter-clockwise), like the world frame's yaw.
Both controllers are deterministic: the same calls in the same order give the same controls.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from vladrivebench.errors import ModelOutputError
from vladrivebench.records import Control, EgoState, Trajectory
from vladrivebench.world._bicycle import BRAKE_DECEL, MAX_WHEEL_ANGLE, THROTTLE_ACCEL, WHEELBASE, advance

MAX_SPEED = 8.5
"""The Bench2Drive speed limit (m/s) that every controller respects."""
STANDSTILL = 1e-3
"""A speed (m/s) below which the MPC plans a standstill."""
MAX_CURVATURE = math.tan(MAX_WHEEL_ANGLE) / WHEELBASE
"""The tightest path curvature (1/m) the vehicle can drive."""


def _option_number(name: str, value: object, *, low: float, high: float = math.inf,
                   low_open: bool = True) -> float:
    """``value`` as a float within (``low``, ``high``] (``[low, high]`` unless ``low_open``), or a ValueError
    naming the option and what it takes."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (value > low if low_open else value >= low) and value <= high
    if not ok:
        bracket = "(" if low_open else "["
        upper = "∞)" if high == math.inf else f"{high:g}]"
        raise ValueError(f"option {name!r} must be a number in {bracket}{low:g}, {upper}, got {value!r}")
    return float(value)


def _option_numbers(name: str, value: object, count: int, *, low: float = 0.0, low_open: bool = False,
                    increasing: bool = False) -> tuple[float, ...]:
    """``value`` as ``count`` numbers ≥ ``low`` (a list like ``[0.5, 1.0]``), or a ValueError naming it."""
    if not isinstance(value, (list, tuple)) or len(value) != count:
        raise ValueError(f"option {name!r} must be a list of {count} numbers (e.g. {name}=[0.5,1.0]), got {value!r}")
    numbers = tuple(_option_number(f"{name}[{i}]", v, low=low, low_open=low_open) for i, v in enumerate(value))
    if increasing and any(b <= a for a, b in zip(numbers, numbers[1:], strict=False)):
        raise ValueError(f"option {name!r} must be increasing (start < end), got {list(value)!r}")
    return numbers


# -- reading a trajectory -------------------------------------------------------------------------------
def _timed_path(trajectory: Trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times, points and cumulative arc length of the trajectory with the ego (origin, t = 0) prepended."""
    problem = trajectory.problems()
    if problem is not None:
        raise ModelOutputError(f"controller: cannot track the model's trajectory: {problem}")
    times = np.concatenate([[0.0], np.asarray(trajectory.times, dtype=float)])
    points = np.vstack([[0.0, 0.0], np.asarray(trajectory.xy, dtype=float)])
    steps = np.hypot(*np.diff(points, axis=0).T)
    return times, points, np.concatenate([[0.0], np.cumsum(steps)])


def arc_length_at(trajectory: Trajectory, t: float | np.ndarray) -> np.ndarray:
    """Distance along the trajectory (from the ego) reached at time(s) ``t``; constant past the horizon."""
    times, _, arc = _timed_path(trajectory)
    return np.interp(t, times, arc)


def desired_speed(trajectory: Trajectory, start_s: float, end_s: float) -> float:
    """The average speed the trajectory asks for between ``start_s`` and ``end_s`` seconds ahead."""
    times, _, arc = _timed_path(trajectory)
    return _window_speed(times, arc, start_s, end_s)


def point_along(trajectory: Trajectory, distance: float) -> np.ndarray | None:
    """The point ``distance`` metres along the trajectory (the last point if it is shorter); ``None`` if
    the trajectory does not move away from the ego."""
    _, points, arc = _timed_path(trajectory)
    return _point_at(points, arc, distance)


def _window_speed(times: np.ndarray, arc: np.ndarray, start_s: float, end_s: float) -> float:
    end = min(end_s, float(times[-1]))
    start = max(min(start_s, end - 1e-6), 0.0) if end > 0 else 0.0
    if end <= start:
        return 0.0
    covered = float(np.interp(end, times, arc) - np.interp(start, times, arc))
    return max(covered, 0.0) / (end - start)


def _point_at(points: np.ndarray, arc: np.ndarray, distance: float) -> np.ndarray | None:
    if arc[-1] <= 1e-6:
        return None
    d = min(distance, float(arc[-1]))
    return np.array([np.interp(d, arc, points[:, 0]), np.interp(d, arc, points[:, 1])])


# -- PID ----------------------------------------------------------------------------------------------
class PID:
    """A discrete PID with a windowed integral (the mean of the last ``window`` errors, which bounds
    wind-up as Bench2Drive's controller does)."""

    def __init__(self, kp: float, ki: float, kd: float, window: int = 40):
        self.kp, self.ki, self.kd = kp, ki, kd
        self._errors: deque[float] = deque(maxlen=window)

    def reset(self) -> None:
        self._errors.clear()

    def step(self, error: float, dt: float) -> float:
        previous = self._errors[-1] if self._errors else error
        self._errors.append(error)
        integral = sum(self._errors) / len(self._errors)
        derivative = (error - previous) / dt
        return self.kp * error + self.ki * integral + self.kd * derivative


class PIDController:
    """Bench2Drive-style trajectory tracker.

    The desired speed is the average speed the trajectory asks for over ``speed_window`` (seconds ahead,
    default 0.5–1.0 s), capped at ``max_speed``; it is ``v_des``. Throttle comes from a PID on the speed
    error, clipped to ``max_throttle``. The controller brakes instead when the desired speed is below
    ``stop_speed`` or the ego is more than ``overspeed_ratio`` over it, in proportion to the speed it
    must shed over ``brake_time`` seconds (default: the middle of the speed window; full brake to hold a
    standstill). Throttle never takes the ego past ``max_speed`` within a step. Steering is a PID on the
    heading (rad) of the point ``aim_distance`` metres along the trajectory, clipped to [−1, 1].
    """

    def __init__(self, *, speed_window: tuple[float, float] = (0.5, 1.0), max_speed: float = MAX_SPEED,
                 max_throttle: float = 0.75, stop_speed: float = 0.4, overspeed_ratio: float = 1.1,
                 brake_time: float | None = None, aim_distance: float = 4.0,
                 speed_gains: tuple[float, float, float] = (0.6, 0.05, 0.0),
                 steer_gains: tuple[float, float, float] = (2.0, 0.1, 0.05)):
        self.speed_window = _option_numbers("speed_window", speed_window, 2, increasing=True)
        self.max_speed = _option_number("max_speed", max_speed, low=0.0, high=60.0)
        self.max_throttle = _option_number("max_throttle", max_throttle, low=0.0, high=1.0)
        self.stop_speed = _option_number("stop_speed", stop_speed, low=0.0, low_open=False)
        self.overspeed_ratio = _option_number("overspeed_ratio", overspeed_ratio, low=1.0, low_open=False)
        # By default the excess speed is shed by the middle of the window the desired speed is read from.
        self.brake_time = (_option_number("brake_time", brake_time, low=0.0) if brake_time is not None
                           else 0.5 * sum(self.speed_window))
        self.aim_distance = _option_number("aim_distance", aim_distance, low=0.0)
        self._speed_pid = PID(*_option_numbers("speed_gains", speed_gains, 3))
        self._steer_pid = PID(*_option_numbers("steer_gains", steer_gains, 3))

    def reset(self) -> None:
        self._speed_pid.reset()
        self._steer_pid.reset()

    def control(self, trajectory: Trajectory, ego: EgoState, dt: float) -> Control:
        times, points, arc = _timed_path(trajectory)
        v_des = min(_window_speed(times, arc, *self.speed_window), self.max_speed)
        throttle, brake = self._longitudinal(v_des, ego.speed, dt)
        steer = self._lateral(points, arc, dt)
        return Control(throttle=throttle, steer=steer, brake=brake, v_des=v_des)

    def _longitudinal(self, v_des: float, speed: float, dt: float) -> tuple[float, float]:
        stopping = v_des < self.stop_speed
        if stopping or speed > self.overspeed_ratio * v_des:
            self._speed_pid.reset()
            if stopping and speed < self.stop_speed:
                return 0.0, 1.0  # hold the standstill
            excess = speed - v_des
            brake = excess / (BRAKE_DECEL * self.brake_time)
            return 0.0, float(np.clip(brake, 0.05, 1.0))
        command = self._speed_pid.step(v_des - speed, dt)
        if command >= 0.0:
            headroom = max(self.max_speed - speed, 0.0) / (THROTTLE_ACCEL * dt)
            return float(min(command, self.max_throttle, headroom)), 0.0
        # A small overspeed inside the tolerance band: shed it with the same deceleration the PID asks
        # for (the vehicle model has no drag, so coasting would keep the excess forever).
        return 0.0, float(min(-command * THROTTLE_ACCEL / BRAKE_DECEL, 1.0))

    def _lateral(self, points: np.ndarray, arc: np.ndarray, dt: float) -> float:
        aim = _point_at(points, arc, self.aim_distance)
        heading = 0.0 if aim is None or np.hypot(*aim) < 0.5 else math.atan2(aim[1], aim[0])
        return float(np.clip(self._steer_pid.step(heading, dt), -1.0, 1.0))


# -- MPC ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MPCWeights:
    """Least-squares weights of the MPC's tracking costs."""

    position: float = 1.0
    speed: float = 0.5
    accel: float = 0.02
    jerk: float = 0.2
    lateral: float = 1.0
    heading: float = 2.0
    curvature: float = 0.5
    curvature_rate: float = 5.0


class MPCController:
    """AlpaSim-style model-predictive tracker that moves the ego itself (``next_state``).

    Over ``horizon_steps`` steps it chooses accelerations within [−``max_decel``, ``max_accel``] that track
    the trajectory's timed arc lengths and speeds, then path curvatures within ±``max_curvature`` that
    track its lateral position and heading (a linearisation about the trajectory's path). The first step
    of the plan is applied exactly to the ego's pose: ``next_state`` is where the ego is after ``dt``,
    never faster than ``max_speed`` nor reversing. ``v_des`` is the trajectory's target speed over the next
    step (its arc length at ``dt`` divided by ``dt``), capped at ``max_speed``. ``throttle``/``brake``/``steer``
    report the same plan in the vehicle model's units, for logs.

    Standstill hold (like a production longitudinal controller's stopped state): when the ego is slower
    than ``hold_speed`` and the trajectory covers less than ``start_distance`` metres in its first
    ``start_window`` seconds, the ego stops and stays, brake applied. A plan that creeps at millimetres a
    second (a learnt planner rarely outputs an exact zero) then holds instead of inching into what it stopped
    for; a plan that pulls away (e.g. 0.5 m/s² from rest covers 0.25 m in a second) leaves the hold.
    ``hold_speed=0`` turns the hold off.
    """

    def __init__(self, *, horizon_steps: int = 20, max_accel: float = THROTTLE_ACCEL,
                 max_decel: float = BRAKE_DECEL, max_curvature: float = MAX_CURVATURE,
                 max_speed: float = MAX_SPEED, min_preview: float = 8.0, weights: MPCWeights | None = None,
                 hold_speed: float = 0.1, start_distance: float = 0.25, start_window: float = 1.0):
        if isinstance(horizon_steps, bool) or not isinstance(horizon_steps, int) or not 1 <= horizon_steps <= 1000:
            raise ValueError(f"option 'horizon_steps' must be a whole number from 1 to 1000, got {horizon_steps!r}")
        self.horizon_steps = int(horizon_steps)
        self.max_accel = _option_number("max_accel", max_accel, low=0.0)
        self.max_decel = _option_number("max_decel", max_decel, low=0.0)
        self.max_curvature = _option_number("max_curvature", max_curvature, low=0.0)
        self.max_speed = _option_number("max_speed", max_speed, low=0.0, high=60.0)
        min_preview = _option_number("min_preview", min_preview, low=0.0, low_open=False)
        self.weights = weights or MPCWeights()
        self.min_preview = min_preview
        self.hold_speed = _option_number("hold_speed", hold_speed, low=0.0, low_open=False)
        self.start_distance = _option_number("start_distance", start_distance, low=0.0, low_open=False)
        self.start_window = _option_number("start_window", start_window, low=0.0)
        self._last_accel = 0.0
        self._last_curvature = 0.0

    def reset(self) -> None:
        self._last_accel = 0.0
        self._last_curvature = 0.0

    def control(self, trajectory: Trajectory, ego: EgoState, dt: float) -> Control:
        times, points, _ = _timed_path(trajectory)
        path = _reference_path(points[1:])
        # Progress along the path, so a lateral offset between the ego and the path is not read as speed.
        progress = np.zeros(len(times)) if path is None else np.concatenate([[0.0], path.progress])
        steps = max(1, min(self.horizon_steps, int(math.floor(times[-1] / dt + 1e-9))))
        t = dt * np.arange(1, steps + 1)
        s_ref = np.maximum(np.interp(t, times, progress), 0.0)
        v_ref = np.diff(np.concatenate([[0.0], s_ref])) / dt
        v_des = float(min(v_ref[0], self.max_speed))

        accel = self._plan_accelerations(ego.speed, s_ref, np.minimum(v_ref, self.max_speed), dt)
        speed1 = float(np.clip(ego.speed + accel * dt, 0.0, self.max_speed))
        if speed1 < STANDSTILL or self._holds(ego.speed, times, progress):
            speed1 = 0.0
        accel = (speed1 - ego.speed) / dt
        travelled = 0.5 * (ego.speed + speed1) * dt

        curvature = 0.0 if path is None else self._plan_curvature(path, s_ref, travelled)
        self._last_accel, self._last_curvature = accel, curvature
        throttle = float(np.clip(accel / THROTTLE_ACCEL, 0.0, 1.0))
        brake = float(np.clip(-accel / BRAKE_DECEL, 0.0, 1.0))
        if speed1 == 0.0:
            throttle, brake = 0.0, 1.0  # stopping or standing: hold the standstill
        steer = float(np.clip(math.atan(curvature * WHEELBASE) / MAX_WHEEL_ANGLE, -1.0, 1.0))
        # The first step of the plan, driven through the simulators' own vehicle model.
        next_state = advance(ego, throttle, steer, brake, dt)
        return Control(throttle=throttle, steer=steer, brake=brake, v_des=max(v_des, 0.0),
                       next_state=next_state)

    def _holds(self, speed: float, times: np.ndarray, progress: np.ndarray) -> bool:
        """Whether the standstill hold applies: the ego nearly stopped and the plan not pulling away."""
        if speed >= self.hold_speed:
            return False
        return float(np.interp(self.start_window, times, progress)) < self.start_distance

    def _plan_accelerations(self, v0: float, s_ref: np.ndarray, v_ref: np.ndarray, dt: float) -> float:
        """First acceleration of the plan minimising position, speed, effort and jerk errors."""
        n, w = len(s_ref), self.weights
        matrix = self._acceleration_matrix(n, dt)
        t = dt * (np.arange(n) + 1)
        jerk_target = np.zeros(n)
        jerk_target[0] = self._last_accel
        target = np.concatenate([
            math.sqrt(w.position) * (s_ref - v0 * t),
            math.sqrt(w.speed) * (v_ref - v0),
            np.zeros(n),
            math.sqrt(w.jerk) * jerk_target,
        ])
        return float(bounded_least_squares(matrix, target, -self.max_decel, self.max_accel)[0])

    def _acceleration_matrix(self, n: int, dt: float) -> np.ndarray:
        """The weighted rows of the acceleration plan over ``n`` steps of ``dt`` (the same for every call with
        these: built once)."""
        key = (n, dt, self.weights)
        if getattr(self, "_matrix_key", None) != key:
            w = self.weights
            k = np.arange(n)
            # v_{k+1} = v0 + dt Σ_{j≤k} a_j ;  s_{k+1} = v0 t_{k+1} + dt² Σ_{j≤k} (k − j + ½) a_j
            lower = (k[:, None] >= k[None, :]).astype(float)
            speed_rows = dt * lower
            position_rows = dt * dt * np.where(lower > 0, k[:, None] - k[None, :] + 0.5, 0.0)
            jerk_rows = np.eye(n) - np.eye(n, k=-1)
            matrix = np.vstack([
                math.sqrt(w.position) * position_rows,
                math.sqrt(w.speed) * speed_rows,
                math.sqrt(w.accel) * np.eye(n),
                math.sqrt(w.jerk) * jerk_rows,
            ])
            matrix.flags.writeable = False
            self._matrix_key, self._matrix = key, matrix
        return self._matrix

    def _curvature_constants(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_curvature_constants_of` for ``n`` steps and these weights (built once per ``n``)."""
        key = (n, self.weights)
        if getattr(self, "_curvature_key", None) != key:
            self._curvature_key, self._curvature_parts = key, _curvature_constants_of(n, self.weights)
        return self._curvature_parts

    def _plan_curvature(self, path: ReferencePath, s_ref: np.ndarray, travelled: float) -> float:
        """First curvature of the plan tracking the path's lateral position and heading."""
        # Distance covered per step: the first as planned, then at the trajectory's pace, but always
        # previewing at least `min_preview` metres so a slow ego still converges smoothly.
        step_len = np.maximum(np.diff(np.concatenate([[0.0], s_ref])), self.min_preview / len(s_ref))
        step_len[0] = travelled
        s_at = path.s0 + np.concatenate([[0.0], np.cumsum(step_len)])[:-1]
        kappa_ref = np.clip(np.interp(s_at, path.vertex_s, path.vertex_kappa), -self.max_curvature,
                            self.max_curvature)
        lateral0, heading0 = path.lateral0, path.heading0
        n, w = len(step_len), self.weights
        # Errors relative to the path (e_y: ego left of it, e_ψ: ego heading minus path heading):
        # e_ψ_{k+1} = e_ψ0 + Σ_{j≤k} Δs_j (κ_j − κref_j) ;  e_y_{k+1} = e_y0 + Σ_{i≤k} Δs_i e_ψ_i
        lower, effort_rows = self._curvature_constants(n)
        heading_rows = lower * step_len[None, :]
        heading_offset = heading0 - heading_rows @ kappa_ref
        # e_ψ before step i (i = 0..n-1): heading0 for i = 0, else row i-1.
        before = np.vstack([np.zeros((1, n)), heading_rows[:-1]])
        before_offset = np.concatenate([[heading0], heading_offset[:-1]])
        lateral_rows = heading_rows @ before
        lateral_offset = lateral0 + heading_rows @ before_offset
        rate_target = np.zeros(n)
        rate_target[0] = self._last_curvature
        matrix = np.vstack([
            math.sqrt(w.heading) * heading_rows,
            math.sqrt(w.lateral) * lateral_rows,
            effort_rows,
        ])
        target = np.concatenate([
            -math.sqrt(w.heading) * heading_offset,
            -math.sqrt(w.lateral) * lateral_offset,
            math.sqrt(w.curvature) * kappa_ref,
            math.sqrt(w.curvature_rate) * rate_target,
        ])
        bound = self.max_curvature
        return float(np.clip(bounded_least_squares(matrix, target, -bound, bound)[0], -bound, bound))


def _curvature_constants_of(n: int, weights: MPCWeights) -> tuple[np.ndarray, np.ndarray]:
    """The parts of the curvature plan over ``n`` steps that do not change from call to call: the
    lower-triangular ones of the running sums, and the weighted curvature and curvature-rate rows."""
    lower = (np.arange(n)[:, None] >= np.arange(n)[None, :]).astype(float)
    rate_rows = np.eye(n) - np.eye(n, k=-1)
    effort_rows = np.vstack([math.sqrt(weights.curvature) * np.eye(n), math.sqrt(weights.curvature_rate) * rate_rows])
    for array in (lower, effort_rows):
        array.flags.writeable = False
    return lower, effort_rows


def bounded_least_squares(matrix: np.ndarray, target: np.ndarray, lower: float, upper: float) -> np.ndarray:
    """``argmin ‖matrix·x − target‖`` with every ``x`` in [lower, upper].

    The unconstrained solution is tried first because it is usually feasible while tracking and is far
    cheaper; only when it leaves the box is the bounded problem solved (scipy's BVLS, deterministic).
    """
    x = np.linalg.lstsq(matrix, target, rcond=None)[0]
    if np.all(x >= lower) and np.all(x <= upper):
        return x
    from scipy.optimize import lsq_linear

    return lsq_linear(matrix, target, bounds=(lower, upper), method="bvls").x


@dataclass(frozen=True)
class ReferencePath:
    """The waypoints' path seen from the ego.

    The path is the polyline through the distinct waypoints, extended backwards along its first segment
    so that the ego (the origin) projects onto it: ``s0`` is the arc length of that projection,
    ``lateral0`` the ego's offset (positive when the ego is left of the path), ``heading0`` the ego's
    heading minus the path's there, ``vertex_kappa`` the curvature at the arc lengths ``vertex_s``, and
    ``progress`` each waypoint's arc length ahead of the ego's projection.
    """

    s0: float
    lateral0: float
    heading0: float
    vertex_s: np.ndarray
    vertex_kappa: np.ndarray
    progress: np.ndarray


def _reference_path(waypoints: np.ndarray) -> ReferencePath | None:
    """The :class:`ReferencePath` of ``waypoints``; ``None`` when they do not leave the ego."""
    keep = np.concatenate([[True], np.hypot(*np.diff(waypoints, axis=0).T) > 1e-3])
    pts = waypoints[keep]
    vertex_of = np.cumsum(keep)  # index in the extended polyline of each waypoint's vertex
    if len(pts) == 1:
        if math.hypot(*pts[0]) < 0.5:
            return None
        pts = np.vstack([[0.0, 0.0], pts])  # a lone target point: the line from the ego to it
        vertex_of = vertex_of + 1
    first = pts[1] - pts[0]
    pts = np.vstack([pts[0] - 50.0 * first / np.hypot(*first), pts])
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    along = np.clip(np.einsum("ij,ij->i", -pts[:-1], seg) / lengths**2, 0.0, 1.0)
    nearest = pts[:-1] + along[:, None] * seg
    i = int(np.argmin(np.hypot(nearest[:, 0], nearest[:, 1])))
    headings = np.arctan2(seg[:, 1], seg[:, 0])
    lateral0 = float(seg[i, 0] * -nearest[i, 1] - seg[i, 1] * -nearest[i, 0]) / lengths[i]
    heading0 = float(np.angle(np.exp(-1j * headings[i])))
    turn = np.angle(np.exp(1j * np.diff(headings)))
    kappa = turn / (0.5 * (lengths[:-1] + lengths[1:]))
    s0 = float(arc[i] + along[i] * lengths[i])
    return ReferencePath(s0, lateral0, heading0, arc[1:-1], kappa, arc[vertex_of] - s0)
