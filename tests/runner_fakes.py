"""Small fake components for the runner, log, executor and CLI tests (a plugin module).

Importable by name (tests/conftest.py puts this folder on ``sys.path``) so that spawned worker processes can
rebuild the same registry. The fakes are real enough to drive closed-loop episodes: a 1-D road with an
optional stopped car, a model whose action follows its own CoT, a proportional speed controller.
"""

from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass

import numpy as np
import vladrivebench
from vladrivebench._engine.rng import episode_rng
from vladrivebench.errors import ConfigError
from vladrivebench.records import (
    Actor,
    Control,
    CoT,
    CoTFormat,
    EgoState,
    GroundTruth,
    Observation,
    Trajectory,
    TrajectorySpec,
)

DT = 0.1


@dataclass(frozen=True)
class FakeScenario:
    """A straight road of ``length`` metres, optionally with a stopped car at ``car_at``."""

    id: str
    length: float = 30.0
    car_at: float | None = None
    max_time_s: float = 20.0
    family: str = "baseline"
    group: str = "Baseline"
    title: str = "fake road"

    @property
    def max_steps(self) -> int:
        return int(round(self.max_time_s / DT))

    def to_json(self) -> dict:
        return asdict(self)


class LineSimulator:
    """Ego on a line: a = 3·throttle − 8·brake; collision with the car; route complete at the end."""

    dt = DT

    def __init__(self, width: int = 8, height: int = 4, fail_reset_for: str = ""):
        self.width, self.height, self.fail_reset_for = width, height, fail_reset_for
        self.closed = False

    def reset(self, scenario: FakeScenario, seed: int) -> Observation:
        if scenario.id == self.fail_reset_for:
            raise RuntimeError(f"cannot build scenario {scenario.id}")
        self.scenario, self.step_index = scenario, 0
        self.ego = EgoState(0.0, 0.0, 0.0, float(3.0 + episode_rng(seed, "simulator").uniform(0.0, 1.0)))
        return self._observe((), ())

    def step(self, control: Control) -> Observation:
        accel = 3.0 * control.throttle - 8.0 * control.brake
        speed = max(0.0, self.ego.speed + accel * self.dt)
        self.ego = EgoState(self.ego.x + speed * self.dt, 0.0, 0.0, speed)
        self.step_index += 1
        collisions = ("car0",) if self._hits_car() else ()
        return self._observe(collisions, ())

    def _hits_car(self) -> bool:
        car = self.scenario.car_at
        return car is not None and abs(car - self.ego.x) < 3.0

    def _observe(self, collisions: tuple, violations: tuple) -> Observation:
        sc = self.scenario
        actors = (Actor("car0", "car", sc.car_at, 0.0, length=4.5, width=1.8),) if sc.car_at is not None else ()
        terminal = None
        if collisions:
            terminal = "collision"
        elif self.ego.x >= sc.length:
            terminal = "route_complete"
        elif self.step_index >= sc.max_steps:
            terminal = "timeout"
        time_s = self.step_index * self.dt
        gt = GroundTruth(
            step=self.step_index, time=time_s, actors=actors,
            critical_id="car0" if actors else None, critical_kind="car" if actors else None,
            distance_to_critical=(sc.car_at - self.ego.x) if actors else None,
            blocking=bool(actors), route_progress=min(self.ego.x, sc.length), route_length=sc.length,
            collisions=collisions, violations=violations, terminal=terminal,
            route_ahead=tuple((float(i), 0.0) for i in range(5)),
        )
        image = np.full((self.height, self.width, 3), self.step_index % 256, np.uint8)
        return Observation(self.step_index, time_s, image, self.ego, "follow_lane", gt, sc.id)

    def close(self) -> None:
        self.closed = True


class EchoModel:
    """States "stop" when a car is within 15 m, else "go"; its trajectory follows its own words.

    Failure switches for tests: ``fail_at`` = (seed, step) raises, ``nan_at`` returns NaN waypoints,
    ``die_at`` kills the worker process (``os._exit``), ``sleep`` slows every step down,
    ``fail_once_file`` fails the first episode that finds the file missing (and creates it).
    """

    cot_format = CoTFormat("sentence")
    trajectory_spec = TrajectorySpec(3.0, 10.0)

    def __init__(self, cruise: float = 5.0, noise: float = 0.05, fail_at: list | None = None,
                 nan_at: list | None = None, die_at: list | None = None, sleep: float = 0.0,
                 fail_on_build: bool = False, fail_once_file: str = ""):
        if fail_on_build:
            raise RuntimeError("weights not found")
        if cruise < 0:
            raise ConfigError(f"model 'echo': cruise must be ≥ 0, got {cruise}")
        self.fail_once_file = fail_once_file
        self.cruise, self.noise, self.sleep = cruise, noise, sleep
        self.fail_at = tuple(fail_at) if fail_at else None
        self.nan_at = tuple(nan_at) if nan_at else None
        self.die_at = tuple(die_at) if die_at else None
        self.builds = 1

    def reset(self, seed: int) -> None:
        self.seed = seed
        if self.fail_once_file and not os.path.exists(self.fail_once_file):
            open(self.fail_once_file, "w").close()
            raise RuntimeError("transient failure")

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        gap = obs.ground_truth.distance_to_critical
        words = "stop for the car ahead" if gap is not None and 0 < gap < 15 else "the road is clear, go"
        return CoT(f"{words} ({rng.integers(0, 100)})")

    def splice_cot(self, obs: Observation, text: str, rng: np.random.Generator) -> CoT:
        return CoT(text, spliced=True)

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        key = (self.seed, obs.step)
        if self.sleep:
            time.sleep(self.sleep)
        if self.fail_at is not None and key == self.fail_at:
            raise RuntimeError("CUDA out of memory")
        if self.die_at is not None and key == self.die_at:
            os._exit(3)
        speed = 0.0 if cot.text.startswith("stop") else self.cruise
        speed = max(0.0, speed + float(rng.normal(0.0, self.noise)))
        times = np.arange(1, 31) * 0.1
        xy = np.stack([speed * times, np.zeros_like(times)], axis=1)
        if self.nan_at is not None and key == self.nan_at:
            xy[3, 0] = np.nan
        return Trajectory(times, xy)

    def state_digest(self, cot: CoT) -> str:
        return cot.text


class BatchedEchoModel(EchoModel):
    """:class:`EchoModel` with the :class:`~vladrivebench.BatchedModel` capability, for lockstep tests.

    It keeps no per-episode memory (its failure switches are off), so one instance can serve a batch;
    ``BATCH_SIZES`` records the size of every batched call made in this process.
    """

    BATCH_SIZES: list[int] = []

    def reset(self, seed: int) -> None:
        self.seed = None

    def generate_cot_batch(self, observations, rngs):
        BatchedEchoModel.BATCH_SIZES.append(len(observations))
        return [self.generate_cot(o, r) for o, r in zip(observations, rngs, strict=True)]

    def decode_action_batch(self, observations, cots, rngs):
        return [self.decode_action(o, c, r) for o, c, r in zip(observations, cots, rngs, strict=True)]


class SpeedController:
    """Proportional control of speed towards the trajectory's first-second mean speed."""

    def __init__(self, gain: float = 0.5):
        self.gain = gain

    def reset(self) -> None:
        pass

    def control(self, trajectory: Trajectory, ego: EgoState, dt: float) -> Control:
        v_des = float(trajectory.forward_displacement(1.0))
        error = v_des - ego.speed
        throttle = float(np.clip(self.gain * error, 0.0, 1.0))
        brake = float(np.clip(-self.gain * error, 0.0, 1.0))
        return Control(throttle, 0.0, brake, v_des)


class ExplodingSimulator(LineSimulator):
    """Raises in ``step`` after ``after`` steps of every episode."""

    def __init__(self, after: int = 3):
        super().__init__()
        self.after = after

    def step(self, control: Control) -> Observation:
        if self.step_index + 1 >= self.after:
            raise ValueError("physics diverged")
        return super().step(control)


@vladrivebench.hookimpl
def register_models(register):
    register("echo", EchoModel, description="fake model for runner tests")
    register("echo-batched", BatchedEchoModel, description="fake batched model for lockstep tests")


@vladrivebench.hookimpl
def register_simulators(register):
    register("line", LineSimulator, description="fake 1-D simulator for runner tests")
    register("exploding", ExplodingSimulator, description="a simulator that raises")


@vladrivebench.hookimpl
def register_controllers(register):
    register("speed", SpeedController, description="fake speed controller")


SCENARIOS = (
    FakeScenario("road"),
    FakeScenario("car", length=40.0, car_at=30.0),
    FakeScenario("long", length=60.0, max_time_s=8.0),
)



# -- worker functions for executor tests (module level: picklable by reference) ------------------------
def square(job: int) -> tuple[int, int]:
    return job, job * job


def square_but_three_raises(job: int) -> tuple[int, int]:
    if job == 3:
        raise ValueError("three is unlucky")
    return square(job)


def square_but_three_dies(job: int) -> tuple[int, int]:
    if job == 3:
        os._exit(7)
    return square(job)


def square_but_odd_die(job: int) -> tuple[int, int]:
    if job % 2:
        os._exit(9)
    return square(job)


def square_then_die_soon(job: int) -> tuple[int, int]:
    """Job 2 returns its result, then its process dies shortly after (idle, or during its next job)."""
    if job == 2:
        import threading

        threading.Timer(0.05, os._exit, args=(5,)).start()
    return square(job)


def component_identity(job) -> tuple[int, int]:
    """(worker pid, identity of the model this worker built for ``job``): shows models are reused."""
    from vladrivebench._engine import sweep

    registry = sweep._registry_for(job.registry)
    return os.getpid(), id(sweep._component(registry, job.model))


# -- a `vdb` entry point with only these fakes installed (for subprocess tests) ------------------------
def fake_resolve_scenarios(spec, registry=None):
    """Stands in for ``vladrivebench._scenarios.spec.resolve_scenarios`` with the fake scenarios."""
    from vladrivebench.errors import UnknownNameError

    ids = [s.id for s in SCENARIOS] if spec == "all" else (spec.split(",") if isinstance(spec, str) else spec)
    by_id = {s.id: s for s in SCENARIOS}
    unknown = [i for i in ids if i not in by_id]
    if unknown:
        raise UnknownNameError("scenario", unknown[0], by_id)
    return [by_id[i] for i in ids]


def fake_registry():
    """The core's built-ins (executors …) and these fakes, without any installed plugin."""
    from vladrivebench import _builtins as builtins
    from vladrivebench._engine.registry import Registry

    return Registry([("core", builtins), ("fakes", this_module())], entry_points=False)


def this_module():
    import importlib

    return importlib.import_module("runner_fakes")


def vdb_main(argv: list[str]) -> int:
    """``vdb`` with the fake registry and fake scenario resolution."""
    from vladrivebench._cli import main as cli
    from vladrivebench._engine import registry as plugins
    from vladrivebench._scenarios import spec as scenarios

    plugins.set_registry(fake_registry())
    scenarios.resolve_scenarios = fake_resolve_scenarios
    return cli.main(argv)


if __name__ == "__main__":  # python tests/runner_fakes.py run --model echo …
    import sys

    sys.exit(this_module().vdb_main(sys.argv[1:]))
