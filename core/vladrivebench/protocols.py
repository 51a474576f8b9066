"""The core's whole contract: what a simulator, a model, a controller, a labeler, a metric, an executor, a
condition and a paradigm are, and the optional capabilities a model may add.

Plugins implement these protocols structurally (no base class needed). Every random draw is made from an
RNG that the caller passes in, so a pinned seed reproduces any step exactly. Optional capabilities are their
own small protocols: the core checks ``isinstance(model, TokenCounter)`` (etc.), never an undocumented
attribute.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from vladrivebench.records import (
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

if TYPE_CHECKING:  # numpy only for annotations: `vdb list-plugins` imports this module
    import numpy as np

    from vladrivebench._scenarios.spec import Scenario

Injection = str | dict[str, str]
"""What replaces a CoT: one string (sentence formats) or slot → text in the model's slot order (slots)."""


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
        """Forget any per-episode memory (history, caches). (Not called for an :class:`EpisodeMemory`
        model, whose ``start_episode`` replaces it.)"""
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



# -- optional model capabilities ----------------------------------------------------------------------
@runtime_checkable
class TokenCounter(Protocol):
    """A model that counts tokens with its own tokenizer.

    Conditions that match another text's length (``repeat`` with ``match``) and the ``max_tokens`` check of
    injected texts use it; without it the benchmark counts whitespace-separated words.
    """

    def count_tokens(self, text: str) -> int:
        """How many tokens ``text`` takes in this model's CoT."""
        ...


@runtime_checkable
class CoTExtras(Protocol):
    """A model that exposes JSON-able internals of its own CoT (logged on ``/extras`` at every step).

    The scripted reference model uses it to record the errors it made on purpose, so labels can be checked
    against what it actually wrote.
    """

    def cot_extras(self, cot: CoT) -> Mapping[str, Any] | None:
        """JSON-able facts about ``cot`` (or ``None``)."""
        ...


@runtime_checkable
class BatchedModel(Protocol):
    """A model that runs one call for many episodes' observations at once (``vdb run --batch B``).

    Each list is in order and as long as ``observations``; ``rngs[i]`` is episode i's pinned RNG for the
    call (``step_rng(seed_i, step, purpose, scenario_i)``), so a batched call must give every episode the
    draws it would have had alone. Results may differ from the unbatched methods in floating point only.

    One instance serves every episode of a batch, so ``reset(seed)``, called whenever an episode joins
    the batch, must not forget what the other episodes still need. A batched model keeps no per-episode
    memory outside the CoTs it returns, unless it also declares :class:`EpisodeMemory` and keys that memory
    by ``obs.episode``. (A model that is not a ``BatchedModel`` runs under ``--batch`` with one instance per lane,
    through its per-episode methods.) A batched model may also offer
    ``splice_cot_batch(observations, texts, rngs)``, feeding the texts exactly as ``generate_cot_batch``
    feeds its own, so that a selfsplice within a batch is bit-identical (the reference models do).
    """

    def generate_cot_batch(self, observations: Sequence[Observation],
                           rngs: Sequence[np.random.Generator]) -> list[CoT]:
        """``generate_cot`` for each observation."""
        ...

    def decode_action_batch(self, observations: Sequence[Observation], cots: Sequence[CoT],
                            rngs: Sequence[np.random.Generator]) -> list[Trajectory]:
        """``decode_action`` for each (observation, CoT) pair."""
        ...


@runtime_checkable
class EpisodeMemory(Protocol):
    """A model that keeps memory per episode (stop signs already obeyed, past frames, a recurrent state)
    while one instance serves several episodes at once, as a :class:`BatchedModel` does under ``--batch``.

    The runner names every episode and stamps the name on each of its observations (``obs.episode``):
    the same at every step, different for every episode that runs beside it. For a model with this
    capability the runner calls ``start_episode(episode, seed)`` when an episode starts, *instead of*
    ``reset(seed)`` (which would wipe the batch-mates' memory), and ``end_episode(episode)`` when it ends
    or fails. The model reads and updates the memory of ``obs.episode`` in every call, batched or not, so
    a row of a batched call sees exactly the memory it would see alone. As for any model, memory is
    updated from observations only, and seeing an observation again changes nothing (interventions splice
    and decode several times per step, in any order).
    """

    def start_episode(self, episode: str, seed: int) -> None:
        """Episode ``episode`` (seeded ``seed``) starts: its memory is empty, whatever it held before."""
        ...

    def end_episode(self, episode: str) -> None:
        """Episode ``episode`` has ended: its memory may be dropped. Unknown names are ignored."""
        ...


@runtime_checkable
class ConditionBatch(Protocol):
    """A model that decodes several injected texts for one observation in one pass over a shared prefix
    (``vdb intervene --batch-conditions``). ``texts[i]`` is one injection (a string, or slot → text); the
    trajectories come back in order, each as ``decode_action(obs, splice_cot(obs, texts[i], …), rng)`` would
    give it up to floating point."""

    def decode_batch(self, obs: Observation, texts: Sequence[Injection],
                     rng: np.random.Generator) -> list[Trajectory]:
        """One trajectory per injected text, in order."""
        ...


@runtime_checkable
class FidelityCheck(Protocol):
    """A model that can compare a spliced CoT's state with its own native computation.

    Selfsplice proves that generating and splicing agree with each other; this proves that the spliced state
    is what the model itself computes: one ordinary forward pass of the model over the prefix and the same
    CoT text, with positions (e.g. multimodal RoPE and its deltas) computed by the model's own code. The
    intervention gate calls it beside the selfsplice check and fails the step when either difference
    exceeds ``fidelity_tolerance``.
    """

    #: The largest cache / trajectory difference (absolute, in the cache's units / metres) still counted as
    #: equal, e.g. float32 rounding between one batched pass and one pass per token.
    fidelity_tolerance: float

    def fidelity_check(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> tuple[float, float]:
        """``(cache_diff, trajectory_diff)``: the largest absolute difference between the cache of ``cot``
        (as produced by :meth:`VLAModel.splice_cot` or generation) and the cache of the native forward pass,
        and the largest waypoint distance (m) between the trajectories decoded from each with ``rng``."""
        ...


# -- intervention conditions --------------------------------------------------------------------------------
@dataclass
class ConditionContext:
    """Everything a condition may read to build its injection at one step.

    ``own`` is the model's own CoT at this step; ``harvested`` maps a harvest condition's name to the
    injection taken from a baseline episode; ``resolve(name)`` gives another condition's injection at the
    same step (memoised per step); ``count_tokens`` is the model's tokenizer when it exposes one
    (``model.count_tokens(text)``), else a whitespace word count; ``model_name`` is used in messages.
    """

    cot_format: CoTFormat
    own: CoT
    resolve: Callable[[str], Injection]
    harvested: Mapping[str, Injection] = field(default_factory=dict)
    count_tokens: Callable[[str], int] = lambda text: len(text.split())
    model_name: str = "model"

    @property
    def slots(self) -> tuple[str, ...]:
        return tuple(self.cot_format.slots)


@runtime_checkable
class Condition(Protocol):
    """What the intervention protocol needs from a condition (plugins may implement their own).

    ``intent`` is one of :data:`INTENTS`; ``requires()`` names the conditions it builds on (checked for
    existence and cycles before a run); ``per_step`` says whether the injection changes from step to step
    (it reads the model's own CoT); ``resolve(ctx)`` returns the injection or raises
    :class:`ConditionError`.
    """

    name: str
    kind: str
    intent: str
    description: str

    def requires(self) -> tuple[str, ...]: ...

    @property
    def per_step(self) -> bool: ...

    def resolve(self, ctx: ConditionContext) -> Injection: ...

    def to_json(self) -> dict[str, Any]: ...




# -- intervention paradigms ---------------------------------------------------------------------------
@runtime_checkable
class Paradigm(Protocol):
    """One way of intervening on the CoT and measuring what it does (open-loop, closed-loop, safety, …).

    Registered with ``register_paradigms``; the registered name is what ``vdb intervene --mode`` takes and
    the factory's keyword arguments are its options (``--paradigm-opt key=value``). The core runs the
    generic part of every run — building the components, the manifest, resuming complete episodes, the
    preflight of every condition, harvesting, the selfsplice gate's verdict and the report — and asks the
    paradigm for the four things that differ:

    1. :meth:`plan`: the episodes of the run, each a
       :class:`~vladrivebench.intervention.PlannedEpisode` (route, seed, role, condition);
    2. :meth:`policy`: the step policy each planned episode runs under (see
       :class:`~vladrivebench.intervention.RunContext` for the splicing tools and
       :class:`~vladrivebench.intervention.OpenLoopPolicy` / ``InjectionPolicy`` / ``BaselinePolicy`` for
       the built-in ones); what a policy returns as extras is logged on ``/extras``;
    3. :meth:`analyse`: JSON-able results from the *logged* episodes (never live objects), adding every
       selfsplice check it finds to the run's :class:`~vladrivebench.intervention.GateTally` — a run whose
       gate checked no step is invalid;
    4. :meth:`tables`: :class:`~vladrivebench.metrics.Table` / ``Plot`` objects for those results, shown by
       ``vdb intervene`` and ``vdb report`` below the selfsplice gate table.

    ``default_conditions`` are the conditions run when ``--conditions`` is not given (``selfsplice`` is
    always run, as the gate). A paradigm may also offer ``pilot_effects(results, route)``
    (:class:`~vladrivebench.intervention.PilotEffects`) so that ``vdb intervene --plan`` can size a study, and
    ``step_batch`` / ``lockstep_group`` (:class:`BatchedParadigm`) so that ``vdb intervene --batch B`` runs its
    episodes in lockstep (without them every episode runs on its own, whatever ``--batch`` says, and the
    command says so on stderr); and ``effective_options()`` (:class:`EffectiveOptions`), the settings it
    runs with, defaults included, recorded in the manifest so that a resume under other settings is refused.
    """

    name: str
    default_conditions: tuple[str, ...]

    def check(self, config: Any) -> None:
        """Raise a :class:`~vladrivebench.errors.VdbError` when this paradigm cannot run ``config`` (an
        :class:`~vladrivebench.intervention.InterventionConfig`), before anything is written."""
        ...

    def plan(self, config: Any) -> list[Any]:
        """The episodes of the run (:class:`~vladrivebench.intervention.PlannedEpisode`), in a fixed order."""
        ...

    def policy(self, episode: Any, context: Any) -> Callable[[VLAModel, Observation, int], Any]:
        """The step policy ``policy(model, obs, seed) -> (cot, trajectory, extras)`` of one planned episode;
        ``context`` is the run's :class:`~vladrivebench.intervention.RunContext`."""
        ...

    def analyse(self, config: Mapping[str, Any], episodes: Any, gate: Any) -> dict[str, Any]:
        """JSON-able results from the logs. ``config`` is the run manifest's configuration (JSON),
        ``episodes`` the run's :class:`~vladrivebench.intervention.LoggedEpisodes`, ``gate`` the
        :class:`~vladrivebench.intervention.GateTally` to add each logged selfsplice check to."""
        ...

    def tables(self, results: Mapping[str, Any]) -> list[Any]:
        """Tables and plots for ``results`` (the run's whole results, with what :meth:`analyse` returned)."""
        ...


@runtime_checkable
class BatchedParadigm(Protocol):
    """A paradigm whose planned episodes can advance in lockstep (``vdb intervene --batch B``).

    Without this capability (or with ``--batch 1``, or a model that is not a :class:`BatchedModel` with
    ``splice_cot_batch``) every planned episode runs on its own under its :meth:`Paradigm.policy`, exactly
    as before: a third-party paradigm keeps working unchanged and opts in by adding the two methods below.

    With it, the core runs the planned episodes B at a time through one model instance (episodes that end
    leave the batch, the next ones join; the policies of :meth:`Paradigm.policy` are still made, still wrap
    the controller, and serve a lane that has to run alone) and, at every step, calls :meth:`step_batch`
    once for all the episodes in the batch. Each episode keeps its own pinned RNG streams: a batched step
    must give episode i exactly the draws ``policy(model, obs_i, seed_i)`` would have (the
    :class:`~vladrivebench.intervention.Splicer`'s ``*_many`` methods do), and what it returns for episode i
    is logged as that policy's output would be. Results may differ from the unbatched run in floating point
    only; the selfsplice gate must still hold bit for bit within a batch (splice the model's own CoTs of
    *all* the batch's observations in one ``splice_many`` call, mirroring the generation — see
    :func:`~vladrivebench.intervention.selfsplice_many`).
    """

    def step_batch(self, model: Any, lanes: Sequence[Any], context: Any) -> list[Any]:
        """``[(cot, trajectory, extras), …]`` for ``lanes`` (each a
        :class:`~vladrivebench.intervention.LaneStep`: planned episode, its policy, observation, seed) at one
        step; ``context`` is the run's :class:`~vladrivebench.intervention.RunContext`."""
        ...

    def lockstep_group(self, episode: Any) -> Any:
        """A hashable key for episodes that must see the same batches at every step (planned consecutively
        and compared bit for bit, e.g. the selfsplice episode and its baseline), or ``None``."""
        ...


@runtime_checkable
class EffectiveOptions(Protocol):
    """A paradigm that states every setting it runs with, its defaults included.

    ``vdb intervene`` records what :meth:`effective_options` returns in the run's manifest
    (``config.paradigm_settings`` in ``run.json``) and refuses to resume a directory whose recorded
    settings differ — e.g. after a default of the paradigm changed between two versions of its plugin — so
    that one directory never mixes episodes made under different settings.

    Without this capability the core records the factory's keyword arguments instead: the options given
    (``--paradigm-opt``) merged with every default in the factory's signature that is a plain JSON value.
    That is enough when the signature's defaults are the settings; a paradigm that takes defaults from
    elsewhere (a sentinel such as ``None`` or a private object resolved when it is built, a module constant,
    a configuration file) or normalises its options (``"25,50"`` → ``[25.0, 50.0]``) should offer this
    method. A paradigm with no options records nothing (its manifest keeps its bytes).
    """

    def effective_options(self) -> Mapping[str, Any]:
        """Every option the paradigm was built with, given or defaulted: option name → JSON-able value, in
        the form the paradigm uses it (two ways of giving the same settings should give the same mapping)."""
        ...


@runtime_checkable
class PilotEffects(Protocol):
    """A paradigm that says which per-seed effects ``vdb intervene --plan`` sizes a study by."""

    def pilot_effects(self, results: Mapping[str, Any], route: str) -> list[tuple[str, list[float], str]]:
        """``(condition, per-seed effects, what was measured)`` for every condition of ``route``."""
        ...
