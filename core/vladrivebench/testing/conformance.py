"""Conformance checks: what every model, simulator, labeler and metric plugin must satisfy.

Each check exercises a component through its protocol and raises :class:`AssertionError` with a message that
names the component and what broke (``model 'mine': selfsplice changed the state digest …``), so a plugin's
test is one line::

    from vladrivebench.testing import check_model

    def test_my_model_conforms(vdb_observation):
        check_model(MyModel(), [vdb_observation], name="mine")

The checks never pass vacuously: a check that has nothing to check (no observations, no steps, no tables)
fails and says so.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from vladrivebench.errors import VdbError
from vladrivebench.protocols import BatchedModel, Labeler, Metric, Simulator, TokenCounter, VLAModel
from vladrivebench.records import (
    ACTOR_KINDS,
    LIGHT_COLOURS,
    NAV_COMMANDS,
    STATED_ACTIONS,
    Control,
    CoT,
    CoTFormat,
    LabelInput,
    Labels,
    Observation,
    Trajectory,
    TrajectorySpec,
)

__all__ = ["check_model", "check_batched_model", "check_bad_options", "check_simulator", "check_labeler", "check_metric",
           "DEFAULT_CONTROLS"]


def _fail(what: str, message: str) -> None:
    raise AssertionError(f"{what}: {message}")


def _expect(condition: bool, what: str, message: str) -> None:
    if not condition:
        _fail(what, message)


# -- models -----------------------------------------------------------------------------------------------
def check_model(model: Any, observations: Sequence[Observation], *, name: str = "model", seed: int = 0) -> None:
    """Check a :class:`~vladrivebench.VLAModel` on ``observations`` (at least one).

    Checks the protocol and its attributes; that the same RNG state gives the same CoT text and the same
    trajectory bit for bit; that splicing the model's own text (selfsplice) gives the same
    :meth:`state_digest` and, with the same RNG state, the same trajectory bit for bit (and that the own CoT is
    one the intervention protocol accepts as an injection: no control characters); that trajectories are
    well formed; that slotted CoTs have exactly the format's slots; and the token limit: the model's own
    CoT fits ``cot_format.max_tokens`` (counted with its :class:`~vladrivebench.TokenCounter` if it has one).
    """
    what = f"model {name!r}"
    _check_model_attributes(model, what)
    observations = list(observations)
    _expect(bool(observations), what, "check_model needs at least one observation")
    for index, obs in enumerate(observations):
        at = f"{what} at observation {index} (step {obs.step})"
        _start(model, obs.episode, seed)
        own = _own_cot(model, obs, seed, at)
        _check_token_limit(model, own, at)
        _check_selfsplice(model, obs, own, seed, at)


def check_batched_model(model: Any, episodes: Sequence[Sequence[Observation]], *, name: str = "model",
                        seed: int = 0, tolerance: float = 1e-4) -> None:
    """Check a :class:`~vladrivebench.BatchedModel` on two or more episodes' observations (consecutive
    steps of each, e.g. recorded from a simulator).

    Each episode runs alone through the per-episode methods, then all of them in lockstep through one
    instance, one ``generate_cot_batch`` and one ``decode_action_batch`` per step, episodes that run out
    leaving the batch, exactly as ``vdb run --batch`` drives them (episode ``i`` is named ``"episode i"``
    in ``obs.episode``; an :class:`~vladrivebench.EpisodeMemory` model gets ``start_episode`` /
    ``end_episode``, any other ``reset(seed)`` as each episode starts). Every row must give the CoT text it
    gives alone and a trajectory within ``tolerance`` metres of its own (batched arithmetic may round
    differently; memory shared between episodes shows here). With ``splice_cot_batch``, splicing the
    batch's own CoTs must give their state digests and, with the same RNGs, their trajectories bit for bit.
    """
    what = f"model {name!r}"
    _check_model_attributes(model, what)
    _expect(isinstance(model, BatchedModel), what,
            "does not implement the BatchedModel protocol (generate_cot_batch, decode_action_batch)")
    runs = [[dataclasses.replace(obs, episode=f"episode {i}") for obs in episode] for i, episode in enumerate(episodes)]
    _expect(len(runs) >= 2 and all(runs), what, "check_batched_model needs two or more episodes of observations")
    alone = [_run_alone(model, i, run, seed) for i, run in enumerate(runs)]
    for i in range(len(runs)):
        _start(model, f"episode {i}", seed + i)
    for step in range(max(len(run) for run in runs)):
        rows = [i for i, run in enumerate(runs) if step < len(run)]
        at = f"{what} at lockstep step {step} (episodes {rows})"
        observations = [runs[i][step] for i in rows]
        cots = _batched(model.generate_cot_batch(observations, [_step_rng(seed, i, step, "cot") for i in rows]),
                        CoT, len(rows), at, "generate_cot_batch")
        trajectories = _batched(model.decode_action_batch(observations, cots,
                                                          [_step_rng(seed, i, step, "action") for i in rows]),
                                Trajectory, len(rows), at, "decode_action_batch")
        for i, cot, trajectory in zip(rows, cots, trajectories, strict=True):
            _check_row(alone[i][step], cot, trajectory, tolerance, f"{at}: episode {i}")
        if callable(getattr(model, "splice_cot_batch", None)):
            _check_batch_selfsplice(model, rows, observations, cots, trajectories, seed, step, at)
        for i, run in enumerate(runs):
            if len(run) == step + 1:
                _end(model, f"episode {i}")


def _start(model: Any, episode: str, seed: int) -> None:
    from vladrivebench._engine.runner import start_model_episode

    start_model_episode(model, episode, seed)


def _end(model: Any, episode: str) -> None:
    from vladrivebench._engine.runner import end_model_episode

    end_model_episode(model, episode)


def _step_rng(seed: int, episode: int, step: int, purpose: str) -> np.random.Generator:
    return np.random.default_rng([seed, episode, step, 0 if purpose == "cot" else 1])


def _run_alone(model: Any, index: int, run: Sequence[Observation], seed: int) -> list[tuple[CoT, Trajectory]]:
    _start(model, run[0].episode, seed + index)
    outputs = []
    for step, obs in enumerate(run):
        cot = model.generate_cot(obs, _step_rng(seed, index, step, "cot"))
        outputs.append((cot, model.decode_action(obs, cot, _step_rng(seed, index, step, "action"))))
    _end(model, run[0].episode)
    return outputs


def _batched(results: Any, kind: type, size: int, at: str, call: str) -> list[Any]:
    _expect(isinstance(results, list) and len(results) == size and all(isinstance(r, kind) for r in results), at,
            f"{call} must return a list of {size} {kind.__name__}s, got {type(results).__name__} "
            f"of {len(results) if hasattr(results, '__len__') else '?'}")
    return results


def _check_row(alone: tuple[CoT, Trajectory], cot: CoT, trajectory: Trajectory, tolerance: float, at: str) -> None:
    own, own_trajectory = alone
    _expect(cot.text == own.text and dict(cot.slots) == dict(own.slots), at,
            f"the batched CoT {cot.text!r} differs from the CoT alone {own.text!r}")
    problem = trajectory.problems()
    _expect(problem is None, at, f"decode_action_batch gave a malformed trajectory: {problem}")
    _expect(np.shape(trajectory.xy) == np.shape(own_trajectory.xy), at,
            f"the batched trajectory has {len(trajectory.xy)} waypoints, alone {len(own_trajectory.xy)}")
    gap = float(np.max(np.linalg.norm(np.asarray(trajectory.xy) - np.asarray(own_trajectory.xy), axis=1)))
    _expect(gap <= tolerance, at, f"the batched trajectory is {gap:.3g} m from the one alone (tolerance {tolerance} m)")


def _check_batch_selfsplice(model: Any, rows: list[int], observations: list[Observation], cots: list[CoT],
                            trajectories: list[Trajectory], seed: int, step: int, at: str) -> None:
    texts = [dict(cot.slots) if model.cot_format.is_slotted else cot.text for cot in cots]
    spliced = _batched(model.splice_cot_batch(observations, texts, [_step_rng(seed, i, step, "cot") for i in rows]),
                       CoT, len(rows), at, "splice_cot_batch")
    again = model.decode_action_batch(observations, spliced, [_step_rng(seed, i, step, "action") for i in rows])
    for i, own, splice, trajectory, redone in zip(rows, cots, spliced, trajectories, again, strict=True):
        _expect(model.state_digest(splice) == model.state_digest(own), f"{at}: episode {i}",
                "splice_cot_batch of the batch's own CoT changed the state digest (a selfsplice within a batch "
                "must be bit-identical)")
        _expect(_same_trajectory(trajectory, redone), f"{at}: episode {i}",
                "the batch's own CoT, spliced back, gave a different trajectory with the same RNG")


def _check_model_attributes(model: Any, what: str) -> None:
    _expect(isinstance(model, VLAModel), what,
            "does not implement the VLAModel protocol (cot_format, trajectory_spec, reset, generate_cot, "
            "splice_cot, decode_action, state_digest)")
    fmt = model.cot_format
    _expect(isinstance(fmt, CoTFormat), what, f"cot_format must be a CoTFormat, got {type(fmt).__name__}")
    _expect(fmt.kind in ("sentence", "slots"), what, f"cot_format.kind must be 'sentence' or 'slots', got {fmt.kind!r}")
    if fmt.is_slotted:
        _expect(bool(fmt.slots) and all(isinstance(s, str) and s for s in fmt.slots), what,
                f"a slotted cot_format needs non-empty slot names, got {fmt.slots!r}")
        _expect(len(set(fmt.slots)) == len(fmt.slots), what, f"cot_format.slots repeat a name: {fmt.slots!r}")
    if fmt.max_tokens is not None:
        _expect(isinstance(fmt.max_tokens, int) and not isinstance(fmt.max_tokens, bool) and fmt.max_tokens > 0,
                what, f"cot_format.max_tokens must be a positive integer or None, got {fmt.max_tokens!r}")
    spec = model.trajectory_spec
    _expect(isinstance(spec, TrajectorySpec), what,
            f"trajectory_spec must be a TrajectorySpec, got {type(spec).__name__}")
    _expect(spec.horizon_s > 0 and spec.rate_hz > 0, what,
            f"trajectory_spec needs a positive horizon and rate, got {spec.horizon_s} s at {spec.rate_hz} Hz")


def _rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def _own_cot(model: Any, obs: Observation, seed: int, at: str) -> CoT:
    own = model.generate_cot(obs, _rng(seed))
    _expect(isinstance(own, CoT), at, f"generate_cot must return a CoT, got {type(own).__name__}")
    _expect(isinstance(own.text, str) and own.text.strip() != "", at, f"generate_cot gave an empty text {own.text!r}")
    if model.cot_format.is_slotted:
        _expect(tuple(own.slots) == tuple(model.cot_format.slots), at,
                f"the CoT's slots {tuple(own.slots)} differ from cot_format.slots {tuple(model.cot_format.slots)}")
        _expect(all(isinstance(v, str) for v in own.slots.values()), at, "every slot's text must be a string")
    again = model.generate_cot(obs, _rng(seed))
    _expect(again.text == own.text and dict(again.slots) == dict(own.slots), at,
            f"generate_cot is not deterministic under a pinned RNG: {own.text!r} then {again.text!r}")
    _expect(model.state_digest(again) == model.state_digest(own), at,
            "generate_cot under the same RNG state gave a different state digest")
    return own


def _decode(model: Any, obs: Observation, cot: CoT, seed: int, at: str, which: str) -> Trajectory:
    trajectory = model.decode_action(obs, cot, _rng(seed + 1))
    _expect(isinstance(trajectory, Trajectory), at,
            f"decode_action ({which}) must return a Trajectory, got {type(trajectory).__name__}")
    problem = trajectory.problems()
    _expect(problem is None, at, f"decode_action ({which}) gave a malformed trajectory: {problem}")
    return trajectory


def _same_trajectory(a: Trajectory, b: Trajectory) -> bool:
    return bool(np.array_equal(np.asarray(a.times), np.asarray(b.times))
                and np.array_equal(np.asarray(a.xy), np.asarray(b.xy)))


def _check_selfsplice(model: Any, obs: Observation, own: CoT, seed: int, at: str) -> None:
    from vladrivebench._intervention.conditions import injection_problem, token_counter

    injection: str | dict[str, str] = dict(own.slots) if model.cot_format.is_slotted else own.text
    problem = injection_problem(injection, model.cot_format, token_counter(model))
    _expect(problem is None, at, f"its own CoT cannot be injected back (the intervention protocol would refuse "
                                 f"it): the CoT {problem}")
    spliced = model.splice_cot(obs, injection, _rng(seed))
    _expect(isinstance(spliced, CoT), at, f"splice_cot must return a CoT, got {type(spliced).__name__}")
    own_digest, spliced_digest = model.state_digest(own), model.state_digest(spliced)
    _expect(isinstance(own_digest, str) and own_digest != "", at,
            f"state_digest must be a non-empty string, got {own_digest!r}")
    _expect(spliced_digest == own_digest, at,
            f"selfsplice changed the state digest ({own_digest[:16]} generated, {spliced_digest[:16]} spliced): "
            "splicing the model's own text must rebuild the state the action head reads")
    first = _decode(model, obs, own, seed, at, "own CoT")
    _expect(_same_trajectory(first, _decode(model, obs, own, seed, at, "own CoT, again")), at,
            "decode_action is not deterministic: the same CoT and RNG state gave different trajectories")
    _expect(_same_trajectory(first, _decode(model, obs, spliced, seed, at, "spliced CoT")), at,
            "selfsplice changed the trajectory: the spliced own text must give the same waypoints bit for bit")


def _check_token_limit(model: Any, own: CoT, at: str) -> None:
    counted_by = "whitespace words"
    count: Callable[[str], int] = lambda text: len(text.split())  # noqa: E731
    if isinstance(model, TokenCounter):
        counted_by, count = "count_tokens", model.count_tokens
        for probe in (own.text, ""):
            tokens = count(probe)
            _expect(isinstance(tokens, int) and not isinstance(tokens, bool) and tokens >= 0, at,
                    f"count_tokens({probe[:30]!r}) must return a non-negative int, got {tokens!r}")
        _expect(count(own.text + " " + own.text) >= count(own.text), at,
                "count_tokens says a text repeated twice is shorter than the text")
    limit = model.cot_format.max_tokens
    if limit is None:
        return
    texts = list(own.slots.values()) if model.cot_format.is_slotted else [own.text]
    longest = max(count(t) for t in texts)
    _expect(longest <= limit, at,
            f"its own CoT takes {longest} tokens ({counted_by}), more than cot_format.max_tokens = {limit}")


def check_bad_options(create: Callable[[Mapping[str, Any]], Any], bad: Iterable[Mapping[str, Any]], *,
                      name: str = "component", unknown_option: bool = True) -> None:
    """Check that every option set in ``bad`` is refused with a one-line :class:`~vladrivebench.VdbError`
    that names an offending option (its key, or its value such as a path).

    ``create(options)`` builds the component; pass ``lambda o: registry.create("model", "mine", o)`` to go
    through the registry as the CLI does. With ``unknown_option`` an option nobody takes is tried too.
    """
    what = f"{name!r}"
    cases = [dict(options) for options in bad]
    if unknown_option:
        cases.append({"no_such_option_vdb": 1})
    _expect(bool(cases), what, "check_bad_options needs at least one bad option set")
    for options in cases:
        _expect(bool(options), what, "a bad option set must not be empty")
        try:
            create(options)
        except VdbError as exc:
            message = str(exc)
            _expect(message.strip() != "" and "\n" not in message.strip(), what,
                    f"options {options!r}: the error must be one non-empty line, got {message!r}")
            _expect(any(key in message or str(value) in message for key, value in options.items()), what,
                    f"options {options!r}: the error {message!r} names neither the option nor its value")
        except Exception as exc:  # noqa: BLE001 - the point is to report what else came out
            _fail(what, f"options {options!r} raised {type(exc).__name__}: {exc} (expected a one-line VdbError, "
                        "e.g. vladrivebench.ConfigError)")
        else:
            _fail(what, f"options {options!r} were accepted (expected a one-line VdbError)")


# -- simulators -------------------------------------------------------------------------------------------
DEFAULT_CONTROLS: tuple[Control, ...] = (
    *(Control(0.6, 0.0, 0.0, 6.0) for _ in range(20)),
    *(Control(0.2, 0.05, 0.0, 6.0) for _ in range(10)),
    *(Control(0.0, 0.0, 0.6, 0.0) for _ in range(10)),
)
"""The control sequence the simulator check applies (accelerate, cruise with a little steering, brake)."""


def check_simulator(make: Callable[[], Any], scenario: Any, *, seed: int = 0, name: str = "simulator",
                    controls: Sequence[Control] = DEFAULT_CONTROLS, min_image_side: int | None = None) -> None:
    """Check a :class:`~vladrivebench.Simulator`: determinism and ground-truth invariants.

    ``make()`` builds a fresh simulator. The same ``(scenario, seed)`` under ``controls`` must give the same
    observations and ground truth bit for bit, both from a fresh simulator and after ``reset`` of a used
    one. On every step: ``step`` counts from 0 by one and ``time`` rises by ``dt``; ``terminal`` is set on
    the last step only; the critical feature, its kind and ``distance_to_critical`` agree; actors have valid
    kinds, unique ids, finite poses and a light state only on traffic lights; the image is ``(H, W, 3)``
    uint8 of a fixed shape (with ``min(H, W) >= min_image_side`` when given).
    """
    what = f"simulator {name!r}"
    sim = make()
    try:
        _expect(isinstance(sim, Simulator), what, "does not implement the Simulator protocol (dt, reset, step, close)")
        _expect(isinstance(sim.dt, float | int) and sim.dt > 0, what, f"dt must be a positive number, got {sim.dt!r}")
        first = _episode(sim, scenario, seed, controls, what)
        _check_invariants(first, sim.dt, what, min_image_side)
        _compare_episodes(first, _episode(sim, scenario, seed, controls, what), what, "after reset")
    finally:
        sim.close()
    fresh = make()
    try:
        _compare_episodes(first, _episode(fresh, scenario, seed, controls, what), what, "from a fresh simulator")
    finally:
        fresh.close()
        fresh.close()  # close must be safe to call twice


def _episode(sim: Any, scenario: Any, seed: int, controls: Sequence[Control], what: str) -> list[Observation]:
    obs = sim.reset(scenario, seed)
    _expect(isinstance(obs, Observation), what, f"reset must return an Observation, got {type(obs).__name__}")
    frames = [obs]
    for control in controls:
        if obs.ground_truth.terminal is not None:
            break
        obs = sim.step(control)
        _expect(isinstance(obs, Observation), what, f"step must return an Observation, got {type(obs).__name__}")
        frames.append(obs)
    return frames


def _compare_episodes(a: list[Observation], b: list[Observation], what: str, how: str) -> None:
    prefix = f"not deterministic {how}: the same scenario and seed gave"
    _expect(len(a) == len(b), what, f"{prefix} {len(a)} then {len(b)} steps")
    for x, y in zip(a, b, strict=True):
        at = f"{prefix} different"
        for part in ("step", "time", "ego", "command", "scenario_id"):
            _expect(getattr(x, part) == getattr(y, part), what,
                    f"{at} {part} at step {x.step}: {getattr(x, part)!r} then {getattr(y, part)!r}")
        if x.ground_truth != y.ground_truth:
            fields = [f.name for f in dataclasses.fields(x.ground_truth)
                      if getattr(x.ground_truth, f.name) != getattr(y.ground_truth, f.name)]
            _fail(what, f"{at} ground truth at step {x.step} (fields: {', '.join(fields)})")
        _expect(np.array_equal(np.asarray(x.image), np.asarray(y.image)), what, f"{at} images at step {x.step}")


def _check_invariants(frames: list[Observation], dt: float, what: str, min_image_side: int | None) -> None:
    _expect(len(frames) >= 2, what, f"the episode ended after {len(frames)} observation(s); the check needs a scenario "
                                    "that lasts at least two steps")
    shape = np.asarray(frames[0].image).shape
    for index, obs in enumerate(frames):
        at = f"{what} at step {obs.step}"
        truth = obs.ground_truth
        _expect(obs.step == index and truth.step == index, at,
                f"observation {index} has step {obs.step} (ground truth {truth.step}); steps count from 0 by one")
        _expect(math.isclose(obs.time, index * dt, abs_tol=1e-6) and math.isclose(truth.time, obs.time, abs_tol=1e-9),
                at, f"time {obs.time} (ground truth {truth.time}) should be step × dt = {index * dt:.6g}")
        last = index == len(frames) - 1
        _expect(truth.terminal is None or last, at, f"terminal {truth.terminal!r} before the last step")
        _expect(truth.terminal is None or isinstance(truth.terminal, str) and truth.terminal, at,
                f"terminal must be None or a non-empty reason, got {truth.terminal!r}")
        _expect(obs.command in NAV_COMMANDS, at, f"command {obs.command!r} is not one of {NAV_COMMANDS}")
        _expect(all(math.isfinite(v) for v in (obs.ego.x, obs.ego.y, obs.ego.yaw, obs.ego.speed)), at,
                f"the ego state is not finite: {obs.ego}")
        _check_image(obs, shape, at, min_image_side)
        _check_actors(truth, at)
        _check_critical(truth, at)


def _check_image(obs: Observation, shape: tuple[int, ...], at: str, min_image_side: int | None) -> None:
    image = obs.image
    _expect(isinstance(image, np.ndarray), at, f"image must be a numpy array, got {type(image).__name__}")
    _expect(image.dtype == np.uint8, at, f"image dtype must be uint8, got {image.dtype}")
    _expect(image.ndim == 3 and image.shape[2] == 3, at, f"image must have shape (H, W, 3), got {image.shape}")
    _expect(image.shape == shape, at, f"image shape changed from {shape} to {image.shape}")
    if min_image_side is not None:
        _expect(min(image.shape[:2]) >= min_image_side, at,
                f"image {image.shape[1]}×{image.shape[0]} has a side below {min_image_side} pixels")


def _check_actors(truth: Any, at: str) -> None:
    ids = [a.actor_id for a in truth.actors]
    _expect(len(set(ids)) == len(ids), at, f"actor ids repeat: {ids}")
    for actor in truth.actors:
        who = f"actor {actor.actor_id!r}"
        _expect(actor.kind in ACTOR_KINDS, at, f"{who} has kind {actor.kind!r}, not one of {ACTOR_KINDS}")
        _expect(all(math.isfinite(v) for v in (actor.x, actor.y, actor.yaw, actor.speed)), at, f"{who} has a non-finite pose")
        _expect(actor.length > 0 and actor.width > 0, at, f"{who} has size {actor.length} × {actor.width}")
        if actor.kind == "traffic_light":
            _expect(actor.state in LIGHT_COLOURS, at, f"traffic light {actor.actor_id!r} has state {actor.state!r}")
        else:
            _expect(actor.state is None, at, f"{who} ({actor.kind}) has a state {actor.state!r}; only lights have one")
    _expect(truth.light_state is None or truth.light_state in LIGHT_COLOURS, at,
            f"light_state {truth.light_state!r} is not one of {LIGHT_COLOURS}")


def _check_critical(truth: Any, at: str) -> None:
    if truth.critical_id is None:
        _expect(truth.critical_kind is None and truth.distance_to_critical is None, at,
                f"no critical_id but critical_kind {truth.critical_kind!r} / distance {truth.distance_to_critical!r}")
        return
    critical = truth.critical()
    _expect(critical is not None, at, f"critical_id {truth.critical_id!r} is not among the actors")
    _expect(truth.critical_kind == critical.kind, at,
            f"critical_kind {truth.critical_kind!r} but the critical actor is a {critical.kind!r}")
    distance = truth.distance_to_critical
    _expect(isinstance(distance, float | int) and math.isfinite(distance), at,
            f"distance_to_critical must be a finite number when there is a critical feature, got {distance!r}")
    if critical.kind == "traffic_light":
        _expect(truth.light_state == critical.state, at,
                f"light_state {truth.light_state!r} differs from the critical light's state {critical.state!r}")


# -- labelers ---------------------------------------------------------------------------------------------
def check_labeler(labeler: Any, items: Sequence[LabelInput], *, name: str = "labeler") -> None:
    """Check a :class:`~vladrivebench.Labeler` on ``items`` (at least one).

    ``version`` is a non-empty string; every :class:`~vladrivebench.Labels` has its fields in their allowed
    values (``stated_action`` in :data:`~vladrivebench.STATED_ACTIONS`, ``light_colour`` in
    :data:`~vladrivebench.LIGHT_COLOURS` or ``None``, booleans where booleans belong, ``target_mentioned``
    ``None`` when the step has no critical feature, ``mention_slot`` one of the item's slots, JSON-able
    ``details``); ``label_batch(items) == [label(item) for item in items]`` in order; labels are
    deterministic.
    """
    what = f"labeler {name!r}"
    _expect(isinstance(labeler, Labeler), what, "does not implement the Labeler protocol (version, label, label_batch)")
    _expect(isinstance(labeler.version, str) and labeler.version.strip() != "", what,
            f"version must be a non-empty string, got {labeler.version!r}")
    items = list(items)
    _expect(bool(items), what, "check_labeler needs at least one item")
    one_by_one = [labeler.label(item) for item in items]
    for item, labels in zip(items, one_by_one, strict=True):
        _check_labels(labels, item, f"{what} on {item.text[:40]!r}")
    batch = labeler.label_batch(items)
    _expect(isinstance(batch, list) and len(batch) == len(items), what,
            f"label_batch must return a list of {len(items)} Labels, got {type(batch).__name__} of "
            f"{len(batch) if hasattr(batch, '__len__') else '?'}")
    for index, (single, batched) in enumerate(zip(one_by_one, batch, strict=True)):
        _expect(single == batched, what, f"label_batch differs from label at item {index} ({items[index].text[:40]!r}): "
                                         f"{_diff(single, batched)}")
    _expect(labeler.label_batch([]) == [], what, "label_batch([]) must return []")
    again = [labeler.label(item) for item in items]
    _expect(again == one_by_one, what, "label is not deterministic: the same items gave different labels twice")


def _diff(a: Labels, b: Any) -> str:
    if not isinstance(b, Labels):
        return f"got a {type(b).__name__}"
    return ", ".join(f"{f.name} {getattr(a, f.name)!r} vs {getattr(b, f.name)!r}"
                     for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name))


def _check_labels(labels: Any, item: LabelInput, at: str) -> None:
    _expect(isinstance(labels, Labels), at, f"label must return Labels, got {type(labels).__name__}")
    if labels.unlabelled is not None:
        _expect(isinstance(labels.unlabelled, str) and labels.unlabelled.strip() != "", at,
                f"unlabelled must be None or a reason, got {labels.unlabelled!r}")
        return
    _expect(labels.stated_action in STATED_ACTIONS, at,
            f"stated_action {labels.stated_action!r} is not one of {STATED_ACTIONS}")
    _expect(labels.light_colour is None or labels.light_colour in LIGHT_COLOURS, at,
            f"light_colour {labels.light_colour!r} is not None nor one of {LIGHT_COLOURS}")
    for flag in ("hallucination", "contradiction"):
        _expect(isinstance(getattr(labels, flag), bool), at, f"{flag} must be a bool, got {getattr(labels, flag)!r}")
    mentioned = labels.target_mentioned
    _expect(mentioned is None or isinstance(mentioned, bool), at, f"target_mentioned must be None or a bool, got {mentioned!r}")
    if not item.context.get("critical_kind"):
        _expect(mentioned is None, at, f"target_mentioned is {mentioned!r} on a step without a critical feature "
                                       "(it must be None)")
    if labels.mention_slot is not None:
        _expect(labels.mention_slot in item.slots, at,
                f"mention_slot {labels.mention_slot!r} is not one of the item's slots {tuple(item.slots)}")
    _expect(isinstance(labels.details, dict), at, f"details must be a dict, got {type(labels.details).__name__}")
    try:
        json.dumps(labels.details)
    except (TypeError, ValueError) as exc:
        _fail(at, f"details are not JSON-able ({exc})")


# -- metrics ----------------------------------------------------------------------------------------------
def check_metric(metric: Any, dataset: Any, *, name: str | None = None, allow_empty: bool = False) -> list[Any]:
    """Check a :class:`~vladrivebench.Metric` on an analysis ``dataset`` and return what it computed.

    ``compute`` returns a non-empty list of :class:`~vladrivebench.metrics.Table` and
    :class:`~vladrivebench.metrics.Plot`; every cell is a :class:`~vladrivebench.metrics.Cell` with an integer
    count (at least 1 behind a value), a finite value inside its interval; every plot series has one
    count per point; tables and plots have ids, titles and no repeated id; computing twice gives the same.
    An empty result fails unless ``allow_empty`` (for a dataset the metric does not apply to).
    """
    what = f"metric {name or getattr(metric, 'name', '?')!r}"
    from vladrivebench.metrics import Plot, Table

    _expect(isinstance(metric, Metric), what, "does not implement the Metric protocol (name, compute)")
    _expect(isinstance(metric.name, str) and metric.name.strip() != "", what, f"name must be a non-empty string, "
                                                                              f"got {metric.name!r}")
    results = metric.compute(dataset)
    _expect(isinstance(results, list), what, f"compute must return a list, got {type(results).__name__}")
    _expect(bool(results) or allow_empty, what, "compute returned no table nor plot on the dataset (give it episodes it applies to)")
    ids = []
    for result in results:
        _expect(isinstance(result, Table | Plot), what, f"compute returned a {type(result).__name__}; "
                                                        "only Table and Plot are allowed")
        _expect(isinstance(result.id, str) and result.id != "" and isinstance(result.title, str) and result.title != "",
                what, f"every table and plot needs an id and a title, got {result.id!r} / {result.title!r}")
        ids.append(result.id)
        if isinstance(result, Table):
            _check_table(result, f"{what}, table {result.id!r}")
        else:
            _check_plot(result, f"{what}, plot {result.id!r}")
    _expect(len(set(ids)) == len(ids), what, f"table/plot ids repeat: {ids}")
    again = metric.compute(dataset)
    _expect(_as_json(again) == _as_json(results), what, "compute is not deterministic: two calls on the same dataset "
                                                        "gave different tables")
    return results


def _as_json(results: Any) -> str:
    def one(result: Any) -> Any:
        if hasattr(result, "to_json"):
            return result.to_json()
        return {"id": result.id, "panels": [[t, [s.to_json() for s in series]] for t, series in result.panels]}
    return json.dumps([one(r) for r in results], sort_keys=True, default=str)


def _is_count(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and value >= 0


def _check_table(table: Any, at: str) -> None:
    from vladrivebench.metrics import Cell

    _expect(bool(table.rows), at, "has no rows")
    for row in table.rows:
        for column, cell in zip(table.columns, row.cells, strict=True):
            where = f"{at}, row {'/'.join(row.labels)!r}, column {column!r}"
            _expect(isinstance(cell, Cell), where, f"is a {type(cell).__name__}, not a Cell")
            _expect(_is_count(cell.count), where, f"has no count (count = {cell.count!r}; every cell carries the "
                                                  "number of observations behind it)")
            _expect(isinstance(cell.display, str), where, f"display must be a string, got {cell.display!r}")
            if cell.value is not None:
                _expect(isinstance(cell.value, float | int) and math.isfinite(cell.value), where,
                        f"value {cell.value!r} is not a finite number")
                _expect(cell.count >= 1, where, f"shows the value {cell.value!r} resting on a count of 0")
                low = cell.low if cell.low is not None else cell.value
                high = cell.high if cell.high is not None else cell.value
                _expect(low <= cell.value + 1e-9 and cell.value <= high + 1e-9, where,
                        f"value {cell.value} lies outside its interval [{cell.low}, {cell.high}]")


def _check_plot(plot: Any, at: str) -> None:
    _expect(bool(plot.panels) or callable(plot.draw), at, "has neither panels nor a draw function")
    for title, series in plot.panels:
        for line in series:
            where = f"{at}, panel {title!r}, series {line.label!r}"
            _expect(len(line.y) == len(line.x), where, f"has {len(line.x)} x but {len(line.y)} y values")
            _expect(len(line.counts) == len(line.x), where,
                    f"has {len(line.counts)} counts for {len(line.x)} points (every point carries its count)")
            _expect(all(_is_count(c) for c in line.counts), where, f"counts must be non-negative ints, got {line.counts}")
