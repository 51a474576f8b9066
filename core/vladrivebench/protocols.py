"""The core's whole contract: what a simulator, a model, a controller, a labeler, a metric and an executor are.

Plugins implement these protocols structurally (no base class needed). Every random draw is made from an
RNG that the caller passes in, so a pinned seed reproduces any step exactly.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from .records import (
    Control,
    CoT,
    CoTFormat,
    EgoState,
    LabelInput,
    Labels,
    Observation,
    Trajectory,
    TrajectorySpec,
)

if TYPE_CHECKING:
    from .scenarios import Scenario


@runtime_checkable
class Simulator(Protocol):
    """A closed-loop driving world at a fixed step (10 Hz for the built-in simulators).

    ``reset`` builds the world of a scenario and returns the first observation; ``step`` applies one
    control (PID-style throttle/steer/brake, or the ``next_state`` an MPC-style controller chose) and
    returns the next observation. Each observation carries the step's :class:`GroundTruth`: every actor
    with type, pose and size, the distance along the route to the critical feature, whether it blocks the
    lane, the light state, collisions and red-light / stop-sign violations of that step, and ``terminal``
    on the last step. The same ``(scenario, seed)`` must give the same episode bit for bit.
    """

    dt: float

    def reset(self, scenario: Scenario, seed: int) -> Observation:
        """Start an episode of ``scenario``; all randomness of the episode derives from ``seed``."""
        ...

    def step(self, control: Control) -> Observation:
        """Advance one step under ``control`` and return the new observation."""
        ...

    def close(self) -> None:
        """Release external resources (processes, files). Safe to call twice."""
        ...


@runtime_checkable
class VLAModel(Protocol):
    """A vision-language-action model, split where the benchmark needs to intervene.

    ``generate_cot`` writes the model's own chain-of-thought for an observation; ``splice_cot`` builds the
    CoT the model *would* hold had it generated ``text`` itself (a string for sentence formats, a mapping
    slot → text for slotted formats); ``decode_action`` turns a CoT into a trajectory. Splicing the
    model's own text (selfsplice) must give a CoT whose :meth:`state_digest` equals the generated one's and,
    with the same RNG state, the same trajectory bit for bit.

    ``cot_format`` says whether the CoT is one sentence or named slots; ``trajectory_spec`` the horizon and
    rate of its trajectories. ``reset`` is called at the start of every episode.
    """

    cot_format: CoTFormat
    trajectory_spec: TrajectorySpec

    def reset(self, seed: int) -> None:
        """Forget any per-episode memory (history, caches)."""
        ...

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        """The model's own chain-of-thought for ``obs``."""
        ...

    def splice_cot(self, obs: Observation, text: str | dict[str, str], rng: np.random.Generator) -> CoT:
        """The CoT as if the model had generated ``text`` for ``obs`` (the intervention mechanism)."""
        ...

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """The trajectory the action head produces given ``obs`` and ``cot``."""
        ...

    def state_digest(self, cot: CoT) -> str:
        """A hash of everything in ``cot``'s model state that the action head reads (e.g. the KV cache)."""
        ...


@runtime_checkable
class Controller(Protocol):
    """Tracks a trajectory: ego-frame waypoints → control for the next step, with its desired speed ``v_des``."""

    def reset(self) -> None:
        """Clear integrators and other memory at the start of an episode."""
        ...

    def control(self, trajectory: Trajectory, ego: EgoState, dt: float) -> Control:
        """The control to apply for the next ``dt`` seconds."""
        ...


@runtime_checkable
class Labeler(Protocol):
    """Reads a CoT against the ground truth and extracts labels (stated action, mention, light colour,
    hallucination, contradiction). ``version`` changes whenever the labels it gives could change, because
    stored labels are keyed by text + context + labeler version.
    """

    version: str

    def label(self, item: LabelInput) -> Labels:
        """Labels for one CoT."""
        ...

    def label_batch(self, items: Sequence[LabelInput]) -> list[Labels]:
        """Labels for many CoTs, in order; implementations may batch or parallelise."""
        ...


@runtime_checkable
class Metric(Protocol):
    """Turns analysed episodes into tables whose every cell carries the count behind it.

    ``compute`` receives an analysis dataset (episodes, their labels, intervention results) and returns
    a list of tables; it must not read live simulators or models, only logs.
    """

    name: str

    def compute(self, dataset: Any) -> list[Any]:
        """Tables for this metric."""
        ...


@runtime_checkable
class Executor(Protocol):
    """Runs independent jobs (episodes) and yields their results as they finish.

    ``worker`` is a picklable module-level function; results may arrive in any order and each carries
    its job's identity. Failures of one job must come back as a result, never stop the others.
    """

    def run(self, worker: Callable[[Any], Any], jobs: Iterable[Any]) -> Iterator[Any]:
        """Yield ``worker(job)`` for every job."""
        ...

