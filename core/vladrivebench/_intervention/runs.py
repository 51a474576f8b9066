"""The CoT intervention protocol (Section 3.6 of the paper): the generic run, whatever the paradigm.

A *paradigm* (:class:`~vladrivebench.protocols.Paradigm`, registered with ``register_paradigms``; the core's
own are open-loop, closed-loop and safety in :mod:`vladrivebench._builtins.paradigms`) plans the episodes of
a run, gives each its step policy, analyses the logs and makes the tables. This module does the rest, the
same for every paradigm: the configuration, the components, the manifest, resuming complete episodes, the
preflight of every condition, harvesting, running the planned episodes, the selfsplice gate's verdict and
``intervention.json``. The policies and helpers paradigms share are here too (public in
:mod:`vladrivebench.intervention`).

Every paradigm compares a condition (an injected CoT, :mod:`vladrivebench._intervention.conditions`) with the
model's own CoT under *the same pinned randomness*: at step ``k`` of seed ``s`` the CoT, the splice and the
action head draw from :func:`~vladrivebench._engine.rng.step_rng` ``(s, k, "cot" | "condition" | "action")``,
so the only difference between a condition and the baseline is the text.

**Selfsplice gate.** At every step the model's own CoT is re-injected (``selfsplice``): its
:meth:`state_digest` must equal the generated CoT's and its trajectory must equal the baseline's bit for
bit. A run where any step differs is marked invalid in the results with the size of the difference.

Output directory (``OUT``)::

    OUT/run.json                          manifest: configuration (with the paradigm's effective options),
                                          condition definitions, versions
    OUT/episodes/<model>__<route>__s<seed>__<name>.mcap
                                          name = the planned episode's condition or role
    OUT/intervention.json                 results computed from the logs (what the metrics read)

The results are always computed from the episode logs (:func:`analyse`), never from live objects.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from vladrivebench._engine.rng import step_rng
from vladrivebench._intervention.conditions import (
    SELFSPLICE,
    ConditionError,
    ConditionLibrary,
    HarvestedText,
    Injection,
    StepResolver,
    build_library,
    check_references,
    harvest_braking_cot,
    injection_problem,
    token_counter,
)
from vladrivebench._intervention.stats import (
    DEFAULT_ALPHA,
    DEFAULT_THRESHOLD_M,
    EpisodeSummary,
    cumulative_distance,
    plan_seeds,
)
from vladrivebench.errors import ConfigError, LogError, VdbError
from vladrivebench.protocols import FidelityCheck
from vladrivebench.records import CoT, Observation, Trajectory

DEFAULT_HORIZONS = (2.0, 3.0)
DEFAULT_CHECKPOINTS = (2.0, 4.0, 5.9)
DEFAULT_SEEDS = 5
"""Seeds per condition when none are asked for (the paper used 5–9 for open loop); see ``--plan``."""
RESULTS_NAME = "intervention.json"
RESULTS_FORMAT = 1
SETTINGS_KEY = "paradigm_settings"
"""The manifest's record of every setting the paradigm runs with, defaults included (absent when it has none,
and in directories written before it was recorded: those resume as before)."""
RESERVED_RESULT_KEYS = ("format", "mode", "paradigm_options", "model", "routes", "seeds", "conditions",
                        "definitions", "horizons", "checkpoints", "threshold", "alpha", "confidence", "gate",
                        "valid", "harvested")
"""Keys of ``intervention.json`` that the core writes; a paradigm's results may not use them."""


# -- configuration ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class InterventionConfig:
    """Everything that determines an intervention run's logs and results.

    ``mode`` is the registered paradigm's name and ``paradigm_options`` the options its factory is built
    with (``--paradigm-opt``); ``routes`` are :class:`~vladrivebench._scenarios.spec.Scenario` objects; ``conditions`` are condition names
    (``selfsplice`` is always run, as the gate, whether listed or not); ``harvest_route`` is where
    harvested conditions (``origbrake``) take their braking CoT from (default: the first route).
    ``batch_conditions`` lets a model with ``decode_batch(obs, texts, rng)`` decode the open-loop
    conditions of a step in one batch (the gate still goes through ``splice_cot`` one by one).
    ``batch`` is the lockstep batch size (``--batch``): up to that many planned episodes advance together
    through one model instance when the paradigm is a :class:`~vladrivebench.BatchedParadigm` and the model a
    :class:`~vladrivebench.BatchedModel` with ``splice_cot_batch`` (else the episodes run one by one). It is
    configuration (results may differ in floating point), recorded in the manifest when not 1.
    """

    mode: str
    model: Any
    simulator: Any
    controller: Any
    routes: tuple[Any, ...]
    conditions: tuple[str, ...]
    seeds: tuple[int, ...]
    horizons: tuple[float, ...] = DEFAULT_HORIZONS
    checkpoints: tuple[float, ...] = DEFAULT_CHECKPOINTS
    threshold: float = DEFAULT_THRESHOLD_M
    alpha: float = DEFAULT_ALPHA
    confidence: float = 0.95
    harvest_route: Any = None
    condition_files: tuple[str, ...] = ()
    batch_conditions: bool = False
    paradigm_options: Mapping[str, Any] = field(default_factory=dict)
    batch: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.mode, str) or not self.mode.strip():
            raise ConfigError(f"--mode must name a paradigm (see `vdb intervene --help`), got {self.mode!r}")
        if not self.routes:
            raise ConfigError("--route: give at least one route (e.g. E.1)")
        if not self.seeds:
            raise ConfigError("--seeds must be a whole number ≥ 1")
        for name, values in (("--horizons", self.horizons), ("--checkpoints", self.checkpoints)):
            if not values or any(not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0) for v in values):
                raise ConfigError(f"{name} must be positive numbers of seconds, got {list(values)}")
        if not 0 < self.alpha < 1 or not 0 < self.confidence < 1:
            raise ConfigError(f"--alpha and the confidence must be in (0, 1), got {self.alpha}, {self.confidence}")
        if not (math.isfinite(self.threshold) and self.threshold >= 0):
            raise ConfigError(f"--threshold must be a distance ≥ 0 m, got {self.threshold}")
        if isinstance(self.batch, bool) or not isinstance(self.batch, int) or self.batch < 1:
            raise ConfigError(f"--batch must be a whole number ≥ 1 (episodes in lockstep), got {self.batch!r}")

    @property
    def tested(self) -> tuple[str, ...]:
        """The conditions compared with the baseline, selfsplice first."""
        return (SELFSPLICE,) + tuple(c for c in self.conditions if c != SELFSPLICE)

    @property
    def harvest_scenario(self) -> Any:
        return self.harvest_route or self.routes[0]

    def to_json(self) -> dict[str, Any]:
        paradigm = {"paradigm_options": _plain(dict(self.paradigm_options))} if self.paradigm_options else {}
        return {
            "mode": self.mode,
            **paradigm,
            "model": self.model.to_json(),
            "simulator": self.simulator.to_json(),
            "controller": self.controller.to_json(),
            "routes": [r.id for r in self.routes],
            "conditions": list(self.tested),
            "seeds": list(self.seeds),
            "horizons": list(self.horizons),
            "checkpoints": list(self.checkpoints),
            "threshold": self.threshold,
            "alpha": self.alpha,
            "confidence": self.confidence,
            "harvest_route": self.harvest_scenario.id,
            "condition_files": list(self.condition_files),
            "batch_conditions": self.batch_conditions,
            **({"batch": self.batch} if self.batch != 1 else {}),  # absent at 1: unbatched runs keep their bytes
        }


# -- trajectories -------------------------------------------------------------------------------------
def trajectory_difference(a: Trajectory, b: Trajectory) -> float:
    """Largest absolute difference between two trajectories' times and waypoints (inf if shapes differ)."""
    ta, tb = np.asarray(a.times, float), np.asarray(b.times, float)
    xa, xb = np.asarray(a.xy, float), np.asarray(b.xy, float)
    if ta.shape != tb.shape or xa.shape != xb.shape:
        return math.inf
    if ta.size == 0:
        return 0.0
    return float(max(np.max(np.abs(ta - tb)), np.max(np.abs(xa - xb)) if xa.size else 0.0))


def displacements(trajectory: Trajectory, horizons: Sequence[float]) -> dict[str, float]:
    """Forward displacement (m) of ``trajectory`` at each horizon, keyed by :func:`horizon_key`."""
    return {horizon_key(h): trajectory.forward_displacement(h) for h in horizons}


def horizon_key(seconds: float) -> str:
    """The JSON key of a horizon or checkpoint: ``2.0`` → ``"2"``, ``5.9`` → ``"5.9"``."""
    return f"{seconds:g}"


# -- splicing one condition at one step ------------------------------------------------------------------
@dataclass
class Splicer:
    """Resolves conditions at a step and splices them into the model, with every check in one place.

    ``resolver(own)`` gives the conditions' injections at a step (from the model's own CoT); ``injection``
    resolves one and checks it (:meth:`check`); ``splice`` and ``decode`` call the model with the pinned
    ``"condition"`` / ``"action"`` streams of the step, turning a refusal into a one-line error.
    ``count_tokens`` is the model's tokenizer when it has one, else a word count.
    """

    model: Any
    library: ConditionLibrary
    harvested: Mapping[str, Injection]
    model_name: str
    count_tokens: Callable[[str], int] = field(init=False)

    def __post_init__(self) -> None:
        self.count_tokens = token_counter(self.model)

    def resolver(self, own: CoT) -> StepResolver:
        """The step's condition resolver, given the model's own CoT at the step."""
        return StepResolver(self.library, self.model.cot_format, own, self.harvested, self.count_tokens,
                            self.model_name)

    def injection(self, resolver: StepResolver, name: str) -> Injection:
        """The condition's text at this step, checked against the model's format and token limit."""
        return self.check(name, resolver(name))

    def check(self, name: str, injection: Injection) -> Injection:
        """``injection`` when the model's format and token limit can take it, else a one-line
        :class:`ConditionError` naming ``name`` (a condition, or whatever a paradigm calls its text)."""
        problem = injection_problem(injection, self.model.cot_format, self.count_tokens, allow_empty=True)
        if problem:
            raise ConditionError(f"condition {name!r} cannot be given to model {self.model_name!r}: its text "
                                 f"{problem}")
        return injection

    def splice(self, obs: Observation, name: str, injection: Injection, seed: int) -> CoT:
        """``model.splice_cot`` with the pinned condition stream; a refusal becomes a one-line error."""
        try:
            return self.model.splice_cot(obs, injection, step_rng(seed, obs.step, "condition", obs.scenario_id))
        except VdbError as exc:
            raise ConditionError(f"condition {name!r}: model {self.model_name!r} cannot take its text: "
                                 f"{_one_line(exc)}") from None
        except (ValueError, KeyError, TypeError) as exc:
            raise ConditionError(f"condition {name!r}: model {self.model_name!r} cannot take its text "
                                 f"({type(exc).__name__}: {_one_line(exc)})") from None

    def decode(self, obs: Observation, cot: CoT, seed: int) -> Trajectory:
        """``model.decode_action`` with the step's pinned action stream (the baseline's action noise)."""
        return self.model.decode_action(obs, cot, step_rng(seed, obs.step, "action", obs.scenario_id))

    # -- several episodes' observations at once (lockstep batches) --
    def own_many(self, observations: Sequence[Observation], seeds: Sequence[int]
                 ) -> tuple[list[CoT], list[Trajectory]]:
        """:func:`own_step` for every ``(observations[i], seeds[i])``: one ``generate_cot_batch`` and one
        ``decode_action_batch`` call on a :class:`~vladrivebench.BatchedModel` (else one by one)."""
        model = self.model
        if not _batched(model, "generate_cot_batch"):
            pairs = [own_step(model, obs, seed) for obs, seed in zip(observations, seeds, strict=True)]
            return [c for c, _ in pairs], [t for _, t in pairs]
        rngs = [step_rng(seed, obs.step, "cot", obs.scenario_id) for obs, seed in zip(observations, seeds, strict=True)]
        owns = _same_length(model.generate_cot_batch(list(observations), rngs), observations, "generate_cot_batch")
        return owns, self.decode_many(observations, owns, seeds)

    def splice_many(self, observations: Sequence[Observation], names: Sequence[str],
                    injections: Sequence[Injection], seeds: Sequence[int]) -> list[CoT]:
        """:meth:`splice` for every row (``names[i]`` in messages) in one ``splice_cot_batch`` call when the
        model has it, with row i's pinned condition stream. A refusal is the one-line error of the row
        that caused it (found by splicing the rows one by one)."""
        if not _batched(self.model, "splice_cot_batch"):
            return [self.splice(o, n, t, s) for o, n, t, s in zip(observations, names, injections, seeds, strict=True)]
        rngs = [step_rng(s, o.step, "condition", o.scenario_id) for o, s in zip(observations, seeds, strict=True)]
        try:
            cots = self.model.splice_cot_batch(list(observations), list(injections), rngs)
        except (VdbError, ValueError, KeyError, TypeError) as exc:
            for o, n, t, s in zip(observations, names, injections, seeds, strict=True):
                self.splice(o, n, t, s)  # raises the offending row's ConditionError
            raise ConditionError(f"conditions {', '.join(dict.fromkeys(names))}: model {self.model_name!r} cannot "
                                 f"take their texts in one batch: {_one_line(exc)}") from None
        return _same_length(cots, observations, "splice_cot_batch")

    def decode_many(self, observations: Sequence[Observation], cots: Sequence[CoT], seeds: Sequence[int]
                    ) -> list[Trajectory]:
        """:meth:`decode` for every row in one ``decode_action_batch`` call (row i: its pinned action stream)."""
        if not _batched(self.model, "decode_action_batch"):
            return [self.decode(o, c, s) for o, c, s in zip(observations, cots, seeds, strict=True)]
        rngs = [step_rng(s, o.step, "action", o.scenario_id) for o, s in zip(observations, seeds, strict=True)]
        trajectories = self.model.decode_action_batch(list(observations), list(cots), rngs)
        return _same_length(trajectories, observations, "decode_action_batch")


def _batched(model: Any, method: str) -> bool:
    return callable(getattr(model, method, None))


def _same_length(results: Any, observations: Sequence[Observation], method: str) -> list[Any]:
    results = list(results)
    if len(results) != len(observations):
        from vladrivebench.errors import ModelOutputError

        raise ModelOutputError(f"{method} returned {len(results)} results for {len(observations)} observations")
    return results


def selfsplice_many(splicer: Splicer, observations: Sequence[Observation], owns: Sequence[CoT],
                    seeds: Sequence[int]) -> tuple[list[CoT], list[Trajectory]]:
    """Every row's own CoT spliced back (``selfsplice``) and decoded, in calls that mirror the generation.

    The splice and decode calls have the same rows and texts as the ``generate_cot_batch`` and
    ``decode_action_batch`` calls that made ``owns``, so a model whose batched splice feeds texts as its
    generation does gives bit-identical states and trajectories: the selfsplice gate within a batch.
    """
    injections = [splicer.injection(splicer.resolver(own), SELFSPLICE) for own in owns]
    spliced = splicer.splice_many(observations, [SELFSPLICE] * len(owns), injections, seeds)
    return spliced, splicer.decode_many(observations, spliced, seeds)


@dataclass(frozen=True)
class RunContext:
    """What a paradigm's :meth:`~vladrivebench.protocols.Paradigm.policy` may use: the run's
    :class:`InterventionConfig` and its :class:`Splicer` (resolving, checking, splicing and decoding
    conditions with the pinned RNG streams; harvested texts included)."""

    config: InterventionConfig
    splicer: Splicer


@dataclass(frozen=True)
class LaneStep:
    """One episode of a lockstep batch at one step, as :meth:`~vladrivebench.BatchedParadigm.step_batch`
    receives it: the :class:`PlannedEpisode`, the step policy the paradigm gave it, the observation and
    the episode's seed."""

    episode: Any
    policy: Any
    obs: Observation
    seed: int


@dataclass(frozen=True)
class PlannedEpisode:
    """One episode of an intervention run, as a paradigm plans it.

    ``route`` is the :class:`~vladrivebench.Scenario`, ``seed`` the episode's seed, ``role`` what the episode
    is (``"baseline"``, ``"openloop"``, ``"injected"``, or a paradigm's own word) and ``condition`` the
    condition that drives it, if any. The log is ``<model>__<route>__s<seed>__<name>.mcap`` with
    ``name`` = ``condition or role``, and its metadata records ``{"mode", "role", "condition"}``; analysis
    finds the episode again under the key ``(route id, seed, name)`` (:class:`LoggedEpisodes`).
    """

    route: Any
    seed: int
    role: str
    condition: str | None = None

    @property
    def name(self) -> str:
        return self.condition or self.role

    @property
    def key(self) -> tuple[str, int, str]:
        return (self.route.id, self.seed, self.name)

    @property
    def episode(self) -> str:
        """The runner's name of the episode (``obs.episode``): unique among a run's episodes."""
        from vladrivebench._engine.runner import episode_name

        return f"{episode_name(self.route, self.seed)} {self.name}"


@runtime_checkable
class WrapsController(Protocol):
    """A step policy that needs to see the controller: the run drives the episode with the controller
    ``wrap_controller`` returns (e.g. a :class:`ShadowController` that also computes the shadow's control)."""

    def wrap_controller(self, controller: Any) -> Any:
        """The controller to drive this episode with, built around the run's ``controller``."""
        ...


def _plain(value: Any) -> Any:
    """JSON round trip: tuples become lists, so stored and fresh configurations compare equal."""
    return json.loads(json.dumps(value, default=str))


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


MOVING_SPEED = 1.0
"""m/s: the ego is driving. A stop counts only after this, not while it pulls away from rest."""
STOPPED_SPEED = 0.3
"""m/s: below this, with the obstacle still ahead, the ego has stopped."""


def came_to_stop(steps: Any, start: float = 0) -> bool:
    """Whether the ego, having driven (≥ MOVING_SPEED), was below STOPPED_SPEED at a step ≥ ``start`` with
    the critical actor still ahead (the rule of ``--mode safety``'s "baseline stopped"; paradigms that
    inject from an onset pass it as ``start``)."""
    has_moved = False
    for step in steps:
        if (has_moved and step.step >= start and step.ego.speed < STOPPED_SPEED
                and (step.ground_truth.distance_to_critical or -1.0) > 0.0):
            return True
        has_moved = has_moved or step.ego.speed >= MOVING_SPEED
    return False


def gate_record(model: Any, own: CoT, own_trajectory: Trajectory, spliced: CoT,
                spliced_trajectory: Trajectory, obs: Observation | None = None,
                seed: int | None = None) -> dict[str, Any]:
    """The selfsplice check of one step: digests equal and trajectories identical (difference in metres).

    Given ``obs`` and ``seed``, a model with the :class:`~vladrivebench.protocols.FidelityCheck` capability
    also compares the spliced state with its own native forward pass (:func:`fidelity_fields`).
    """
    own_digest, splice_digest = model.state_digest(own), model.state_digest(spliced)
    difference = trajectory_difference(own_trajectory, spliced_trajectory)
    record = {
        "digest_equal": own_digest == splice_digest,
        "trajectory_diff": difference if math.isfinite(difference) else 1e300,
        "ok": own_digest == splice_digest and difference == 0.0,
    }
    if obs is not None and seed is not None:
        record.update(fidelity_fields(model, obs, spliced, seed))
        record["ok"] = record["ok"] and record.get("fidelity_ok", True)
    return record


def fidelity_fields(model: Any, obs: Observation, spliced: CoT, seed: int) -> dict[str, Any]:
    """The fidelity check of one step: the spliced state against the model's native computation.

    Empty for models without :class:`~vladrivebench.protocols.FidelityCheck`; else the largest cache and
    trajectory differences and whether both are within the model's ``fidelity_tolerance``.
    """
    if not isinstance(model, FidelityCheck):
        return {}
    cache_diff, trajectory_diff = (float(x) for x in model.fidelity_check(
        obs, spliced, step_rng(seed, obs.step, "action", obs.scenario_id)))
    tolerance = float(model.fidelity_tolerance)
    return {
        "fidelity_cache_diff": cache_diff if math.isfinite(cache_diff) else 1e300,
        "fidelity_trajectory_diff": trajectory_diff if math.isfinite(trajectory_diff) else 1e300,
        "fidelity_ok": cache_diff <= tolerance and trajectory_diff <= tolerance,
    }


def own_step(model: Any, obs: Observation, seed: int) -> tuple[CoT, Trajectory]:
    """The model's own CoT and its trajectory, with the pinned streams a plain episode uses."""
    own = model.generate_cot(obs, step_rng(seed, obs.step, "cot", obs.scenario_id))
    return own, model.decode_action(obs, own, step_rng(seed, obs.step, "action", obs.scenario_id))


# -- step policies ------------------------------------------------------------------------------------
class BaselinePolicy:
    """The model's own CoT drives; extras mark the episode as a baseline."""

    def __call__(self, model: Any, obs: Observation, seed: int) -> tuple[CoT, Trajectory, dict]:
        return self.outcome(*own_step(model, obs, seed))

    def outcome(self, own: CoT, trajectory: Trajectory) -> tuple[CoT, Trajectory, dict]:
        """The step's output from the own CoT and its trajectory."""
        return own, trajectory, {"intervention": {"role": "baseline"}}


class OpenLoopPolicy:
    """The model's own CoT drives; every condition is spliced and decoded on the same observation.

    Extras per step: ``gate`` (the selfsplice check) and ``displacement[horizon][name]`` for ``baseline``,
    ``selfsplice`` and each condition, in metres.
    """

    def __init__(self, splicer: Splicer, conditions: Sequence[str], horizons: Sequence[float],
                 batch: bool = False):
        self.splicer, self.horizons = splicer, tuple(horizons)
        self.conditions = [c for c in conditions if c != SELFSPLICE]
        self.batch = batch and callable(getattr(splicer.model, "decode_batch", None))

    def __call__(self, model: Any, obs: Observation, seed: int) -> tuple[CoT, Trajectory, dict]:
        sp = self.splicer
        own, trajectory = own_step(model, obs, seed)
        resolver = sp.resolver(own)
        selfsplice = sp.splice(obs, SELFSPLICE, sp.injection(resolver, SELFSPLICE), seed)
        selfsplice_trajectory = sp.decode(obs, selfsplice, seed)
        return self.outcome(model, obs, seed, own, trajectory, selfsplice, selfsplice_trajectory,
                            self._conditions(obs, resolver, seed))

    def outcome(self, model: Any, obs: Observation, seed: int, own: CoT, trajectory: Trajectory,
                selfsplice: CoT, selfsplice_trajectory: Trajectory, conditions: Mapping[str, Trajectory]
                ) -> tuple[CoT, Trajectory, dict]:
        """The step's output from its parts: the own CoT drives; extras hold the gate and the displacements
        of the baseline, selfsplice and every condition's trajectory."""
        gate = gate_record(model, own, trajectory, selfsplice, selfsplice_trajectory, obs, seed)
        trajectories = {"baseline": trajectory, SELFSPLICE: selfsplice_trajectory}
        trajectories.update(self.checked(obs, conditions))
        by_horizon = {horizon_key(h): {name: t.forward_displacement(h) for name, t in trajectories.items()}
                      for h in self.horizons}
        extras = {"intervention": {"role": "openloop", "gate": gate, "displacement": by_horizon}}
        return own, trajectory, extras

    def _conditions(self, obs: Observation, resolver: StepResolver, seed: int) -> dict[str, Trajectory]:
        sp = self.splicer
        injections = {name: sp.injection(resolver, name) for name in self.conditions}
        if self.batch and injections and all(isinstance(t, str) for t in injections.values()):
            decoded = sp.model.decode_batch(obs, list(injections.values()), step_rng(seed, obs.step, "action", obs.scenario_id))
            return dict(zip(injections, decoded, strict=True))
        return {name: sp.decode(obs, sp.splice(obs, name, text, seed), seed) for name, text in injections.items()}

    def checked(self, obs: Observation, trajectories: Mapping[str, Any]) -> dict[str, Trajectory]:
        """``trajectories`` (condition → trajectory), or a one-line error for the first unusable one."""
        for name, traj in trajectories.items():
            problem = traj.problems() if isinstance(traj, Trajectory) else f"not a Trajectory ({type(traj).__name__})"
            if problem:
                raise ConfigError(f"model {self.splicer.model_name!r} at step {obs.step}: unusable trajectory under "
                                  f"condition {name!r}: {problem}")
        return dict(trajectories)


def open_loop_step_batch(model: Any, lanes: Sequence[LaneStep], context: RunContext) -> list[tuple[CoT, Trajectory, dict]]:
    """One lockstep step of :class:`OpenLoopPolicy` episodes (``lanes``, one per episode).

    The own CoTs of every lane in one batched generation and one decode; the selfsplice gate in calls
    mirroring them (:func:`selfsplice_many`); then each condition in one splice and one decode call for the
    lanes that test it (or, with ``--batch-conditions``, each lane's conditions in one ``decode_batch``).
    """
    sp = context.splicer
    observations, seeds = [lane.obs for lane in lanes], [lane.seed for lane in lanes]
    owns, trajectories = sp.own_many(observations, seeds)
    mirrored, mirrored_trajectories = selfsplice_many(sp, observations, owns, seeds)
    resolvers = [sp.resolver(own) for own in owns]
    conditions: list[dict[str, Trajectory]] = [{} for _ in lanes]
    names = list(dict.fromkeys(c for lane in lanes for c in lane.policy.conditions))
    for name in names:
        rows = [i for i, lane in enumerate(lanes) if name in lane.policy.conditions and not lane.policy.batch]
        if not rows:
            continue
        injections = [sp.injection(resolvers[i], name) for i in rows]
        cots = sp.splice_many([observations[i] for i in rows], [name] * len(rows), injections, [seeds[i] for i in rows])
        for i, traj in zip(rows, sp.decode_many([observations[i] for i in rows], cots, [seeds[i] for i in rows]),
                           strict=True):
            conditions[i][name] = traj
    outputs = []
    for i, lane in enumerate(lanes):
        if lane.policy.batch:
            conditions[i] = lane.policy._conditions(lane.obs, resolvers[i], lane.seed)
        outputs.append(lane.policy.outcome(model, lane.obs, lane.seed, owns[i], trajectories[i], mirrored[i],
                                           mirrored_trajectories[i], conditions[i]))
    return outputs


class ShadowController:
    """Wraps a controller so that, besides the applied control, it computes the control the *shadow*
    trajectory (the model's own) would have produced from the same controller state, on a copy."""

    def __init__(self, inner: Any):
        self.inner = inner
        self.pending: tuple[Trajectory, dict] | None = None

    def reset(self) -> None:
        self.inner.reset()
        self.pending = None

    def control(self, trajectory: Trajectory, ego: Any, dt: float) -> Any:
        if self.pending is not None:
            shadow_trajectory, record = self.pending
            self.pending = None
            twin = copy.deepcopy(self.inner)
            shadow = twin.control(shadow_trajectory, ego, dt)
            record["brake"], record["v_des"] = float(shadow.brake), float(shadow.v_des)
        return self.inner.control(trajectory, ego, dt)


class InjectionPolicy:
    """The condition's text drives at every step; the model's own CoT runs alongside as the shadow.

    Extras: ``condition``, ``shadow`` (own CoT text, its displacement at the horizons, and — filled by
    :class:`ShadowController` — the brake and v_des the controller would have applied), and for
    ``selfsplice`` the ``gate`` record.
    """

    def __init__(self, splicer: Splicer, condition: str, horizons: Sequence[float],
                 controller: ShadowController | None = None):
        self.splicer, self.condition, self.horizons = splicer, condition, tuple(horizons)
        self.controller = controller

    def __call__(self, model: Any, obs: Observation, seed: int) -> tuple[CoT, Trajectory, dict]:
        sp = self.splicer
        own, own_trajectory = own_step(model, obs, seed)
        resolver = sp.resolver(own)
        injected = sp.splice(obs, self.condition, sp.injection(resolver, self.condition), seed)
        trajectory = sp.decode(obs, injected, seed)
        return self.outcome(model, obs, seed, own, own_trajectory, injected, trajectory)

    def outcome(self, model: Any, obs: Observation, seed: int, own: CoT, own_trajectory: Trajectory,
                injected: CoT, trajectory: Trajectory) -> tuple[CoT, Trajectory, dict]:
        """The step's output from its parts: the injected CoT drives, the own CoT is the shadow (and, for
        ``selfsplice``, the gate's reference); hands the shadow to the :class:`ShadowController`."""
        shadow: dict[str, Any] = {"text": own.text, "slots": dict(own.slots),
                                  "displacement": displacements(own_trajectory, self.horizons)}
        record: dict[str, Any] = {"role": "injected", "condition": self.condition, "shadow": shadow,
                                  "displacement": displacements(trajectory, self.horizons)}
        if self.condition == SELFSPLICE:
            record["gate"] = gate_record(model, own, own_trajectory, injected, trajectory, obs, seed)
        if self.controller is not None:
            self.controller.pending = (own_trajectory, shadow)
        return injected, trajectory, {"intervention": record}

    def wrap_controller(self, controller: Any) -> ShadowController:
        """Drive with a :class:`ShadowController` around ``controller`` (fills the shadow's brake, v_des)."""
        self.controller = ShadowController(controller)
        return self.controller


def injection_step_batch(model: Any, lanes: Sequence[LaneStep], context: RunContext
                         ) -> list[tuple[CoT, Trajectory, dict]]:
    """One lockstep step of :class:`BaselinePolicy` and :class:`InjectionPolicy` episodes (closed loop).

    Every lane's own CoT in one batched generation and one decode (the baseline drives with it, an
    injected episode logs it as the shadow); the ``selfsplice`` lanes' CoTs from calls mirroring those
    (:func:`selfsplice_many`, so the gate holds bit for bit); every other injected lane's condition in one
    ``splice_many`` and one ``decode_many`` call.
    """
    sp = context.splicer
    observations, seeds = [lane.obs for lane in lanes], [lane.seed for lane in lanes]
    owns, own_trajectories = sp.own_many(observations, seeds)
    injected: dict[int, tuple[CoT, Trajectory]] = {}
    rows = [i for i, lane in enumerate(lanes) if isinstance(lane.policy, InjectionPolicy)]
    if any(lanes[i].policy.condition == SELFSPLICE for i in rows):
        mirrored, mirrored_trajectories = selfsplice_many(sp, observations, owns, seeds)
        injected.update({i: (mirrored[i], mirrored_trajectories[i]) for i in rows
                         if lanes[i].policy.condition == SELFSPLICE})
    others = [i for i in rows if i not in injected]
    if others:
        names = [lanes[i].policy.condition for i in others]
        texts = [sp.injection(sp.resolver(owns[i]), name) for i, name in zip(others, names, strict=True)]
        obs_rows, seed_rows = [observations[i] for i in others], [seeds[i] for i in others]
        cots = sp.splice_many(obs_rows, names, texts, seed_rows)
        injected.update(zip(others, zip(cots, sp.decode_many(obs_rows, cots, seed_rows), strict=True), strict=True))
    outputs = []
    for i, lane in enumerate(lanes):
        if i in injected:
            outputs.append(lane.policy.outcome(model, lane.obs, lane.seed, owns[i], own_trajectories[i], *injected[i]))
        elif isinstance(lane.policy, BaselinePolicy):
            outputs.append(lane.policy.outcome(owns[i], own_trajectories[i]))
        else:  # a policy of the paradigm's own: served alone
            outputs.append(lane.policy(model, lane.obs, lane.seed))
    return outputs


# -- the run ------------------------------------------------------------------------------------------
Progress = Callable[[str, int, int], None]
"""``progress(label, done, total)`` after every episode."""


class InterventionRun:
    """Runs an :class:`InterventionConfig` into ``out`` (resuming complete episodes) and analyses it."""

    def __init__(self, config: InterventionConfig, out: Path | str, *, registry: Any = None,
                 progress: Progress | None = None, on_note: Callable[[str], None] | None = None,
                 executor: Any = None):
        from vladrivebench._engine.registry import get_registry

        self.config, self.out = config, Path(out)
        # Runs the episodes' shares in worker processes (or a cluster) when it is not an in-process one; the
        # shares are the same lockstep chunks (or single episodes) either way, so the logs are the same bytes.
        self.executor = executor
        self.injections: dict[str, Any] = {}  # the harvested conditions' texts, once harvested
        self.registry = registry or get_registry()
        self.progress = progress
        self.on_note = on_note  # called once when the run is accepted, if it runs otherwise than asked
        self.paradigm = build_paradigm(self.registry, config.mode, config.paradigm_options)
        self.library = build_library(self.registry, config.condition_files)
        self.closure = check_references(self.library, list(config.tested))
        self.paradigm.check(config)
        self.harvest_names = self.library.harvest_names(list(config.tested))
        self._components: dict[str, Any] = {}

    # -- components --
    def component(self, kind: str) -> Any:
        spec = {"model": self.config.model, "simulator": self.config.simulator,
                "controller": self.config.controller}[kind]
        if kind not in self._components:
            from vladrivebench._engine.sweep import create_component  # on the model server when pipelined

            self._components[kind] = create_component(self.registry, spec)
        return self._components[kind]

    def close(self) -> None:
        objects = [o for value in self._components.values() for o in (value if isinstance(value, tuple) else (value,))]
        for obj in objects:
            close = getattr(obj, "close", None)
            if callable(close):
                try:
                    close()
                except Exception:  # closing must not hide the run's own outcome
                    pass
        self._components.clear()

    # -- the whole run --
    def manifest(self) -> dict[str, Any]:
        from vladrivebench._engine.sweep import ComponentSpec, collect_versions

        c = self.config
        paradigm = ComponentSpec("paradigm", c.mode, dict(c.paradigm_options))
        versions = collect_versions(self.registry, (c.model, c.simulator, c.controller, paradigm))
        definitions = {cond.name: {**cond.to_json(), "source": self.library.sources.get(cond.name, "parametric")}
                       for cond in self.closure}
        settings = paradigm_settings(self.paradigm, self.registry, paradigm)
        config = {**c.to_json(), **({SETTINGS_KEY: settings} if settings else {}), "definitions": definitions,
                  "route_specs": {r.id: r.to_json() for r in (*c.routes, c.harvest_scenario)}}
        return {"format": RESULTS_FORMAT, "kind": "intervention", "config": config, "versions": versions}

    def run(self) -> dict[str, Any]:
        """Check, harvest, run every missing episode, then analyse the logs into ``OUT/intervention.json``."""
        from vladrivebench._engine.sweep import EPISODES_DIR, _remove_stale_partials, prepare_out

        for spec in (self.config.model, self.config.simulator, self.config.controller):
            self.registry.get(spec.kind, spec.name)
        manifest = self.manifest()
        check_paradigm_settings(self.out, manifest)
        model = self.component("model")
        self.model_name = self.config.model.name
        self.splicer = Splicer(model, self.library, {}, self.model_name)
        self.preflight(harvested=False)
        if self.lockstep():
            from vladrivebench._engine.sweep import check_lane_instances

            try:
                check_lane_instances(self.registry, (self.config.simulator, self.config.controller),
                                     self.config.batch)
            except VdbError:
                self.close()  # nothing runs: hold no simulator (a SUMO slot) for the next command
                raise
        prepare_out(self.out, manifest, optional=(SETTINGS_KEY,))
        note = self.unbatched_note()
        if note and self.on_note is not None:
            self.on_note(note)
        _remove_stale_partials(self.out / EPISODES_DIR)  # left by a killed run (a batch leaves several)
        self.versions = manifest["versions"]
        try:
            harvested = self.harvest() if self.harvest_names else {}
            self.injections = {k: v.injection for k, v in harvested.items()}
            self.splicer = Splicer(model, self.library, self.injections, self.model_name)
            if harvested:
                self.preflight(harvested=True)
            self.run_episodes()
        finally:
            self.close()
        return analyse(self.out, registry=self.registry)

    def preflight(self, *, harvested: bool) -> None:
        """Resolve and splice every condition on the first step of each route before any episode runs,
        so a condition the model cannot take is a one-line error and nothing is written."""
        from vladrivebench._engine.runner import (
            end_model_episode,
            episode_name,
            start_model_episode,
            with_episode,
        )

        sim, model = self.component("simulator"), self.component("model")
        seed = self.config.seeds[0]
        for route in self.config.routes:
            episode = f"{episode_name(route, seed)} preflight"
            obs = with_episode(sim.reset(route, seed), episode)
            start_model_episode(model, episode, seed)
            own, _ = own_step(model, obs, seed)
            resolver = self.splicer.resolver(own)
            for name in self.config.tested:
                needs_harvest = bool(set(self.library.harvest_names([name])))
                if needs_harvest != harvested:
                    continue
                self.splicer.splice(obs, name, self.splicer.injection(resolver, name), seed)
            end_model_episode(model, episode)

    def episode_path(self, episode: PlannedEpisode) -> Path:
        from vladrivebench._engine.sweep import EPISODES_DIR, episode_id

        eid = f"{episode_id(self.config.model.name, episode.route.id, episode.seed)}__{episode.name}"
        return self.out / EPISODES_DIR / f"{eid}.mcap"

    def harvest(self) -> dict[str, HarvestedText]:
        """Take each harvest condition's text from the baseline episode of the harvest route's first seed.

        In a lockstep run whose plan holds that baseline, its lockstep group is the run's first batch, so
        the baseline is logged exactly as the rest of the run computes it."""
        from vladrivebench._logs.episodes import read_episode

        route, seed = self.config.harvest_scenario, self.config.seeds[0]
        baseline = PlannedEpisode(route, seed, "baseline")
        chunks = self.lockstep_chunks() if self.lockstep() else []
        if chunks and baseline.key in {e.key for e in chunks[0]}:
            self.run_chunk(chunks[0], RunContext(self.config, self.splicer))
            path = self.episode_path(baseline)
        else:
            path = self.ensure_episode(baseline, BaselinePolicy())
        episode = read_episode(path)
        found = harvest_braking_cot(((s.step, s.cot, s.control) for s in episode.steps),
                                    self.component("model").cot_format, path.stem)
        if found is None:
            raise ConditionError(
                f"condition {self.harvest_names[0]!r}: model {self.model_name!r} never braked in the baseline "
                f"episode of route {route.id!r} (seed {seed}), so there is no braking CoT to harvest; use "
                f"--harvest-route with a route where it brakes (e.g. P.1 or C.1)")
        return {name: found for name in self.harvest_names}

    def planned(self) -> list[PlannedEpisode]:
        """The paradigm's plan, each episode with a log of its own."""
        plan = list(self.paradigm.plan(self.config))
        names = [episode.key for episode in plan]
        if len(set(names)) != len(names):
            raise VdbError(f"paradigm {self.config.mode!r} planned two episodes with the same route, seed and "
                           f"name; each planned episode needs its own log")
        return plan

    def run_episodes(self) -> None:
        """Every episode the paradigm plans, under the policy it gives, skipping complete logs (in lockstep
        batches when :meth:`lockstep` says so; on the executor's workers when it runs out of process)."""
        plan = self.planned()
        context = RunContext(self.config, self.splicer)
        if self.executor is not None and not getattr(self.executor, "in_process", False):
            self.run_on_executor(plan)
            return
        if self.lockstep():
            finished: list[PlannedEpisode] = []

            def report(episode: PlannedEpisode) -> None:
                finished.append(episode)
                self._report(episode, len(finished), len(plan))

            for chunk in self.lockstep_chunks():
                self.run_chunk(chunk, context, report)
            return
        for done, episode in enumerate(plan, start=1):
            self.ensure_episode(episode, self.paradigm.policy(episode, context))
            self._report(episode, done, len(plan))

    def run_on_executor(self, plan: Sequence[PlannedEpisode]) -> None:
        """The plan's shares without complete logs as :class:`InterventionJob` s on the executor's workers."""
        from vladrivebench._engine.executors import JobFailure
        from vladrivebench._engine.sweep import RegistrySpec

        lockstep = self.lockstep()
        shares = self.lockstep_chunks() if lockstep else [[episode] for episode in plan]
        registry = RegistrySpec.of(self.registry)
        jobs, finished = [], 0
        for share in shares:
            if all(self.complete(episode) for episode in share):
                for episode in share:
                    finished += 1
                    self._report(episode, finished, len(plan))
                continue
            jobs.append(InterventionJob(self.config, str(self.out), tuple(share), lockstep,
                                        dict(self.injections), dict(self.versions), registry))
        stream = self.executor.run(run_intervention_job, jobs)
        try:
            for item in stream:
                if isinstance(item, JobError):
                    raise item.error()
                if isinstance(item, JobFailure):
                    raise VdbError(f"intervention episodes from {item.job.share_name()} failed in a worker: "
                                   f"{item.error}")
                for episode in item:
                    finished += 1
                    self._report(episode, finished, len(plan))
        finally:
            close = getattr(stream, "close", None)
            if callable(close):
                close()

    def complete(self, episode: PlannedEpisode) -> bool:
        """Whether ``episode`` has a complete log."""
        from vladrivebench._logs.episodes import read_result

        path = self.episode_path(episode)
        return path.exists() and read_result(path) is not None

    def attach(self, injections: Mapping[str, Any], versions: Mapping[str, Any]) -> None:
        """Ready a worker's copy of the run to log episodes: the harvested texts and the recorded versions the
        driver found (a worker never harvests, prepares the directory or analyses)."""
        self.model_name = self.config.model.name
        self.injections = dict(injections)
        self.splicer = Splicer(self.component("model"), self.library, self.injections, self.model_name)
        self.versions = dict(versions)

    def _report(self, episode: PlannedEpisode, done: int, total: int) -> None:
        if self.progress is not None:
            self.progress(f"{episode.route.id} seed {episode.seed} {episode.name}", done, total)

    # -- lockstep batches (--batch B) --
    def lockstep(self) -> bool:
        """Whether the planned episodes advance in lockstep: ``--batch`` above 1, a
        :class:`~vladrivebench.BatchedParadigm` and a :class:`~vladrivebench.BatchedModel` with
        ``splice_cot_batch`` (without it a selfsplice could not mirror the batched generation)."""
        from vladrivebench.protocols import BatchedModel, BatchedParadigm

        model = self.component("model")
        return (self.config.batch > 1 and isinstance(self.paradigm, BatchedParadigm)
                and isinstance(model, BatchedModel) and callable(getattr(model, "splice_cot_batch", None)))

    def unbatched_note(self) -> str | None:
        """What to tell the user when ``--batch`` is above 1 but :meth:`lockstep` is not possible (the paradigm
        or the model lacks the capability), else ``None``; one line naming each component that lacks it."""
        from vladrivebench.protocols import BatchedModel, BatchedParadigm

        if self.config.batch == 1 or self.lockstep():
            return None
        c, model = self.config, self.component("model")
        reasons = []
        if not isinstance(self.paradigm, BatchedParadigm):
            reasons.append(f"paradigm {c.mode!r} has no batched step (BatchedParadigm)")
        if not isinstance(model, BatchedModel):
            reasons.append(f"model {c.model.name!r} has no batched forms")
        elif not callable(getattr(model, "splice_cot_batch", None)):
            reasons.append(f"model {c.model.name!r} has no splice_cot_batch")
        return f"{' and '.join(reasons)}; {'its' if len(reasons) == 1 else 'the'} episodes run one at a time"

    def lockstep_chunks(self) -> list[list[PlannedEpisode]]:
        """The plan cut into fixed lockstep runs: the harvest baseline's lockstep group first (when the run
        harvests and plans that baseline), then up to ``BATCH_JOB_FACTOR × batch`` consecutive episodes each,
        never splitting a lockstep group. They depend only on the configuration, so a resumed run gives every
        episode the same batch-mates."""
        from vladrivebench._engine.sweep import BATCH_JOB_FACTOR

        plan = self.planned()
        groups = [self.paradigm.lockstep_group(e) for e in plan]
        first: list[int] = []
        if self.harvest_names:
            key = (self.config.harvest_scenario.id, self.config.seeds[0], "baseline")
            at = [i for i, e in enumerate(plan) if e.key == key]
            if at:
                group = groups[at[0]]
                first = [i for i in range(len(plan)) if i == at[0] or (group is not None and groups[i] == group)]
        rest = [i for i in range(len(plan)) if i not in set(first)]
        size = BATCH_JOB_FACTOR * self.config.batch
        chunks, current = ([first] if first else []), []
        for n, i in enumerate(rest):
            current.append(i)
            following = rest[n + 1] if n + 1 < len(rest) else None
            if len(current) >= size and (following is None or groups[i] is None or groups[following] != groups[i]):
                chunks.append(current)
                current = []
        if current:
            chunks.append(current)
        return [[plan[i] for i in chunk] for chunk in chunks]

    def run_chunk(self, chunk: Sequence[PlannedEpisode], context: RunContext,
                  report: Callable[[PlannedEpisode], None] | None = None) -> None:
        """Run ``chunk`` in lockstep, logging the episodes without a complete log; the complete ones run
        again unlogged (only when some are missing) so every episode has its first run's batch-mates."""
        from vladrivebench._engine.runner import LockstepEpisode, run_lockstep
        from vladrivebench._engine.sweep import pipeline_turns

        report = report or (lambda episode: None)
        complete = {e.key for e in chunk if self.complete(e)}
        if len(complete) == len(chunk):
            for episode in chunk:
                report(episode)
            return
        writers: dict[tuple, Any] = {}
        episodes = []
        for planned in chunk:
            policy = self.paradigm.policy(planned, context)
            opener = None
            if planned.key not in complete:
                self.episode_path(planned).unlink(missing_ok=True)
                opener = self._writer_opener(planned, writers)
            wrap = policy.wrap_controller if isinstance(policy, WrapsController) else None
            episodes.append(LockstepEpisode((planned, policy), planned.route, planned.seed, opener, policy=policy,
                                            wrap_controller=wrap, group=self.paradigm.lockstep_group(planned),
                                            name=planned.episode))

        def done(episode: LockstepEpisode, finished: Any, writer: Any) -> None:
            from vladrivebench._engine.runner import EpisodeFailure

            planned = episode.key[0]
            writers.pop(planned.key, None)
            if isinstance(finished, EpisodeFailure):
                if writer is not None:
                    writer.__exit__(EpisodeFailure, finished, None)
                raise _episode_error(self.episode_path(planned), finished)
            if writer is not None:
                writer.finish(finished.to_json())
                writer.__exit__(None, None, None)
            report(planned)

        def step_batch(model: Any, lanes: Sequence[LockstepEpisode], observations: Sequence[Observation]) -> list:
            return self.paradigm.step_batch(model, [LaneStep(e.key[0], e.key[1], obs, e.seed) for e, obs in
                                                    zip(lanes, observations, strict=True)], context)

        c = self.config
        names = {"model": c.model.name, "simulator": c.simulator.name, "controller": c.controller.name}
        try:
            run_lockstep(episodes, c.batch, make_lane=self.lane, done=done, names=names,
                         episode_batch_policy=step_batch, **pipeline_turns())
        except BaseException as exc:
            for writer in writers.values():  # abandoned: their partial logs are removed
                writer.__exit__(type(exc), exc, None)
            raise

    def lane(self, index: int) -> tuple[Any, Any, Any]:
        """Lane ``index``'s ``(model, simulator, controller)``: the one model, a simulator and controller each."""
        model = self.component("model")
        if index == 0:
            return model, self.component("simulator"), self.component("controller")
        key = f"lane{index}"
        if key not in self._components:
            c = self.config
            self._components[key] = (self.registry.create("simulator", c.simulator.name, c.simulator.options),
                                     self.registry.create("controller", c.controller.name, c.controller.options))
        return (model, *self._components[key])

    def _writer_opener(self, planned: PlannedEpisode, writers: dict[tuple, Any]) -> Callable[[], Any]:
        from vladrivebench._logs.episodes import EpisodeWriter

        def open_writer() -> Any:
            writer = EpisodeWriter(self.episode_path(planned), self.episode_meta(planned)).__enter__()
            writers[planned.key] = writer
            return writer

        return open_writer

    def episode_meta(self, episode: PlannedEpisode) -> dict[str, Any]:
        """The metadata record of ``episode``'s log."""
        from vladrivebench._engine.sweep import EpisodeJob, episode_meta

        path, c = self.episode_path(episode), self.config
        job = EpisodeJob(path.stem, str(path), episode.route, episode.seed, c.model, c.simulator, c.controller,
                         {"intervention": c.to_json()}, dict(self.versions))
        meta = episode_meta(job, self.component("model"), self.component("simulator"), self.registry)
        meta["intervention"] = {"mode": c.mode, "role": episode.role, "condition": episode.condition}
        return meta

    def ensure_episode(self, episode: PlannedEpisode, policy: Any) -> Path:
        """Run one episode into its log unless a complete log is already there; return its path."""
        from vladrivebench._engine.runner import EpisodeFailure, run_episode
        from vladrivebench._logs.episodes import EpisodeWriter

        path = self.episode_path(episode)
        if self.complete(episode):
            return path
        path.unlink(missing_ok=True)
        model, sim = self.component("model"), self.component("simulator")
        controller: Any = self.component("controller")
        if isinstance(policy, WrapsController):
            controller = policy.wrap_controller(controller)
        c, route, seed = self.config, episode.route, episode.seed
        meta = self.episode_meta(episode)
        try:
            with EpisodeWriter(path, meta) as writer:
                result = run_episode(model, sim, controller, route, seed, policy=policy, writer=writer,
                                     model_name=c.model.name, simulator_name=c.simulator.name,
                                     controller_name=c.controller.name, episode=episode.episode)
                writer.finish(result.to_json())
        except EpisodeFailure as exc:
            raise _episode_error(path, exc) from None
        return path


def _episode_error(path: Path, failure: Exception) -> VdbError:
    """The one-line error a failed episode stops the run with (its cause's, when that was a VdbError)."""
    cause = failure.__cause__
    if isinstance(cause, VdbError):
        return type(cause)(str(cause))
    return VdbError(f"episode {path.stem} failed: {failure}")


@dataclass(frozen=True)
class InterventionJob:
    """One share of an intervention run for an executor's worker (picklable): a lockstep chunk, or one
    episode of an unbatched run, with what the driver found before (harvested texts, component versions)."""

    config: InterventionConfig
    out: str
    episodes: tuple[PlannedEpisode, ...]
    lockstep: bool
    injections: Mapping[str, Any]
    versions: Mapping[str, Any]
    registry: Any

    def share_name(self) -> str:
        first = self.episodes[0]
        more = f" and {len(self.episodes) - 1} more" if len(self.episodes) > 1 else ""
        return f"{first.route.id} seed {first.seed} {first.name}{more}"


@dataclass(frozen=True)
class JobError:
    """The one-line error that stopped a worker's share, sent back for the driver to raise as it was."""

    message: str
    exit_code: int

    def error(self) -> VdbError:
        error = VdbError(self.message)
        error.exit_code = self.exit_code
        return error


def run_intervention_job(job: InterventionJob) -> list[PlannedEpisode] | JobError:
    """Worker: log ``job``'s episodes that lack a complete log; its episodes, or the one-line error that
    stopped them (a :class:`JobError`: an exception's own class need not survive pickling)."""
    from vladrivebench._engine.sweep import _registry_for

    run = InterventionRun(job.config, job.out, registry=_registry_for(job.registry))
    try:
        run.attach(job.injections, job.versions)
        context = RunContext(job.config, run.splicer)
        if job.lockstep:
            run.run_chunk(job.episodes, context)
        else:
            for episode in job.episodes:
                run.ensure_episode(episode, run.paradigm.policy(episode, context))
    except VdbError as exc:
        return JobError(str(exc), exc.exit_code)
    finally:
        run.close()
    return list(job.episodes)


def paradigm_settings(paradigm: Any, registry: Any, spec: Any) -> dict[str, Any]:
    """Every setting ``paradigm`` (built from ``spec``) runs with, as JSON: its ``effective_options()``
    (:class:`~vladrivebench.protocols.EffectiveOptions`) when it has the method, else the options given merged
    with the defaults of its factory's signature that are plain JSON values (a sentinel object's text would
    differ from process to process, and so refuse every resume)."""
    from vladrivebench.protocols import EffectiveOptions

    if not isinstance(paradigm, EffectiveOptions):
        return _plain({**_json_defaults(registry.get("paradigm", spec.name).factory), **dict(spec.options)})
    settings = paradigm.effective_options()
    if not isinstance(settings, Mapping) or not all(isinstance(k, str) for k in settings):
        raise VdbError(f"paradigm {spec.name!r} (plugin {registry.get('paradigm', spec.name).plugin!r}): "
                       f"effective_options() returned {type(settings).__name__}, expected a mapping of option "
                       f"name → value")
    return _plain(dict(settings))


def _json_defaults(factory: Any) -> dict[str, Any]:
    """The keyword defaults of ``factory``'s signature that JSON can hold as they are."""
    import inspect

    try:
        parameters = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):
        return {}
    defaults = {}
    for p in parameters:
        if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and p.default is not p.empty:
            try:
                json.dumps(p.default)
            except (TypeError, ValueError):
                continue
            defaults[p.name] = p.default
    return defaults


def check_paradigm_settings(out: Path, manifest: Mapping[str, Any]) -> None:
    """Refuse, in one line and before anything is touched, to resume a run of the same paradigm, asked with the
    same options, whose recorded settings (``SETTINGS_KEY``) differ from this run's: a default of the paradigm
    changed since (e.g. its plugin was upgraded). The line names the first differing setting.

    A directory whose manifest does not record the settings (written before they were recorded) is accepted,
    as before: its settings are unknown. Every other difference, other options given included, is
    :func:`~vladrivebench._engine.sweep.prepare_out`'s to refuse."""
    from vladrivebench._engine.sweep import MANIFEST_NAME, read_manifest

    path = out / MANIFEST_NAME
    if not path.is_file():
        return
    before, now = read_manifest(path)["config"], _plain(manifest["config"])
    if (SETTINGS_KEY not in before or before.get("mode") != now["mode"]
            or before.get("paradigm_options", {}) != now.get("paradigm_options", {})):
        return
    recorded, current = before[SETTINGS_KEY], now.get(SETTINGS_KEY, {})
    if not isinstance(recorded, dict):
        return  # not a record of settings: prepare_out names the difference
    changed = next((key for key in sorted(set(recorded) | set(current))
                    if recorded.get(key, _MISSING) != current.get(key, _MISSING)), None)
    if changed is not None:
        raise ConfigError(
            f"{out} holds a run with a different configuration (paradigm {now['mode']!r} setting {changed}: "
            f"{_setting(current.get(changed, _MISSING))} now, {_setting(recorded.get(changed, _MISSING))} before; "
            f"the options given are the same, so a default of the paradigm changed since that run); resuming "
            f"would mix episodes made under both, so use another --out")


_MISSING = object()


def _setting(value: Any) -> str:
    from vladrivebench._engine.sweep import _short

    return "absent" if value is _MISSING else _short(value)


def build_paradigm(registry: Any, name: str, options: Mapping[str, Any] | None = None) -> Any:
    """The registered paradigm ``name`` built with ``options`` (an unknown name: one line with suggestions)."""
    from vladrivebench.protocols import Paradigm

    paradigm = registry.create("paradigm", name, dict(options or {}))
    if not isinstance(paradigm, Paradigm):
        missing = [m for m in ("name", "default_conditions", "check", "plan", "policy", "analyse", "tables")
                   if not hasattr(paradigm, m)]
        raise VdbError(f"paradigm {name!r} (plugin {registry.get('paradigm', name).plugin!r}) is not a "
                       f"Paradigm: it lacks {', '.join(missing)}")
    return paradigm


# -- analysis (from the logs only) --------------------------------------------------------------------
def load_manifest(out: Path | str) -> dict[str, Any]:
    from vladrivebench._engine.sweep import MANIFEST_NAME

    path = Path(out) / MANIFEST_NAME
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LogError(f"{out}: no {MANIFEST_NAME}; not an intervention run directory") from None
    except (OSError, ValueError) as exc:
        raise LogError(f"{path}: unreadable manifest ({exc})") from None
    if manifest.get("kind") != "intervention":
        raise LogError(f"{out}: the run in this directory is not an intervention run (vdb intervene)")
    return manifest


class LoggedEpisodes(dict):
    """The logged episodes of a run by ``(route id, seed, name)`` (name = the planned episode's condition
    or role, e.g. ``("E.1", 0, "baseline")``, ``("E.1", 0, "car")``); :meth:`require` for one that must be
    there."""

    def require(self, route: str, seed: int, name: str) -> Any:
        """The episode, or a one-line :class:`LogError` saying the run is incomplete."""
        key = (route, seed, name)
        if key not in self:
            raise LogError(f"the intervention run lacks the {name} episode of route {route} seed {seed}; run the "
                           f"same `vdb intervene` command again to complete it")
        return self[key]


def _episodes_by_role(out: Path) -> LoggedEpisodes:
    from vladrivebench._logs.episodes import find_episodes, read_episode

    found = LoggedEpisodes()
    for path in find_episodes(out):
        episode = read_episode(path)
        info = episode.meta.get("intervention") or {}
        role = info.get("condition") or info.get("role")
        if role:
            found[(episode.scenario_id, episode.seed, role)] = episode
    return found


def analyse(out: Path | str, *, write: bool = True, registry: Any = None) -> dict[str, Any]:
    """Compute the results of the intervention run in ``out`` from its logs (and write ``intervention.json``).

    The header (configuration), the selfsplice gate and the harvested texts are the core's; the rest is
    what the run's paradigm (``registry``'s, default: the installed plugins') returns from its ``analyse``.
    """
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.sweep import write_json_atomic

    out = Path(out)
    manifest = load_manifest(out)
    config = manifest["config"]
    paradigm = build_paradigm(registry or get_registry(), config["mode"], config.get("paradigm_options"))
    episodes = _episodes_by_role(out)
    options = {"paradigm_options": config["paradigm_options"]} if config.get("paradigm_options") else {}
    results: dict[str, Any] = {
        "format": RESULTS_FORMAT, "mode": config["mode"], **options, "model": config["model"],
        "routes": config["routes"], "seeds": config["seeds"], "conditions": config["conditions"],
        "definitions": config["definitions"], "horizons": config["horizons"],
        "checkpoints": config["checkpoints"], "threshold": config["threshold"], "alpha": config["alpha"],
        "confidence": config["confidence"],
    }
    gate = GateTally()
    own = paradigm.analyse(config, episodes, gate)
    clash = sorted(set(own) & set(RESERVED_RESULT_KEYS))
    if clash:
        raise VdbError(f"paradigm {config['mode']!r} returned the result key {clash[0]!r}, which the core "
                       f"writes itself (reserved: {', '.join(RESERVED_RESULT_KEYS)})")
    results.update(own)
    results["gate"] = gate.to_json()
    results["valid"] = gate.valid
    results["harvested"] = _harvest_record(config, episodes)
    if write:
        write_json_atomic(out / RESULTS_NAME, results)
    return results


@dataclass
class GateTally:
    """The selfsplice gate over every checked step of a run.

    A paradigm's ``analyse`` adds each logged gate record (:func:`gate_record`) with :meth:`add` (or all of
    an episode's with :meth:`add_episode`) and each selfsplice episode that drove differently from its
    baseline to ``episode_mismatches``; the run is valid when at least one step was checked and none failed.
    """

    steps: int = 0
    failed: int = 0
    digest_mismatches: int = 0
    max_trajectory_diff: float = 0.0
    first_failure: dict[str, Any] | None = None
    episode_mismatches: list[str] = field(default_factory=list)
    fidelity_steps: int = 0
    fidelity_failed: int = 0
    max_fidelity_cache_diff: float = 0.0
    max_fidelity_trajectory_diff: float = 0.0

    def add(self, record: Mapping[str, Any] | None, where: dict[str, Any]) -> None:
        """Count one step's gate ``record`` (ignored when empty); ``where`` locates it for the report."""
        if not record:
            return
        self.steps += 1
        diff = float(record.get("trajectory_diff", 0.0))
        self.max_trajectory_diff = max(self.max_trajectory_diff, diff)
        if not record.get("digest_equal", False):
            self.digest_mismatches += 1
        self._add_fidelity(record)
        if not record.get("ok", False):
            self.failed += 1
            if self.first_failure is None:
                self.first_failure = {**where, "trajectory_diff": diff,
                                      "digest_equal": bool(record.get("digest_equal"))}
                if "fidelity_ok" in record:
                    self.first_failure["fidelity_ok"] = bool(record["fidelity_ok"])

    def _add_fidelity(self, record: Mapping[str, Any]) -> None:
        if "fidelity_ok" not in record:
            return
        self.fidelity_steps += 1
        self.fidelity_failed += 0 if record["fidelity_ok"] else 1
        self.max_fidelity_cache_diff = max(self.max_fidelity_cache_diff, float(record["fidelity_cache_diff"]))
        self.max_fidelity_trajectory_diff = max(self.max_fidelity_trajectory_diff,
                                                float(record["fidelity_trajectory_diff"]))

    def add_episode(self, episode: Any, route: str, seed: int, role: str) -> None:
        """Count the gate record (``extras["intervention"]["gate"]``) of every step of ``episode``."""
        for step in episode.steps:
            info = step.extras.get("intervention") or {}
            self.add(info.get("gate"), {"route": route, "seed": seed, "step": step.step, "role": role})

    @property
    def valid(self) -> bool:
        return self.steps > 0 and self.failed == 0 and not self.episode_mismatches

    def to_json(self) -> dict[str, Any]:
        return {"steps_checked": self.steps, "steps_failed": self.failed,
                "digest_mismatches": self.digest_mismatches, "max_trajectory_diff": self.max_trajectory_diff,
                "first_failure": self.first_failure, "episode_mismatches": self.episode_mismatches,
                "valid": self.valid, **self._fidelity_json()}

    def _fidelity_json(self) -> dict[str, Any]:
        if not self.fidelity_steps:
            return {}
        return {"fidelity_steps_checked": self.fidelity_steps, "fidelity_steps_failed": self.fidelity_failed,
                "max_fidelity_cache_diff": self.max_fidelity_cache_diff,
                "max_fidelity_trajectory_diff": self.max_fidelity_trajectory_diff}


def gate_message(results: Mapping[str, Any]) -> str | None:
    """One loud line when the selfsplice gate failed (or checked nothing), else ``None``."""
    gate = results.get("gate") or {}
    if results.get("valid"):
        return None
    if not gate.get("steps_checked"):
        return "INVALID RUN: the selfsplice gate checked no step"
    first = gate.get("first_failure") or {}
    where = f" (first at {first.get('route')} seed {first.get('seed')} step {first.get('step')})" if first else ""
    parts = [f"selfsplice differs from the model's own CoT at {gate['steps_failed']} of {gate['steps_checked']} "
             f"steps{where}", f"state digest mismatches: {gate['digest_mismatches']}",
             f"largest trajectory difference: {gate['max_trajectory_diff']:.3g} m"]
    if gate.get("fidelity_steps_failed") and not gate["digest_mismatches"] and not gate["max_trajectory_diff"]:
        parts = [f"selfsplice holds but the gate failed at {gate['steps_failed']} of {gate['steps_checked']} "
                 f"steps{where}"]
    if gate.get("episode_mismatches"):
        parts.append(f"selfsplice episodes differing from their baseline: {', '.join(gate['episode_mismatches'])}")
    if gate.get("fidelity_steps_failed"):
        parts.append(f"spliced state differs from the model's native forward pass at {gate['fidelity_steps_failed']} "
                     f"of {gate['fidelity_steps_checked']} steps (largest cache difference "
                     f"{gate['max_fidelity_cache_diff']:.3g}, trajectory {gate['max_fidelity_trajectory_diff']:.3g} m)")
    return "INVALID RUN: " + "; ".join(parts) + " — the splice pipeline is not artifact-free"


def episode_summary(episode: Any, checkpoints: Sequence[float], *, baseline: bool) -> EpisodeSummary:
    """The closed-loop figures of one episode log (distances at the checkpoints, brakes, speed …).

    ``baseline=False`` counts the shadow's brakes from the logged ``shadow`` records of an
    :class:`InjectionPolicy` episode; for a baseline they equal its own brakes.
    """
    steps = episode.steps
    times = [s.time for s in steps]
    xy = [(s.ego.x, s.ego.y) for s in steps]
    brakes = sum(1 for s in steps if s.control.brake > 0.0)
    if baseline:
        shadow = brakes
    else:
        shadow = sum(1 for s in steps
                     if float(((s.extras.get("intervention") or {}).get("shadow") or {}).get("brake", 0.0)) > 0.0)
    result = episode.result or {}
    speeds = [s.ego.speed for s in steps]
    return EpisodeSummary(
        seed=episode.seed, steps=len(steps), duration_s=(times[-1] - times[0]) if times else 0.0,
        mean_speed=float(np.mean(speeds)) if speeds else math.nan,
        route_completion=float(result.get("route_completion", math.nan)),
        completed=result.get("terminal") == "route_complete", collided=int(result.get("collisions", 0)) > 0,
        brake_steps=brakes, shadow_brake_steps=shadow,
        distances=tuple(cumulative_distance(times, xy, checkpoints)), terminal=result.get("terminal"),
    )


def _harvest_record(config: Mapping, episodes: Mapping) -> dict[str, Any]:
    names = [n for n, d in config["definitions"].items() if d.get("kind") == "harvest"]
    if not names:
        return {}
    route, seed = config["harvest_route"], config["seeds"][0]
    episode = episodes.get((route, seed, "baseline"))
    fmt = (episode.meta.get("model") or {}).get("cot_format") if episode else None
    if episode is None or not fmt:
        return {}
    from vladrivebench.records import CoTFormat

    cot_format = CoTFormat(fmt.get("kind", "sentence"), tuple(fmt.get("slots") or ()), fmt.get("max_tokens"))
    found = harvest_braking_cot(((s.step, s.cot, s.control) for s in episode.steps), cot_format, episode.path.stem)
    return {name: found.to_json() for name in names} if found else {}


# -- results ------------------------------------------------------------------------------------------
def load_results(out: Path | str) -> dict[str, Any] | None:
    """The results JSON of an intervention run directory, or ``None`` when there is none."""
    path = Path(out) / RESULTS_NAME
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise LogError(f"{path}: unreadable intervention results ({exc}); rerun `vdb intervene` to rewrite "
                       f"them") from None


def seed_plan(results: Mapping[str, Any], *, effect_m: float | None = None, power: float = 0.8,
              alpha: float | None = None, registry: Any = None) -> list[dict[str, Any]]:
    """Seeds needed per condition from a pilot run's results (the effects its paradigm names, e.g. open-loop:
    first horizon; closed-loop: last checkpoint), at ``alpha`` divided by the number of tested conditions
    (Holm's first step)."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench.protocols import PilotEffects

    mode = results.get("mode")
    paradigm = build_paradigm(registry or get_registry(), mode, results.get("paradigm_options"))
    if not isinstance(paradigm, PilotEffects):
        raise ConfigError(f"--plan: paradigm {mode!r} does not say which effect to size a study by (it has no "
                          f"pilot_effects)")
    alpha = results.get("alpha", DEFAULT_ALPHA) if alpha is None else alpha
    tested = [c for c in results["conditions"] if c != SELFSPLICE]
    plans = []
    for route in results["routes"]:
        for condition, seed_means, what in paradigm.pilot_effects(results, route):
            if condition == SELFSPLICE:
                continue
            try:
                plan = plan_seeds(condition, seed_means, effect_m=effect_m, power=power, alpha=alpha,
                                  family_size=len(tested))
            except ValueError as exc:
                raise ConfigError(f"--plan: {exc}; run the pilot with --seeds 2 or more") from None
            plans.append({"route": route, "measure": what, **plan.to_json()})
    return plans
