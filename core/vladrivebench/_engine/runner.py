"""The closed-loop episode loop: simulator → model (CoT, then action) → controller → simulator.

One episode is one ``(model, simulator, controller, scenario, seed)``. Every step draws the model's
randomness from :func:`~vladrivebench._engine.rng.step_rng` pinned to ``(seed, step, purpose)``, so a step can be
reproduced exactly — and an intervention at a step uses exactly the action noise the baseline used.

What happens at a step is a *step policy*: by default the model's own CoT and the action decoded from it
(:func:`own_cot_policy`). The intervention protocol passes its own policy (an injected CoT each step, plus
a "shadow" of what the model's own CoT would have done, returned as extras and logged in ``/extras``).
"""

from __future__ import annotations

import dataclasses
import math
import traceback
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vladrivebench._engine.rng import step_rng
from vladrivebench.errors import ModelOutputError, VdbError
from vladrivebench.protocols import Controller, CoTExtras, Simulator, VLAModel
from vladrivebench.records import Control, CoT, GroundTruth, Observation, Trajectory

StepOutput = tuple[CoT, Trajectory, dict]
StepPolicy = Callable[[VLAModel, Observation, int], StepOutput]
"""``policy(model, obs, seed) -> (cot, trajectory, extras)``; extras (JSON-able) go to ``/extras``."""


def own_cot_policy(model: VLAModel, obs: Observation, seed: int) -> StepOutput:
    """The model drives with its own chain-of-thought: generate the CoT, decode the action from it.

    A model that is a :class:`~vladrivebench.CoTExtras` adds JSON-able internals of its own CoT (e.g. the
    scripted model's record of the errors it made on purpose), logged in ``/extras``.
    """
    cot = model.generate_cot(obs, step_rng(seed, obs.step, "cot", obs.scenario_id))
    trajectory = model.decode_action(obs, cot, step_rng(seed, obs.step, "action", obs.scenario_id))
    extras = model.cot_extras(cot) if isinstance(model, CoTExtras) else None
    return cot, trajectory, dict(extras or {})


class EpisodeFailure(Exception):
    """A component raised (or returned something unusable) during an episode.

    ``message`` is one line: which component, which call, which step, what went wrong; ``details`` is
    the full traceback of the original error, for ``failures.json`` (never printed on the terminal).
    """

    def __init__(self, message: str, *, step: int | None, component: str, details: str):
        super().__init__(message)
        self.step, self.component, self.details = step, component, details


@dataclass(frozen=True)
class EpisodeResult:
    """The outcome of an episode, as written to the log's ``result`` record."""

    terminal: str
    steps: int
    collisions: int
    collision_events: tuple[str, ...]
    violations: int
    violation_events: tuple[str, ...]
    route_completion: float
    mean_speed: float
    duration: float

    def to_json(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}


@dataclass
class _Tally:
    """Running totals over the steps of an episode."""

    steps: int = 0
    speed_sum: float = 0.0
    collisions: list[str] = field(default_factory=list)
    violations: list[str] = field(default_factory=list)
    first_time: float | None = None
    last: GroundTruth | None = None
    last_time: float = 0.0

    def add(self, obs: Observation) -> None:
        gt = obs.ground_truth
        self.steps += 1
        self.speed_sum += float(obs.ego.speed)
        self.collisions.extend(gt.collisions)
        self.violations.extend(gt.violations)
        self.first_time = obs.time if self.first_time is None else self.first_time
        self.last, self.last_time = gt, obs.time

    def result(self, terminal: str) -> EpisodeResult:
        gt = self.last
        if terminal == "route_complete":
            completion = 1.0
        elif gt is not None and gt.route_length > 0:
            completion = min(1.0, max(0.0, gt.route_progress / gt.route_length))
        else:
            completion = 0.0
        return EpisodeResult(
            terminal=terminal,
            steps=self.steps,
            collisions=len(self.collisions),
            collision_events=tuple(self.collisions),
            violations=len(self.violations),
            violation_events=tuple(self.violations),
            route_completion=completion,
            mean_speed=self.speed_sum / self.steps if self.steps else 0.0,
            duration=self.last_time - (self.first_time or 0.0),
        )


def run_episode(
    model: VLAModel,
    simulator: Simulator,
    controller: Controller,
    scenario: Any,
    seed: int,
    *,
    policy: StepPolicy | None = None,
    writer: Any = None,
    model_name: str = "model",
    simulator_name: str = "simulator",
    controller_name: str = "controller",
    max_steps: int | None = None,
    on_step: Callable[[Observation, CoT, Trajectory, Control, dict], None] | None = None,
) -> EpisodeResult:
    """Drive one episode closed-loop and return its result.

    Each step: ``policy(model, obs, seed)`` → validated (CoT, trajectory, extras); the controller turns the
    trajectory into a control; the step is logged (``writer.write_step``) and passed to ``on_step``;
    unless the observation is terminal, the simulator advances. The terminal observation is logged too,
    with the model's output for it, so the step that ended the episode (a collision) is in the log.
    ``max_steps`` (default: the scenario's ``max_steps`` + 1) is a safety net against a simulator that
    never ends an episode; reaching it ends the episode with terminal ``"step_limit"``.

    Any exception of a component becomes an :class:`EpisodeFailure` naming the component, the call and
    the step; a malformed model output becomes one too (its cause a :class:`ModelOutputError`).
    """
    policy = policy or own_cot_policy
    limit = max_steps if max_steps is not None else _default_step_limit(scenario)
    names = {"model": model_name, "simulator": simulator_name, "controller": controller_name}
    scenario_id = getattr(scenario, "id", str(scenario))
    where = f"{scenario_id} seed {seed}"
    with _blame(names, "simulator", "reset", where, None):
        obs = simulator.reset(scenario, seed)
    with _blame(names, "model", "reset", where, None):
        model.reset(seed)
    with _blame(names, "controller", "reset", where, None):
        controller.reset()
    tally = _Tally()
    while True:
        step = obs.step
        with _blame(names, "model", "step policy", where, step):
            cot, trajectory, extras = policy(model, obs, seed)
            check_model_output(cot, trajectory, model_name=model_name, step=step, where=where)
        with _blame(names, "controller", "control", where, step):
            control = controller.control(trajectory, obs.ego, simulator.dt)
            _check_control(control)
        if writer is not None:
            writer.write_step(obs, cot, trajectory, control, extras)
        if on_step is not None:
            on_step(obs, cot, trajectory, control, extras)
        tally.add(obs)
        if obs.ground_truth.terminal:
            return tally.result(obs.ground_truth.terminal)
        if tally.steps >= limit:
            return tally.result("step_limit")
        with _blame(names, "simulator", "step", where, step):
            obs = simulator.step(control)


def _default_step_limit(scenario: Any) -> int:
    max_steps = getattr(scenario, "max_steps", None)
    return int(max_steps) + 1 if max_steps is not None else 100_000


def model_step(model: VLAModel, obs: Observation, seed: int, *, policy: StepPolicy | None = None,
               model_name: str = "model") -> StepOutput:
    """One validated model step on a live or recorded observation (open-loop use).

    The RNG streams are the ones a closed-loop episode with ``seed`` uses at ``obs.step``, so the result
    equals what the model produced at that step of the episode (given the same observation).
    """
    cot, trajectory, extras = (policy or own_cot_policy)(model, obs, seed)
    check_model_output(cot, trajectory, model_name=model_name, step=obs.step, where=f"seed {seed}")
    return cot, trajectory, extras


def check_model_output(cot: Any, trajectory: Any, *, model_name: str, step: int, where: str = "") -> None:
    """Raise :class:`ModelOutputError` (naming the model, the step and the problem) for unusable output."""
    at = f"model {model_name!r} at step {step}" + (f" of {where}" if where else "")
    if not isinstance(cot, CoT):
        raise ModelOutputError(f"{at}: expected a CoT, got {type(cot).__name__}")
    if not isinstance(cot.text, str):
        raise ModelOutputError(f"{at}: CoT text must be a str, got {type(cot.text).__name__}")
    if not isinstance(cot.slots, Mapping) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in cot.slots.items()
    ):
        raise ModelOutputError(f"{at}: CoT slots must map slot names to str texts")
    if not isinstance(trajectory, Trajectory):
        raise ModelOutputError(f"{at}: expected a Trajectory, got {type(trajectory).__name__}")
    try:
        problem = trajectory.problems()
    except (TypeError, ValueError) as exc:
        problem = f"not numeric ({exc})"
    if problem:
        raise ModelOutputError(f"{at}: unusable trajectory: {problem}")


def _check_control(control: Any) -> None:
    if not isinstance(control, Control):
        raise TypeError(f"expected a Control, got {type(control).__name__}")
    values = (control.throttle, control.steer, control.brake, control.v_des)
    if not all(isinstance(v, (int, float, np.number)) and math.isfinite(float(v)) for v in values):
        raise ValueError(f"control has non-finite values: {values}")


@contextmanager
def _blame(names: Mapping[str, str], kind: str, call: str, where: str, step: int | None) -> Iterator[None]:
    """Turn any exception inside the block into an EpisodeFailure that says who failed, where."""
    try:
        yield
    except EpisodeFailure:
        raise
    except Exception as exc:
        at = f" at step {step}" if step is not None else ""
        if isinstance(exc, ModelOutputError):
            message = str(exc)
        else:
            text = " ".join(str(exc).split()) or "(no message)"
            message = f"{kind} {names[kind]!r} {call}{at} of {where} raised {type(exc).__name__}: {text}"
        details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        raise EpisodeFailure(message, step=step, component=kind, details=details) from exc


# -- observations from logs (open-loop analysis on recorded episodes) ----------------------------------
def observation_from_step(record: Any, *, scenario_id: str = "", image: np.ndarray | None = None) -> Observation:
    """Rebuild the :class:`Observation` a logged step (``logs.StepRecord``) was made from.

    The camera image is only in logs written with images; pass ``image`` to supply one, otherwise the
    decoded logged image is used, or a 1×1 black image when the log has none.
    """
    if image is None:
        image = decode_png(record.image_png) if record.image_png else np.zeros((1, 1, 3), np.uint8)
    return Observation(step=record.step, time=record.time, image=image, ego=record.ego,
                       command=record.command or "follow_lane", ground_truth=record.ground_truth,
                       scenario_id=scenario_id)


def decode_png(data: bytes) -> np.ndarray:
    """Decode a PNG written by :func:`vladrivebench._logs.episodes.encode_png` (8-bit, unfiltered rows)."""
    import struct
    import zlib

    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise VdbError("not a PNG image")
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        tag, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if tag == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat += body
        pos += 12 + length
    if header is None:
        raise VdbError("PNG without a header")
    width, height, _depth, colour_type = header[:4]
    channels = 3 if colour_type == 2 else 1
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(height, 1 + width * channels)
    if np.any(rows[:, 0] != 0):
        raise VdbError("PNG uses row filters; only unfiltered PNGs from episode logs are supported")
    pixels = rows[:, 1:].reshape(height, width, channels)
    return pixels if channels == 3 else pixels[:, :, 0]
