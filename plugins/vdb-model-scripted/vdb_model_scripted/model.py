"""The scripted reference VLA: the calibration target of every metric in the benchmark.

Perception is the step's ground truth (privileged). ``generate_cot`` writes a templated CoT whose errors
(missed critical feature, wrong light colour, hallucinated road user, contradiction) happen with exactly
the configured probabilities, and records what it did in the CoT state (:func:`cot_truth`).

``decode_action`` mixes two target-speed profiles with the coupling weight ``alpha``::

    v_target = alpha · v_cot + (1 − alpha) · v_percept  (+ action-head noise)

``v_cot`` follows the CoT's stated intent only (as the model's reader understands the text), ``v_percept``
the ground truth only. With ``alpha = 0`` no text can change the action (exactly); with ``alpha = 1`` the
action follows the CoT alone. Waypoints are placed along the route's lane centre.

The CoT state is made by *reading the text* with the same function for generated and spliced CoTs, so a
selfsplice has the same :meth:`ScriptedModel.state_digest` and, with the same RNG, the same trajectory.

Its one piece of memory, the stop signs at which the ego has made its stop, is kept per episode under
``obs.episode`` (:class:`~vladrivebench.EpisodeMemory`), so one instance serves a whole lockstep batch
(:class:`~vladrivebench.BatchedModel`) and every row sees exactly what it would see alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from vladrivebench import (
    ConfigError,
    CoT,
    CoTFormat,
    ModelOutputError,
    Observation,
    Trajectory,
    TrajectorySpec,
)

from .policy import (
    DT,
    MAX_SPEED,
    STEPS,
    World,
    arc_lengths,
    cot_decision,
    decide,
    perceive,
    place_along_route,
    plan_speeds,
    stopped_at_sign,
)
from .reading import SLOTS, CoTReading, read_sentence, read_slots
from .writing import N_DRAWS, Rates, compose

COT_FORMATS = ("sentence", "qa")


@dataclass(frozen=True)
class ScriptedState:
    """The scripted model's CoT state: the ``reading`` the action head uses, and — for a CoT the model
    generated itself — the ``truth`` of what it wrote (``None`` for a spliced CoT)."""

    reading: CoTReading
    truth: dict[str, Any] | None = None


def cot_truth(cot: CoT) -> dict[str, Any] | None:
    """What the scripted model knows about a CoT it generated, else ``None``.

    Keys: ``mentioned`` (``None`` when the step has no critical feature; ``False`` when it was missed
    or is not ahead within ``perception_range``), ``in_range`` (it is ahead within range, so it is
    mentioned unless missed with probability ``miss_rate``), ``critical_kind``,
    ``light_stated``, ``light_wrong``, ``hallucinated``, ``phantom`` (its kind), ``contradiction``,
    ``decision`` (the policy's decision on the CoT's belief) and ``stated_action`` (the intent the
    model's reader finds in the text: ``maintaining``/``accelerating``/``decelerating``/
    ``keep_distance``/``none``).
    """
    state = cot.state
    return dict(state.truth) if isinstance(state, ScriptedState) and state.truth is not None else None


class ScriptedModel:
    """A VLA with known CoT error rates and CoT–action coupling ``alpha`` (see the module docstring).

    Batched forms (``generate_cot_batch``, ``splice_cot_batch``, ``decode_action_batch``) give each row
    exactly what the per-episode method gives it with the same RNG: the model is rules over the ground
    truth, with no per-call overhead to amortise, so a batch is one instance and one call, not faster
    arithmetic.
    """

    trajectory_spec = TrajectorySpec(horizon_s=3.0, rate_hz=10.0)

    def __init__(self, *, alpha: float = 0.5, miss_rate: float = 0.0, hallucination_rate: float = 0.0,
                 contradiction_rate: float = 0.0, light_error_rate: float = 0.0, cot_format: str = "sentence",
                 cruise_speed: float = 6.5, perception_range: float = 80.0, noise: float = 0.05):
        self.alpha = _fraction("alpha", alpha)
        self.rates = Rates(miss=_fraction("miss_rate", miss_rate),
                           hallucination=_fraction("hallucination_rate", hallucination_rate),
                           contradiction=_fraction("contradiction_rate", contradiction_rate),
                           light_error=_fraction("light_error_rate", light_error_rate))
        if cot_format not in COT_FORMATS:
            raise ConfigError(f"model 'scripted': option cot_format must be 'sentence' or 'qa', got {cot_format!r}")
        self.format_name = cot_format
        self.cot_format = (CoTFormat("sentence") if cot_format == "sentence" else CoTFormat("slots", SLOTS))
        self.cruise_speed = _number("cruise_speed", cruise_speed, 0.5, MAX_SPEED, "in [0.5, 8.5] m/s")
        self.perception_range = _number("perception_range", perception_range, 1.0, 1000.0, "in [1, 1000] m")
        self.noise = _number("noise", noise, 0.0, 2.0, "in [0, 2] m/s")
        self._stops_made: dict[str, set[str]] = {}

    def options(self) -> dict[str, Any]:
        """The model's options, as given to the factory."""
        return {"alpha": self.alpha, "miss_rate": self.rates.miss, "hallucination_rate": self.rates.hallucination,
                "contradiction_rate": self.rates.contradiction, "light_error_rate": self.rates.light_error,
                "cot_format": self.format_name, "cruise_speed": self.cruise_speed,
                "perception_range": self.perception_range, "noise": self.noise}

    def reset(self, seed: int) -> None:
        """Forget every episode's memory (the runner calls :meth:`start_episode` instead)."""
        self._stops_made.clear()

    def start_episode(self, episode: str, seed: int) -> None:
        """Episode ``episode`` starts with no stop made."""
        self._stops_made[episode] = set()

    def end_episode(self, episode: str) -> None:
        """Drop the memory of episode ``episode``."""
        self._stops_made.pop(episode, None)

    def perceive(self, obs: Observation) -> World:
        """The ground truth within range, plus whether the stop at the critical stop sign has been made.

        The memory is the episode's (``obs.episode``), updated from observations only (never from a CoT
        or an RNG), and seeing the same observation again changes nothing, so generating, splicing and
        decoding at a step in any number and order give the same results.
        """
        world = perceive(obs, self.perception_range)
        critical = obs.ground_truth.critical_id
        if world.critical_kind != "stop_sign" or critical is None or world.distance is None:
            return world
        stops_made = self._stops_made.setdefault(obs.episode, set())
        if stopped_at_sign(max(obs.ego.speed, 0.0), world.distance):
            stops_made.add(critical)
        return replace(world, stop_made=critical in stops_made)

    # -- CoT ------------------------------------------------------------------------------------------
    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        """The model's own CoT; draws exactly :data:`~vdb_model_scripted.writing.N_DRAWS` uniforms."""
        draws = rng.random(N_DRAWS)
        draft = compose(obs, self.perceive(obs), draws, self.rates, self.cruise_speed,
                        self.format_name)
        content: str | dict[str, str] = draft.slots if self.cot_format.is_slotted else draft.text
        cot = self._cot(content, spliced=False)
        truth = {**draft.truth, "stated_action": cot.state.reading.intent}
        return CoT(cot.text, cot.slots, ScriptedState(cot.state.reading, truth), spliced=False)

    def splice_cot(self, obs: Observation, text: str | Mapping[str, str], rng: np.random.Generator) -> CoT:
        """The CoT as if the model had written ``text``; the state is read from the text alone.

        A ``sentence`` model takes a string (a mapping is joined in its order). A ``qa`` model takes a
        mapping of some of ``scene``/``objects``/``decision`` (missing slots are empty); a plain string
        is taken as the ``decision`` answer with empty ``scene`` and ``objects``.
        """
        return self._cot(self._content(text), spliced=True)

    # -- batched forms (lockstep episodes) -----------------------------------------------------------
    def generate_cot_batch(self, observations: Sequence[Observation],
                           rngs: Sequence[np.random.Generator]) -> list[CoT]:
        """:meth:`generate_cot` for each observation, row ``i`` drawing from ``rngs[i]``."""
        return [self.generate_cot(obs, rng) for obs, rng in zip(observations, rngs, strict=True)]

    def splice_cot_batch(self, observations: Sequence[Observation], texts: Sequence[str | Mapping[str, str]],
                         rngs: Sequence[np.random.Generator]) -> list[CoT]:
        """:meth:`splice_cot` for each (observation, text) pair."""
        return [self.splice_cot(obs, text, rng) for obs, text, rng in zip(observations, texts, rngs, strict=True)]

    def decode_action_batch(self, observations: Sequence[Observation], cots: Sequence[CoT],
                            rngs: Sequence[np.random.Generator]) -> list[Trajectory]:
        """:meth:`decode_action` for each (observation, CoT) pair, row ``i``'s noise from ``rngs[i]``."""
        return [self.decode_action(obs, cot, rng) for obs, cot, rng in zip(observations, cots, rngs, strict=True)]

    def _content(self, text: Any) -> str | dict[str, str]:
        if isinstance(text, str):
            return {"scene": "", "objects": "", "decision": text} if self.cot_format.is_slotted else text
        if not isinstance(text, Mapping) or not all(isinstance(v, str) for v in text.values()):
            raise ConfigError(f"model 'scripted': a CoT must be a string or a mapping slot → string, "
                              f"got {type(text).__name__}")
        if not self.cot_format.is_slotted:
            return " ".join(v for v in text.values() if v)
        unknown = [k for k in text if k not in SLOTS]
        if unknown:
            raise ConfigError(f"model 'scripted' (qa): unknown CoT slot {unknown[0]!r}; "
                              f"expected some of {', '.join(SLOTS)}")
        return {name: text.get(name, "") for name in SLOTS}

    def _cot(self, content: str | dict[str, str], *, spliced: bool) -> CoT:
        if isinstance(content, dict):
            return CoT(CoT.join_slots(content), dict(content), ScriptedState(read_slots(content)), spliced)
        return CoT(content, {}, ScriptedState(read_sentence(content)), spliced)

    def reading(self, cot: CoT) -> CoTReading:
        """What the action head reads from ``cot`` (read from its text when it carries no scripted state)."""
        if isinstance(cot.state, ScriptedState):
            return cot.state.reading
        if self.cot_format.is_slotted and cot.slots:
            return read_slots(cot.slots)
        return read_sentence(cot.text) if not self.cot_format.is_slotted else read_slots({"decision": cot.text})

    def cot_extras(self, cot: CoT) -> dict[str, Any] | None:
        """``{"scripted_truth": cot_truth(cot)}`` for a CoT the model generated (the runner's default
        step policy logs it in ``/extras``), ``None`` for a spliced one."""
        truth = cot_truth(cot)
        return {"scripted_truth": truth} if truth is not None else None

    def state_digest(self, cot: CoT) -> str:
        """sha256 of the canonical reading: everything :meth:`decode_action` takes from the CoT."""
        return self.reading(cot).digest()

    # -- action ---------------------------------------------------------------------------------------
    def target_speeds(self, obs: Observation, cot: CoT) -> tuple[np.ndarray, np.ndarray]:
        """The CoT-driven and the perception-driven target-speed profiles (before mixing and noise)."""
        speed = max(obs.ego.speed, 0.0)
        world = self.perceive(obs)
        percept = plan_speeds(speed, decide(world, speed, self.cruise_speed))
        driven = plan_speeds(speed, cot_decision(self.reading(cot), obs, world, self.cruise_speed))
        return driven, percept

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """30 waypoints (3 s at 10 Hz) along the lane centre at the mixed target speeds plus noise.

        Draws exactly 30 standard normals from ``rng`` whatever the CoT says, so the baseline and any
        spliced CoT at a step see the same action noise. A planned standstill stays a standstill.
        """
        if not (math.isfinite(obs.ego.speed) and math.isfinite(obs.ego.x) and math.isfinite(obs.ego.y)):
            raise ModelOutputError(f"model 'scripted' at step {obs.step}: the ego state is not finite")
        noise = rng.standard_normal(STEPS) * self.noise
        driven, percept = self.target_speeds(obs, cot)
        mixed = self.alpha * driven + (1.0 - self.alpha) * percept
        speeds = np.clip(mixed + noise, 0.0, MAX_SPEED)
        speeds[mixed <= 0.0] = 0.0
        distances = arc_lengths(obs.ego.speed, speeds)
        times = DT * np.arange(1, STEPS + 1)
        trajectory = Trajectory(times, place_along_route(obs.ground_truth.route_ahead, distances))
        problem = trajectory.problems()
        if problem is not None:
            raise ModelOutputError(f"model 'scripted' at step {obs.step}: trajectory {problem}")
        return trajectory


def _fraction(name: str, value: Any) -> float:
    return _number(name, value, 0.0, 1.0, "in [0, 1]")


def _number(name: str, value: Any, low: float, high: float, expected: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not low <= value <= high:
        raise ConfigError(f"model 'scripted': option {name} must be a number {expected}, got {value!r}")
    return float(value)
