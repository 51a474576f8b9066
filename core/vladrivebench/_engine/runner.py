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
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager as ContextManager
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from vladrivebench._engine.rng import step_rng
from vladrivebench.errors import ModelOutputError, VdbError
from vladrivebench.protocols import Controller, CoTExtras, EpisodeMemory, Simulator, VLAModel
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
    episode: str | None = None,
) -> EpisodeResult:
    """Drive one episode closed-loop and return its result.

    Each step: ``policy(model, obs, seed)`` → validated (CoT, trajectory, extras); the controller turns the
    trajectory into a control; the step is logged (``writer.write_step``) and passed to ``on_step``;
    unless the observation is terminal, the simulator advances. The terminal observation is logged too,
    with the model's output for it, so the step that ended the episode (a collision) is in the log.
    ``max_steps`` (default: the scenario's ``max_steps`` + 1) is a safety net against a simulator that
    never ends an episode; reaching it ends the episode with terminal ``"step_limit"``. Every observation
    carries ``episode`` (default :func:`episode_name`) as ``obs.episode``; an
    :class:`~vladrivebench.EpisodeMemory` model is told when the episode starts and ends.

    Any exception of a component becomes an :class:`EpisodeFailure` naming the component, the call and
    the step; a malformed model output becomes one too (its cause a :class:`ModelOutputError`).
    """
    policy = policy or own_cot_policy
    limit = max_steps if max_steps is not None else _default_step_limit(scenario)
    names = {"model": model_name, "simulator": simulator_name, "controller": controller_name}
    scenario_id = getattr(scenario, "id", str(scenario))
    where = f"{scenario_id} seed {seed}"
    name = episode or episode_name(scenario, seed)
    with _blame(names, "simulator", "reset", where, None):
        obs = with_episode(simulator.reset(scenario, seed), name)
    with _blame(names, "model", "reset", where, None):
        start_model_episode(model, name, seed)
    with _blame(names, "controller", "reset", where, None):
        controller.reset()
    tally = _Tally()
    try:
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
                result = tally.result(obs.ground_truth.terminal)
                break
            if tally.steps >= limit:
                result = tally.result("step_limit")
                break
            with _blame(names, "simulator", "step", where, step):
                obs = with_episode(simulator.step(control), name)
    except Exception:  # an interrupt ends the process: nothing to tell the model
        _end_after_failure(model, name)
        raise
    with _blame(names, "model", "end_episode", where, None):
        end_model_episode(model, name)
    return result


def episode_name(scenario: Any, seed: int) -> str:
    """The runner's default name of an episode (``obs.episode``): ``"<scenario id> seed <seed>"``."""
    return f"{getattr(scenario, 'id', scenario)} seed {seed}"


def with_episode(obs: Observation, episode: str) -> Observation:
    """``obs`` stamped with the name of the episode it belongs to (a simulator leaves ``obs.episode`` empty)."""
    if not isinstance(obs, Observation) or obs.episode == episode:
        return obs
    return dataclasses.replace(obs, episode=episode)


def start_model_episode(model: Any, episode: str, seed: int) -> None:
    """Tell ``model`` that ``episode`` starts: ``start_episode(episode, seed)`` for an
    :class:`~vladrivebench.EpisodeMemory` model (which may be serving other episodes), else ``reset(seed)``."""
    if isinstance(model, EpisodeMemory):
        model.start_episode(episode, seed)
    else:
        model.reset(seed)


def end_model_episode(model: Any, episode: str) -> None:
    """Tell an :class:`~vladrivebench.EpisodeMemory` model that ``episode`` has ended (others need nothing)."""
    if isinstance(model, EpisodeMemory):
        model.end_episode(episode)


def _end_after_failure(model: Any, episode: str) -> None:
    """:func:`end_model_episode` for an episode that already failed: its own failure is the one reported."""
    try:
        end_model_episode(model, episode)
    except Exception:
        pass


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


# -- lockstep batches ---------------------------------------------------------------------------------
BatchStepPolicy = Callable[[Any, Sequence[Observation], Sequence[int]], list[StepOutput]]
"""``policy(model, observations, seeds) -> [(cot, trajectory, extras), …]`` for the episodes of one step."""


def own_cot_batch_policy(model: Any, observations: Sequence[Observation], seeds: Sequence[int]
                         ) -> list[StepOutput]:
    """:func:`own_cot_policy` for several episodes in one batched call of a :class:`BatchedModel`.

    Episode ``i`` draws from its own pinned streams ``step_rng(seeds[i], step, purpose, scenario)``.
    """
    cot_rngs = [step_rng(s, o.step, "cot", o.scenario_id) for o, s in zip(observations, seeds, strict=True)]
    cots = model.generate_cot_batch(observations, cot_rngs)
    action_rngs = [step_rng(s, o.step, "action", o.scenario_id) for o, s in zip(observations, seeds, strict=True)]
    trajectories = model.decode_action_batch(observations, cots, action_rngs)
    if len(cots) != len(observations) or len(trajectories) != len(observations):
        raise ModelOutputError(f"batched model returned {len(cots)} CoTs and {len(trajectories)} trajectories "
                               f"for {len(observations)} observations")
    outputs = []
    for cot, trajectory in zip(cots, trajectories, strict=True):
        extras = model.cot_extras(cot) if isinstance(model, CoTExtras) else None
        outputs.append((cot, trajectory, dict(extras or {})))
    return outputs


@dataclass
class LockstepEpisode:
    """One episode of a lockstep batch: what to run, where to log it (``open_writer`` gives an entered
    :class:`~vladrivebench._logs.episodes.EpisodeWriter`-like object; ``None`` for an episode run only
    to keep its batch-mates' company), and ``key`` to tell the caller which one finished.

    ``policy`` is the episode's own step policy, used when its lane is served one by one (default:
    :func:`own_cot_policy`); ``wrap_controller(controller)`` gives the controller the episode drives with,
    built around its lane's; episodes with the same non-``None`` ``group`` (consecutive in the list) join
    the batch together, so they see the same batches at every step. ``name`` is stamped on the episode's
    observations (``obs.episode``; default :func:`episode_name`, made unique among the lanes running)."""

    key: Any
    scenario: Any
    seed: int
    open_writer: Callable[[], Any] | None = None
    policy: StepPolicy | None = None
    wrap_controller: Callable[[Any], Any] | None = None
    group: Any = None
    name: str = ""


@dataclass
class _Lane:
    episode: LockstepEpisode
    name: str
    obs: Observation
    writer: Any
    simulator: Any
    controller: Any
    model: Any
    tally: _Tally = field(default_factory=_Tally)
    limit: int = 0


LockstepDone = Callable[[LockstepEpisode, "EpisodeResult | EpisodeFailure", Any], None]
"""``done(episode, result_or_failure, writer)``: called once per episode as it leaves the batch."""

EpisodeBatchPolicy = Callable[[Any, Sequence[LockstepEpisode], Sequence[Observation]], list[StepOutput]]
"""``policy(model, episodes, observations) -> [(cot, trajectory, extras), …]``: a batched step that sees which
episode each observation belongs to (episodes with different step policies in one batch)."""


def run_lockstep(
    episodes: Sequence[LockstepEpisode],
    batch: int,
    *,
    make_lane: Callable[[int], tuple[Any, Any, Any]],
    done: LockstepDone,
    names: Mapping[str, str] | None = None,
    batch_policy: BatchStepPolicy | None = None,
    episode_batch_policy: EpisodeBatchPolicy | None = None,
    harness_turn: ContextManager[Any] | None = None,
    model_turn: ContextManager[Any] | None = None,
) -> None:
    """Run ``episodes`` with up to ``batch`` of them advancing step by step together.

    ``make_lane(i)`` gives lane ``i``'s ``(model, simulator, controller)``; a :class:`BatchedModel` should be
    the same instance in every lane (one batched call per step serves every lane), any other model one
    instance per lane (it may keep per-episode memory; its per-episode methods are called). Episodes join
    in order as lanes free up, lowest lane first; an episode that ends (or fails) leaves its lane and the
    next one joins before the next step. The order of everything depends only on the episodes, so the same
    episodes and batch size give the same calls, and each episode's log the same bytes. ``done`` receives
    each episode's result or :class:`EpisodeFailure` (with its writer, still open, to finish or abandon).
    ``episode_batch_policy`` (instead of ``batch_policy``) is a batched step that also receives the
    lanes' episodes. A ``group`` of episodes joins only when it fits in the free lanes, the earlier
    episodes waiting with it; a group larger than ``batch`` is a :class:`VdbError`.

    ``harness_turn`` and ``model_turn`` (reusable context managers) are entered around each step's harness
    (the lanes' control, logging and simulation, and the joining of new episodes) and around its model
    calls: the ``pipelined`` executor passes two locks shared by its threads, so that one batch's harness
    runs while the model server computes another batch's whole step, rather than the threads' model calls
    queueing behind each other and their harness contending at once.
    """
    names = {"model": "model", "simulator": "simulator", "controller": "controller", **(names or {})}
    _check_groups(episodes, batch)
    if episode_batch_policy is not None:
        def batch_policy(model: Any, observations: Sequence[Observation], seeds: Sequence[int]) -> list[StepOutput]:
            return episode_batch_policy(model, [lane.episode for lane in active_lanes], observations)
    active_lanes: list[_Lane] = []
    queue = list(episodes)
    queue.reverse()
    lanes: list[_Lane | None] = [None] * max(1, batch)
    components: dict[int, tuple[Any, Any, Any]] = {}
    harness_turn, model_turn = harness_turn or nullcontext(), model_turn or nullcontext()
    outputs: list[StepOutput | EpisodeFailure] = []
    active: list[tuple[int, _Lane]] = []
    while True:
        with harness_turn:
            for (i, lane), output in zip(active, outputs, strict=True):
                finished = _advance_lane(lane, output, names)
                if finished is not None:
                    finished = _end_lane(lane, finished, names)
                    lanes[i] = None
                    if isinstance(finished, EpisodeFailure) and finished.component != "model":
                        components.pop(i, None)  # ask make_lane again for that lane before its next episode
                    done(lane.episode, finished, lane.writer)
            _fill_lanes(lanes, queue, components, make_lane, names, done)
        active = [(i, lane) for i, lane in enumerate(lanes) if lane is not None]
        if not active:
            return
        active_lanes[:] = [lane for _, lane in active]
        with model_turn:
            outputs = _lockstep_outputs([lane for _, lane in active], names, batch_policy)


def _check_groups(episodes: Sequence[LockstepEpisode], batch: int) -> None:
    sizes: dict[Any, int] = {}
    for episode in episodes:
        if episode.group is not None:
            sizes[episode.group] = sizes.get(episode.group, 0) + 1
    too_big = [(group, size) for group, size in sizes.items() if size > max(1, batch)]
    if too_big:
        group, size = too_big[0]
        raise VdbError(f"a lockstep group of {size} episodes ({group}) must advance together, more than the "
                       f"batch of {batch}; expected --batch {size} or more")


def _next_group(queue: list[LockstepEpisode]) -> int:
    """How many episodes at the head of ``queue`` (its end) must join together."""
    group = queue[-1].group
    if group is None:
        return 1
    count = 1
    while count < len(queue) and queue[-1 - count].group == group:
        count += 1
    return count


def _fill_lanes(lanes: list[_Lane | None], queue: list[LockstepEpisode], components: dict[int, tuple],
                make_lane: Callable[[int], tuple[Any, Any, Any]], names: Mapping[str, str],
                done: LockstepDone) -> None:
    while queue:
        free = [i for i, lane in enumerate(lanes) if lane is None]
        size = _next_group(queue)
        if len(free) < size:
            return
        for i in free[:size]:
            _join(i, queue.pop(), lanes, components, make_lane, names, done)


def _join(i: int, episode: LockstepEpisode, lanes: list[_Lane | None], components: dict[int, tuple],
          make_lane: Callable[[int], tuple[Any, Any, Any]], names: Mapping[str, str], done: LockstepDone) -> None:
    if i not in components:
        components[i] = make_lane(i)
    model, simulator, controller = components[i]
    writer = None
    try:
        writer = episode.open_writer() if episode.open_writer else None
        if episode.wrap_controller is not None:
            controller = episode.wrap_controller(controller)
        name = _unique_name(episode.name or episode_name(episode.scenario, episode.seed), i, lanes)
        lanes[i] = _start_lane(episode, name, writer, model, simulator, controller, names)
    except EpisodeFailure as failure:
        components.pop(i, None)
        done(episode, failure, writer)


def _unique_name(name: str, lane: int, lanes: Sequence[_Lane | None]) -> str:
    """``name``, or ``name`` with its lane when a running lane already has that name."""
    taken = {other.name for other in lanes if other is not None}
    return name if name not in taken else f"{name} (lane {lane})"


def _start_lane(episode: LockstepEpisode, name: str, writer: Any, model: Any, simulator: Any, controller: Any,
                names: Mapping[str, str]) -> _Lane:
    scenario_id = getattr(episode.scenario, "id", str(episode.scenario))
    where = f"{scenario_id} seed {episode.seed}"
    with _blame(names, "simulator", "reset", where, None):
        obs = with_episode(simulator.reset(episode.scenario, episode.seed), name)
    with _blame(names, "model", "reset", where, None):
        start_model_episode(model, name, episode.seed)
    with _blame(names, "controller", "reset", where, None):
        controller.reset()
    return _Lane(episode, name, obs, writer, simulator, controller, model,
                 limit=_default_step_limit(episode.scenario))


def _end_lane(lane: _Lane, finished: EpisodeResult | EpisodeFailure, names: Mapping[str, str]
              ) -> EpisodeResult | EpisodeFailure:
    """Tell the lane's model that its episode ended; a model that fails at that fails the episode."""
    if isinstance(finished, EpisodeFailure):
        _end_after_failure(lane.model, lane.name)
        return finished
    try:
        with _blame(names, "model", "end_episode", _where(lane), None):
            end_model_episode(lane.model, lane.name)
    except EpisodeFailure as failure:
        return failure
    return finished


def _lockstep_outputs(lanes: Sequence[_Lane], names: Mapping[str, str], batch_policy: BatchStepPolicy | None
                      ) -> list[StepOutput | EpisodeFailure]:
    """Every lane's (CoT, trajectory, extras) for this step: one batched call when the lanes share a
    :class:`BatchedModel`, else each lane's own policy call. A failing call fails the lanes it served."""
    from vladrivebench.protocols import BatchedModel

    shared = lanes[0].model
    if all(lane.model is shared for lane in lanes) and isinstance(shared, BatchedModel):
        observations = [lane.obs for lane in lanes]
        seeds = [lane.episode.seed for lane in lanes]
        where = ", ".join(f"{_where(lane)}" for lane in lanes)
        try:
            with _blame(names, "model", "batched step policy", f"the batch {where}", lanes[0].obs.step):
                return list((batch_policy or own_cot_batch_policy)(shared, observations, seeds))
        except EpisodeFailure as failure:
            return [failure] * len(lanes)
    outputs: list[StepOutput | EpisodeFailure] = []
    for lane in lanes:
        try:
            with _blame(names, "model", "step policy", _where(lane), lane.obs.step):
                outputs.append((lane.episode.policy or own_cot_policy)(lane.model, lane.obs, lane.episode.seed))
        except EpisodeFailure as failure:
            outputs.append(failure)
    return outputs


def _where(lane: _Lane) -> str:
    return f"{getattr(lane.episode.scenario, 'id', lane.episode.scenario)} seed {lane.episode.seed}"


def _advance_lane(lane: _Lane, output: StepOutput | EpisodeFailure, names: Mapping[str, str]
                  ) -> EpisodeResult | EpisodeFailure | None:
    """Validate, control, log and step one lane; its result or failure if the episode ended."""
    if isinstance(output, EpisodeFailure):
        return output
    obs, where, step = lane.obs, _where(lane), lane.obs.step
    try:
        cot, trajectory, extras = output
        with _blame(names, "model", "step policy", where, step):
            check_model_output(cot, trajectory, model_name=names["model"], step=step, where=where)
        with _blame(names, "controller", "control", where, step):
            control = lane.controller.control(trajectory, obs.ego, lane.simulator.dt)
            _check_control(control)
        if lane.writer is not None:
            lane.writer.write_step(obs, cot, trajectory, control, extras)
        lane.tally.add(obs)
        if obs.ground_truth.terminal:
            return lane.tally.result(obs.ground_truth.terminal)
        if lane.tally.steps >= lane.limit:
            return lane.tally.result("step_limit")
        with _blame(names, "simulator", "step", where, step):
            lane.obs = with_episode(lane.simulator.step(control), lane.name)
    except EpisodeFailure as failure:
        return failure
    return None
