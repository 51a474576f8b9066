"""Small fakes for the intervention tests: a one-dimensional road, a PI speed controller and a keyword VLA
whose action mixes its CoT's stated intent (weight ``alpha``) with a perception policy."""

from __future__ import annotations

import hashlib
import json

import numpy as np
from vladrivebench import hookimpl
from vladrivebench.records import Control, CoT, CoTFormat, EgoState, GroundTruth, Observation, Trajectory

CRUISE = 6.5


# -- fakes --------------------------------------------------------------------------------------------
class LineSim:
    """A one-dimensional road: the ego drives along x; the scenario's critical actor (if any) stands in
    the lane at its route position; collision when the ego's front reaches it."""

    dt = 0.1

    def __init__(self, length: float = 40.0):
        self.length = length

    def reset(self, scenario, seed):
        self.scenario, self.step_no = scenario, 0
        rng = np.random.default_rng(seed)
        self.x, self.v = 0.0, 4.0 + float(rng.uniform(0, 1.0))
        actor = scenario.actor(scenario.critical) if scenario.critical else None
        self.obstacle = actor.s - actor.length / 2 if actor else None
        self.route_length = min(self.length, scenario.road.approach_length)
        return self._obs(())

    def _obs(self, collisions):
        terminal = None
        if collisions:
            terminal = "collision"
        elif self.x >= self.route_length:
            terminal = "route_complete"
        elif self.step_no >= self.scenario.max_steps:
            terminal = "timeout"
        distance = None if self.obstacle is None else self.obstacle - (self.x + 2.35)
        gt = GroundTruth(step=self.step_no, time=self.step_no * self.dt, critical_id=self.scenario.critical,
                         critical_kind=self.scenario.critical_kind, distance_to_critical=distance,
                         blocking=self.obstacle is not None, route_progress=self.x,
                         route_length=self.route_length, collisions=tuple(collisions), terminal=terminal)
        return Observation(self.step_no, self.step_no * self.dt, np.zeros((2, 2, 3), np.uint8),
                           EgoState(self.x, 0.0, 0.0, self.v), "follow_lane", gt, self.scenario.id)

    def step(self, control):
        self.v = max(0.0, self.v + (3.0 * control.throttle - 8.0 * control.brake) * self.dt)
        self.x += self.v * self.dt
        self.step_no += 1
        hit = self.obstacle is not None and self.x + 2.35 >= self.obstacle
        return self._obs(("obstacle",) if hit else ())

    def close(self):
        pass


class SpeedController:
    """Desired speed over the first 0.5 s of the trajectory; PI on speed (the integral makes it stateful)."""

    def __init__(self):
        self.integral = 0.0

    def reset(self):
        self.integral = 0.0

    def control(self, trajectory, ego, dt):
        v_des = float(np.interp(0.5, np.r_[0, trajectory.times], np.r_[0, trajectory.xy[:, 0]])) / 0.5
        error = v_des - ego.speed
        self.integral += error * dt
        if v_des < 0.4 or ego.speed > 1.1 * v_des:
            return Control(0.0, 0.0, min(1.0, 0.2 + (ego.speed - v_des) / 3.0), v_des)
        return Control(float(np.clip(0.5 * error + 0.1 * self.integral, 0.0, 0.75)), 0.0, 0.0, v_des)


def intent_of(text: str) -> str:
    words = text.lower()
    if any(w in words for w in ("stop", "brake", "slow")):
        return "decelerate"
    if "accelerate" in words or "speed up" in words:
        return "accelerate"
    if any(w in words for w in ("maintain", "keep", "continue")):
        return "maintain"
    return "none"


class KeywordModel:
    """A fake VLA whose action mixes the CoT's stated intent (weight ``alpha``) with a perception policy.

    ``leak`` makes generation and splicing differ (a broken splice pipeline) by ``leak`` m/s.
    """

    def __init__(self, alpha: float = 1.0, cot_format: str = "sentence", leak: float = 0.0, noise: float = 0.05,
                 max_tokens: int = 400):
        self.alpha, self.leak, self.noise = alpha, leak, noise
        slots = ("scene", "objects", "decision") if cot_format == "qa" else ()
        self.cot_format = CoTFormat("slots" if slots else "sentence", slots, max_tokens)
        self.trajectory_spec = None

    def reset(self, seed):
        pass

    def count_tokens(self, text):
        return len(text.split())

    def _danger(self, obs):
        d = obs.ground_truth.distance_to_critical
        return d is not None and 0 < d < 25

    def generate_cot(self, obs, rng):
        flavour = ["Keep the lane and maintain speed.", "Continue and maintain the current speed."][rng.integers(2)]
        decision = "Stop for the obstacle in the lane because it is blocking the lane." if self._danger(obs) \
            else flavour
        if self.cot_format.is_slotted:
            slots = {"scene": "The scene depicts a road.", "objects": "None.", "decision": decision}
            return CoT(CoT.join_slots(slots), slots, state=self._state(slots, self.leak))
        return CoT(decision, state=self._state(decision, self.leak))

    def splice_cot(self, obs, text, rng):
        if self.cot_format.is_slotted:
            if not isinstance(text, dict):
                raise ValueError("needs slots")
            return CoT(CoT.join_slots(text), dict(text), state=self._state(text, 0.0), spliced=True)
        return CoT(text, state=self._state(text, 0.0), spliced=True)

    def _state(self, text, bias):
        decision = text["decision"] if isinstance(text, dict) else text
        return {"intent": intent_of(decision), "bias": bias}

    def state_digest(self, cot):
        return hashlib.sha256(json.dumps(cot.state, sort_keys=True).encode()).hexdigest()

    def decode_action(self, obs, cot, rng):
        v = obs.ego.speed
        v_cot = {"decelerate": 0.0, "accelerate": min(8.5, v + 2.0), "maintain": CRUISE, "none": v}[cot.state["intent"]]
        v_percept = 0.0 if self._danger(obs) else CRUISE
        target = max(0.0, self.alpha * v_cot + (1 - self.alpha) * v_percept + rng.normal(0, self.noise)
                     + cot.state["bias"])
        times = np.arange(1, 31) * 0.1
        speeds = np.clip(v + np.sign(target - v) * 3.0 * times, min(v, target), max(v, target))
        xs = np.cumsum(speeds * 0.1)
        return Trajectory(times, np.stack([xs, np.zeros_like(xs)], axis=1))


class Fakes:
    @hookimpl
    def register_models(self, register):
        register("keyword", KeywordModel)

    @hookimpl
    def register_simulators(self, register):
        register("line", LineSim)

    @hookimpl
    def register_controllers(self, register):
        register("speed", SpeedController)


def fake_registry(*extra):
    """The core's built-ins (scenario suite, conditions, metrics) and these fakes, nothing installed."""
    import importlib

    from vladrivebench import _builtins as builtins
    from vladrivebench._engine.registry import Registry

    return Registry([("core", builtins), ("fakes", importlib.import_module("intervention_fakes").Fakes()),
                     *extra], entry_points=False)


# -- the CLI in process, for the intervention command's tests ------------------------------------------------
def vdb(capsys, *args):
    """``vdb ARGS`` in this process: ``(exit status, stdout, stderr)``."""
    from vladrivebench._cli import main as cli

    code = cli.main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def one_line_error(code, err, *fragments):
    """Assert a user error: exit status 2 and one ``vdb: error:`` line holding every fragment."""
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdb: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
