"""Sweeps: many episodes (scenarios × seeds) into one output directory, resumable and failure-isolated.

Output directory layout::

    OUT/run.json                 the run manifest (configuration + versions), written before anything else
    OUT/episodes/<model>__<scenario>__s<seed>.mcap   one log per episode (complete or absent)
    OUT/failures.json            failed episodes with their errors and tracebacks

Running the same configuration into the same ``OUT`` again resumes: complete episodes are kept, partial
or damaged ones are redone, failed ones are kept as failed unless ``retry_failed``. A different
configuration is refused before anything is touched. Episode logs hold no wall-clock time and no
executor details, so every executor produces the same bytes.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.metadata as metadata
import json
import os
import platform
import re
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vladrivebench._engine.executors import JobFailure
from vladrivebench._engine.registry import Registry, check_options, get_registry
from vladrivebench._engine.runner import EpisodeFailure, run_episode
from vladrivebench._logs.episodes import PARTIAL_SUFFIX, EpisodeWriter, partial_in_use, read_result
from vladrivebench.errors import ConfigError, VdbError

MANIFEST_NAME = "run.json"
FAILURES_NAME = "failures.json"
EPISODES_DIR = "episodes"
MANIFEST_FORMAT = 1


# -- what is asked ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ComponentSpec:
    """A registered component by kind and name, with the options its factory is called with."""

    kind: str
    name: str
    options: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "options": _plain(dict(self.options))}

    def key(self) -> str:
        return json.dumps([self.kind, self.name, _plain(dict(self.options))], sort_keys=True)


@dataclass(frozen=True)
class RunConfig:
    """Everything that determines a sweep's episode logs (not how it is executed)."""

    model: ComponentSpec
    simulator: ComponentSpec
    controller: ComponentSpec
    scenarios: tuple[Any, ...]
    seeds: tuple[int, ...]
    log_images: bool = False
    batch: int = 1

    def to_json(self) -> dict[str, Any]:
        identity = {
            "model": self.model.to_json(),
            "simulator": self.simulator.to_json(),
            "controller": self.controller.to_json(),
            "scenarios": [s.id for s in self.scenarios],
            "scenario_digest": scenario_digest(self.scenarios),
            "seeds": list(self.seeds),
            "log_images": self.log_images,
        }
        if self.batch != 1:  # batched results may differ in floating point: the batch size is configuration
            identity["batch"] = self.batch  # (absent at 1, so unbatched runs keep their bytes)
        return identity


def scenario_digest(scenarios: Iterable[Any]) -> str:
    """sha256 of the scenarios' full specs: an edited scenario file makes a different run."""
    text = json.dumps([_plain(s.to_json()) for s in scenarios], sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


MAX_SEEDS = 100_000
"""The most seeds one sweep takes (every seed is an episode log; more is a mistyped number)."""
MAX_SEED = 2**53
"""Seeds stay exact in JSON (and in every reader's double)."""


def seed_list(count: Any, offset: Any = 0) -> tuple[int, ...]:
    """Seeds ``offset … offset+count−1``; a one-line :class:`ConfigError` for a bad count or offset."""
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_SEEDS:
        raise ConfigError(f"--seeds must be a whole number from 1 to {MAX_SEEDS:,} (seeds 0 … N−1), got {count!r}")
    if isinstance(offset, bool) or not isinstance(offset, int) or not 0 <= offset <= MAX_SEED - count:
        raise ConfigError(f"--seed-offset must be a whole number from 0 to {MAX_SEED - count}, got {offset!r}")
    return tuple(range(offset, offset + count))


def batch_size(value: Any) -> int:
    """A lockstep batch size (``--batch``): a whole number ≥ 1, else a one-line :class:`ConfigError`."""
    if isinstance(value, str):
        try:
            value = int(value.strip())
        except ValueError:
            raise ConfigError(f"--batch must be a whole number ≥ 1 (episodes in lockstep), got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"--batch must be a whole number ≥ 1 (episodes in lockstep), got {value!r}")
    return value


def episode_id(model: str, scenario_id: str, seed: int) -> str:
    """``<model>__<scenario>__s<seed>``, with characters unsafe in file names replaced by ``-``."""
    def safe(text: str) -> str:
        return re.sub(r"[^A-Za-z0-9._-]", "-", text)
    return f"{safe(model)}__{safe(scenario_id)}__s{seed}"


# -- registries in worker processes -------------------------------------------------------------------
@dataclass(frozen=True)
class RegistrySpec:
    """How to rebuild the driver's plugin registry in another process (entry points + local plugins).

    Local plugins (added with ``Registry(plugins=…)``, e.g. by tests) are carried as module names when
    they are modules, otherwise as the (picklable) plugin objects themselves.
    """

    entry_points: bool
    disabled: tuple[str, ...] = ()
    local_plugins: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def of(cls, registry: Registry) -> RegistrySpec:
        local = []
        for info in registry.plugins:
            if info.distribution == "(local)" and info.status == "ok":
                obj = registry.manager.get_plugin(info.name)
                local.append((info.name, obj.__name__ if isinstance(obj, type(os)) else obj))
        from_entry_points = any(p.distribution != "(local)" for p in registry.plugins)
        return cls(from_entry_points, tuple(sorted(registry.disabled)), tuple(local))

    def build(self) -> Registry:
        plugins = [(name, importlib.import_module(obj) if isinstance(obj, str) else obj)
                   for name, obj in self.local_plugins]
        return Registry(plugins, entry_points=self.entry_points, disabled=self.disabled)

    def key(self) -> str:
        return repr((self.entry_points, self.disabled, [(n, o if isinstance(o, str) else id(o))
                                                         for n, o in self.local_plugins]))


_WORKER_REGISTRIES: dict[str, Registry] = {}
_REGISTRIES_LOCK = threading.Lock()


def _registry_for(spec: RegistrySpec | Registry | None) -> Registry:
    if spec is None:
        return get_registry()
    if isinstance(spec, Registry):  # an in-process executor: the driver's own registry
        return spec
    key = spec.key()
    with _REGISTRIES_LOCK:  # the pipelined executor's threads share this process's registries
        if key not in _WORKER_REGISTRIES:
            _WORKER_REGISTRIES[key] = spec.build()
        return _WORKER_REGISTRIES[key]


# -- one episode (runs in a worker) -------------------------------------------------------------------
@dataclass(frozen=True)
class EpisodeJob:
    """One episode to run: everything a worker needs, picklable."""

    episode_id: str
    path: str
    scenario: Any
    seed: int
    model: ComponentSpec
    simulator: ComponentSpec
    controller: ComponentSpec
    config: Mapping[str, Any]
    versions: Mapping[str, str]
    log_images: bool = False
    registry: RegistrySpec | Registry | None = None


@dataclass(frozen=True)
class EpisodeOutcome:
    """What became of a job: ``status`` is ``ok``, ``failed`` (recorded, the sweep goes on) or ``fatal``
    (a configuration mistake that concerns every episode: the sweep stops with ``error``)."""

    episode_id: str
    status: str
    result: dict | None = None
    error: str | None = None
    details: str = ""
    step: int | None = None
    component: str | None = None
    seconds: float = 0.0


class _ThreadComponents(threading.local):
    """Components built in this thread of this process, reused across episodes: ``kind → (key, component)``
    and ``(kind, lane) → (key, component)``; and, under the ``pipelined`` executor, the model server and
    pipe this thread's models live on."""

    def __init__(self):
        self.by_kind: dict[str, tuple[str, Any]] = {}
        self.by_lane: dict[tuple[str, int], tuple[str, Any]] = {}
        self.model_server: tuple[Any, int] | None = None


_THREAD = _ThreadComponents()


@contextmanager
def serve_models_from(server: Any, pipe: int) -> Iterator[None]:
    """In this thread, while the block runs, build models on ``server`` (a
    :class:`~vladrivebench._engine.model_server.ModelServer`) over its pipe ``pipe``; close them after."""
    _THREAD.model_server = (server, pipe)
    try:
        yield
    finally:
        release_components()
        _THREAD.model_server = None


def create_component(registry: Registry, spec: Any) -> Any:
    """A new component of ``spec`` (kind, name, options); a model is built on this thread's model server
    when the thread has one (:func:`serve_models_from`)."""
    if spec.kind == "model" and _THREAD.model_server is not None:
        server, pipe = _THREAD.model_server
        return server.model(pipe, RegistrySpec.of(registry), spec)
    return registry.create(spec.kind, spec.name, spec.options)


def pipeline_turns(*, one_request: bool = False) -> dict[str, Any]:
    """``run_lockstep``'s ``harness_turn`` and ``model_turn`` for this thread: the model server's locks
    under the ``pipelined`` executor, none otherwise. A step that is ``one_request`` to the server needs no
    model turn: it queues at the server while another job's step computes, and cannot interleave with it."""
    server = _THREAD.model_server[0] if _THREAD.model_server else None
    return {"harness_turn": server and server.harness_turn,
            "model_turn": None if one_request else server and server.model_turn}


def _component(registry: Registry, spec: ComponentSpec) -> Any:
    key = f"{id(registry)}:{spec.key()}"
    cached = _THREAD.by_kind.get(spec.kind)
    if cached is not None and cached[0] == key:
        return cached[1]
    forget_component(spec.kind)
    component = create_component(registry, spec)
    _THREAD.by_kind[spec.kind] = (key, component)
    return component


def forget_component(kind: str) -> None:
    """Drop (and close, if it can be closed) the cached component of ``kind`` in this thread."""
    cached = _THREAD.by_kind.pop(kind, None)
    if cached is not None:
        close_quietly(cached[1])


def close_quietly(component: Any) -> None:
    """Close ``component`` if it can be closed; a failure to close is not reported (closing a broken
    component must not hide the episode's or the command's own outcome)."""
    close = getattr(component, "close", None)
    if callable(close):
        try:
            close()
        except Exception:
            pass


def release_components() -> None:
    """Close and drop every component this process built (end of an in-process sweep)."""
    for kind in list(_THREAD.by_kind):
        forget_component(kind)
    for kind, lane in list(_THREAD.by_lane):
        _forget_lane(kind, lane)


def run_job(job: EpisodeJob) -> EpisodeOutcome:
    """Run one episode into its log file; never raises (failures come back as outcomes)."""
    started = time.perf_counter()

    def outcome(status: str, **kw: Any) -> EpisodeOutcome:
        return EpisodeOutcome(job.episode_id, status, seconds=time.perf_counter() - started, **kw)

    try:
        registry = _registry_for(job.registry)
        model = _component(registry, job.model)
        simulator = _component(registry, job.simulator)
        controller = _component(registry, job.controller)
    except VdbError as exc:
        return outcome("fatal", error=str(exc))
    except Exception as exc:
        failure = _describe_exception(exc)
        return outcome("failed", error=f"building the components raised {failure[0]}", details=failure[1])
    try:
        meta = episode_meta(job, model, simulator, registry)
        with EpisodeWriter(job.path, meta, log_images=job.log_images) as writer:
            result = run_episode(model, simulator, controller, job.scenario, job.seed, writer=writer,
                                 model_name=job.model.name, simulator_name=job.simulator.name,
                                 controller_name=job.controller.name)
            writer.finish(result.to_json())
    except EpisodeFailure as exc:
        forget_component(exc.component)
        return outcome("failed", error=str(exc), details=exc.details, step=exc.step, component=exc.component)
    except Exception as exc:
        error, details = _describe_exception(exc)
        return outcome("failed", error=error, details=details)
    return outcome("ok", result=result.to_json())


# -- lockstep batches (runs in a worker) --------------------------------------------------------------
BATCH_JOB_FACTOR = 4
"""A batch job holds up to ``BATCH_JOB_FACTOR × batch`` consecutive episodes of the sweep (scenario-major):
``batch`` of them advance in lockstep and the next join as others end. The grouping depends only on the
configuration, never on what is already done, so a resumed sweep gives every episode the same batch-mates."""


@dataclass(frozen=True)
class BatchJob:
    """Episodes run in lockstep in one worker. ``todo`` names those to log; the others (complete or failed
    before) are run again without a log only so that the batch is the same as in the first run."""

    episodes: tuple[EpisodeJob, ...]
    todo: frozenset[str]
    batch: int

    @property
    def episode_id(self) -> str:  # what an executor names a failed job by
        return ", ".join(sorted(self.todo))


def make_batch_jobs(jobs: Sequence[EpisodeJob], todo: Sequence[EpisodeJob], batch: int) -> list[BatchJob]:
    """The batch jobs holding at least one episode of ``todo`` (groups of consecutive ``jobs``)."""
    wanted = {job.episode_id for job in todo}
    size = BATCH_JOB_FACTOR * batch
    groups = [tuple(jobs[i:i + size]) for i in range(0, len(jobs), size)]
    return [BatchJob(group, frozenset(j.episode_id for j in group) & wanted, batch)
            for group in groups if any(j.episode_id in wanted for j in group)]


def _lane_component(registry: Registry, spec: ComponentSpec, lane: int) -> Any:
    """Lane ``lane``'s own instance of a component (lane 0 shares the process's cached one)."""
    if lane == 0:
        return _component(registry, spec)
    key = f"{id(registry)}:{spec.key()}"
    cached = _THREAD.by_lane.get((spec.kind, lane))
    if cached is not None and cached[0] == key:
        return cached[1]
    _forget_lane(spec.kind, lane)
    component = create_component(registry, spec)
    _THREAD.by_lane[(spec.kind, lane)] = (key, component)
    return component


def _forget_lane(kind: str, lane: int) -> None:
    if lane == 0:
        forget_component(kind)
        return
    cached = _THREAD.by_lane.pop((kind, lane), None)
    if cached is not None:
        close_quietly(cached[1])


def run_batch_job(job: BatchJob) -> list[EpisodeOutcome]:
    """Run a batch job's episodes in lockstep, each logged to its own file; never raises.

    A :class:`~vladrivebench.BatchedModel` serves every lane with one instance and one batched call per
    step; any other model gets an instance per lane and its per-episode methods (as without ``--batch``).
    """
    from vladrivebench._engine.runner import LockstepEpisode, run_lockstep
    from vladrivebench.protocols import BatchedModel

    started = time.perf_counter()
    first = job.episodes[0]
    outcomes: dict[str, EpisodeOutcome] = {}

    def outcome(eid: str, status: str, **kw: Any) -> EpisodeOutcome:
        return EpisodeOutcome(eid, status, seconds=time.perf_counter() - started, **kw)

    try:
        registry = _registry_for(first.registry)
        shared = _component(registry, first.model)
        batched = isinstance(shared, BatchedModel)
        for spec in (first.simulator, first.controller):
            _lane_component(registry, spec, 0)  # a configuration mistake shows before any episode starts
    except VdbError as exc:
        return [outcome(eid, "fatal", error=str(exc)) for eid in sorted(job.todo)]
    except Exception as exc:
        error, details = _describe_exception(exc)
        return [outcome(eid, "failed", error=f"building the components raised {error}", details=details)
                for eid in sorted(job.todo)]

    def make_lane(lane: int) -> tuple[Any, Any, Any]:
        model = shared if batched else _lane_component(registry, first.model, lane)
        return model, _lane_component(registry, first.simulator, lane), _lane_component(registry, first.controller, lane)

    def opener(ep: EpisodeJob) -> Callable[[], Any]:
        def open_writer() -> Any:
            meta = episode_meta(ep, shared, _lane_component(registry, ep.simulator, 0), registry)
            return EpisodeWriter(ep.path, meta, log_images=ep.log_images).__enter__()
        return open_writer

    def done(episode: Any, finished: Any, writer: Any) -> None:
        ep: EpisodeJob = episode.key
        if ep.episode_id not in job.todo:
            return
        if isinstance(finished, EpisodeFailure):
            if writer is not None:
                writer.__exit__(EpisodeFailure, finished, None)
            outcomes[ep.episode_id] = outcome(ep.episode_id, "failed", error=str(finished), details=finished.details,
                                              step=finished.step, component=finished.component)
            return
        writer.finish(finished.to_json())
        writer.__exit__(None, None, None)
        outcomes[ep.episode_id] = outcome(ep.episode_id, "ok", result=finished.to_json())

    episodes = [LockstepEpisode(ep, ep.scenario, ep.seed, opener(ep) if ep.episode_id in job.todo else None)
                for ep in job.episodes]
    names = {"model": first.model.name, "simulator": first.simulator.name, "controller": first.controller.name}
    try:
        served = batched and _THREAD.model_server is not None  # then a step is one request
        run_lockstep(episodes, job.batch, make_lane=make_lane, done=done, names=names,
                     batch_policy=_served_own_cot_policy if served else None, **pipeline_turns(one_request=served))
    except Exception as exc:  # a writer or the loop itself broke: the episodes not yet done fail
        error, details = _describe_exception(exc)
        for eid in sorted(job.todo - set(outcomes)):
            outcomes[eid] = outcome(eid, "failed", error=error, details=details)
    if any(o.status == "failed" and o.component == "model" for o in outcomes.values()):
        forget_component("model")
    return [outcomes[eid] for eid in sorted(outcomes)]


def _served_own_cot_policy(model: Any, observations: Sequence[Any], seeds: Sequence[int]) -> list[Any]:
    """The default batched step run on the model server, one round trip for the CoTs and the actions."""
    from vladrivebench._engine.runner import own_cot_batch_policy

    return model.run_policy(own_cot_batch_policy, observations, seeds)


def episode_meta(job: EpisodeJob, model: Any, simulator: Any, registry: Registry | None = None) -> dict[str, Any]:
    """The ``episode`` metadata record of a job's log.

    Given the ``registry``, each component also records ``effective_options``: every option its factory
    takes, with the signature's default where the run did not set it.
    """
    from dataclasses import asdict, is_dataclass

    def describe(obj: Any) -> Any:
        return asdict(obj) if is_dataclass(obj) and not isinstance(obj, type) else None

    def spec_json(spec: ComponentSpec) -> dict[str, Any]:
        if registry is None:
            return spec.to_json()
        return {**spec.to_json(), "effective_options": effective_options(registry, spec)}

    return {
        "episode_id": job.episode_id,
        "model": {**spec_json(job.model), "cot_format": describe(getattr(model, "cot_format", None)),
                  "trajectory_spec": describe(getattr(model, "trajectory_spec", None))},
        "simulator": {**spec_json(job.simulator), "dt": float(simulator.dt)},
        "controller": spec_json(job.controller),
        "scenario": _plain(job.scenario.to_json()),
        "seed": job.seed,
        "config": dict(job.config),
        "versions": dict(job.versions),
    }


def _describe_exception(exc: BaseException) -> tuple[str, str]:
    import traceback

    text = " ".join(str(exc).split())
    details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return (f"{type(exc).__name__}: {text}" if text else type(exc).__name__), details


# -- the sweep (runs in the driver) -------------------------------------------------------------------
@dataclass
class SweepSummary:
    """The state of an output directory after a sweep: results of every complete episode, failures."""

    out: Path
    jobs: list[EpisodeJob]
    results: dict[str, dict]
    failures: dict[str, dict]
    ran: int = 0
    skipped: int = 0
    seconds: float = 0.0

    @property
    def total(self) -> int:
        return len(self.jobs)

    def per_scenario(self) -> list[dict[str, Any]]:
        """One row per scenario: episodes complete and failed, collisions, violations, completion, speed."""
        rows: dict[str, dict[str, Any]] = {}
        for job in self.jobs:
            row = rows.setdefault(job.scenario.id, {"scenario": job.scenario.id, "episodes": 0, "failed": 0,
                                                    "collisions": 0, "violations": 0, "_completion": [],
                                                    "_speed": []})
            result = self.results.get(job.episode_id)
            if result is None:
                row["failed"] += job.episode_id in self.failures
                continue
            row["episodes"] += 1
            row["collisions"] += result["collisions"] > 0
            row["violations"] += result["violations"] > 0
            row["_completion"].append(result["route_completion"])
            row["_speed"].append(result["mean_speed"])
        table = []
        for row in rows.values():
            completion, speed = row.pop("_completion"), row.pop("_speed")
            row["route_completion"] = sum(completion) / len(completion) if completion else None
            row["mean_speed"] = sum(speed) / len(speed) if speed else None
            table.append(row)
        return table

    def to_json(self) -> dict[str, Any]:
        return {
            "out": str(self.out),
            "episodes": self.total,
            "complete": len(self.results),
            "failed": len(self.failures),
            "ran": self.ran,
            "skipped": self.skipped,
            "seconds": round(self.seconds, 3),
            "scenarios": self.per_scenario(),
            "failures": [{"episode_id": k, "error": v["error"]} for k, v in sorted(self.failures.items())],
        }


OutcomeCallback = Callable[[EpisodeOutcome, int, int], None]
"""``callback(outcome, done, todo)`` after each episode of this sweep (progress display)."""


def run_sweep(config: RunConfig, out: Path | str, *, executor: Any, executor_info: Mapping[str, Any] | None = None,
              retry_failed: bool = False, registry: Registry | None = None,
              on_outcome: OutcomeCallback | None = None,
              on_note: Callable[[str], None] | None = None) -> SweepSummary:
    """Run every episode of ``config`` not already complete in ``out`` and return the directory's summary.

    Raises a one-line :class:`VdbError` (before anything is written) for unknown components, options their
    factories do not take, or an ``out`` holding a different run; and, during the sweep, for a component
    that cannot be built because of the configuration (episodes already complete stay). ``on_note(text)`` is
    called once, once the directory is accepted, when the sweep runs otherwise than asked: a ``--batch``
    above 1 with a model that has no batched forms (:func:`unbatched_note`).
    """
    started = time.perf_counter()
    registry = registry or get_registry()
    components = (config.model, config.simulator, config.controller)
    for spec in components:
        check_options(spec.kind, spec.name, registry.get(spec.kind, spec.name).factory, spec.options)
    out = Path(out)
    check_output_directory(out)
    in_process = bool(getattr(executor, "in_process", False))
    try:
        build_components(registry, components, keep=True)
        check_lane_instances(registry, (config.simulator, config.controller), config.batch)
        note = unbatched_note(config, _component(registry, config.model))
    except VdbError:
        release_components()  # nothing runs: hold no simulator (a SUMO slot) for the next command
        raise
    finally:
        if not in_process:
            release_components()
    versions = collect_versions(registry, components)
    manifest = {"format": MANIFEST_FORMAT, "config": config.to_json(), "versions": versions,
                "executor": dict(executor_info or {})}
    prepare_out(out, manifest)
    if note and on_note is not None:
        on_note(note)
    jobs = make_jobs(config, out, versions, registry if in_process else RegistrySpec.of(registry))
    failures = load_failures(out)
    todo, results = _plan(jobs, failures, retry_failed)
    summary = SweepSummary(out, jobs, results, failures, skipped=len(jobs) - len(todo))
    _remove_stale_partials(out / EPISODES_DIR)
    try:
        if config.batch > 1:
            by_id = {job.episode_id: job for job in todo}
            _execute(executor, make_batch_jobs(jobs, todo, config.batch), summary, out, on_outcome,
                     worker=run_batch_job, by_id=by_id)
        else:
            _execute(executor, todo, summary, out, on_outcome)
    finally:
        if in_process:
            release_components()
        write_failures(out, summary.failures)
        summary.seconds = time.perf_counter() - started
    return summary


def unbatched_note(config: RunConfig, model: Any) -> str | None:
    """What to tell the user when ``--batch`` above 1 meets a model without the
    :class:`~vladrivebench.BatchedModel` capability (each lane then gets its own instance and the per-episode
    methods, as without ``--batch``), else ``None``."""
    from vladrivebench.protocols import BatchedModel

    if config.batch > 1 and not isinstance(model, BatchedModel):
        return f"model {config.model.name!r} has no batched forms; its episodes run one at a time"
    return None


def build_components(registry: Registry, components: Sequence[ComponentSpec], *, keep: bool) -> None:
    """Build every component once before anything is written, so that an option value its factory refuses
    (``alpha=2``, ``max_speed=-1``) is one line and no run directory; ``keep`` them for an in-process sweep."""
    try:
        for spec in components:
            try:
                _component(registry, spec)
            except VdbError:
                raise
            except Exception as exc:  # the factory refused its options: one line naming them
                options = ", ".join(f"{k}={v!r}" for k, v in spec.options.items()) or "no options"
                reason = " ".join(str(exc).split()) or type(exc).__name__
                if not isinstance(exc, (ValueError, TypeError)):
                    reason = f"{type(exc).__name__}: {reason}"
                raise ConfigError(f"{spec.kind} {spec.name!r} ({options}) cannot be built: {reason}") from None
    finally:
        if not keep:
            release_components()


def check_lane_instances(registry: Registry, components: Sequence[ComponentSpec], batch: int) -> None:
    """``--batch`` above 1 gives every episode of a batch its own simulator and controller, all in one process:
    build a second instance of each beside the first (already built) before anything is written, so that one
    which allows a single instance per process (``sumo``: libsumo holds one simulation) is one line, not a
    run whose every episode fails."""
    if batch < 2:
        return
    for spec in components:
        second = None
        try:
            second = create_component(registry, spec)
        except Exception as exc:
            reason = " ".join(str(exc).split()) or type(exc).__name__
            raise ConfigError(f"--batch {batch} runs each episode of a batch with its own {spec.kind} in one process, "
                              f"and a second {spec.kind} {spec.name!r} cannot be built beside the first ({reason}); "
                              f"expected --batch 1 (and --executor process --workers N to run episodes in "
                              f"parallel)") from None
        finally:
            close_quietly(second)


def trusted_result(path: str) -> dict | None:
    """The result of a complete log whose every record passes its CRC, else ``None`` (the episode is redone).

    :func:`read_result` reads the summary only; a log edited or damaged after it was written must not be
    counted as complete, so the whole file is checked before the result is trusted."""
    from vladrivebench._logs.episodes import read_episode
    from vladrivebench.errors import LogError

    if not os.path.exists(path) or read_result(path) is None:
        return None
    try:
        episode = read_episode(path)
    except LogError:
        return None
    return episode.result


def _plan(jobs: list[EpisodeJob], failures: dict[str, dict], retry_failed: bool
          ) -> tuple[list[EpisodeJob], dict[str, dict]]:
    todo, results = [], {}
    for job in jobs:
        result = trusted_result(job.path)
        if result is not None:
            results[job.episode_id] = result
            failures.pop(job.episode_id, None)
        elif job.episode_id in failures and not retry_failed:
            continue
        else:
            Path(job.path).unlink(missing_ok=True)  # truncated or damaged: redo it
            todo.append(job)
    return todo, results


def _execute(executor: Any, todo: Sequence[Any], summary: SweepSummary, out: Path,
             on_outcome: OutcomeCallback | None, *, worker: Callable[[Any], Any] = run_job,
             by_id: Mapping[str, EpisodeJob] | None = None) -> None:
    by_id = by_id if by_id is not None else {job.episode_id: job for job in todo}
    stream = executor.run(worker, todo)
    try:
        for outcome in (o for item in stream for o in _as_outcomes(item)):
            if outcome.status == "fatal":
                raise VdbError(outcome.error or "a component could not be built")
            summary.ran += 1
            if outcome.status == "ok":
                summary.results[outcome.episode_id] = outcome.result or {}
                summary.failures.pop(outcome.episode_id, None)
            else:
                summary.failures[outcome.episode_id] = _failure_entry(by_id.get(outcome.episode_id), outcome)
                write_failures(out, summary.failures)
            if on_outcome is not None:
                on_outcome(outcome, summary.ran, len(by_id))
    finally:
        close = getattr(stream, "close", None)
        if callable(close):
            close()


def _as_outcomes(item: Any) -> list[EpisodeOutcome]:
    """A worker's result as outcomes: one (an episode job), a list (a batch job), or failures of every
    episode a crashed job held."""
    if isinstance(item, EpisodeOutcome):
        return [item]
    if isinstance(item, list) and all(isinstance(o, EpisodeOutcome) for o in item):
        return item
    if isinstance(item, JobFailure):
        ids = sorted(item.job.todo) if isinstance(item.job, BatchJob) else [item.job.episode_id]
        return [EpisodeOutcome(eid, "failed", error=item.error, details=item.details) for eid in ids]
    raise TypeError(f"executor returned {type(item).__name__}, expected the worker's result or a JobFailure")


def _failure_entry(job: EpisodeJob | None, outcome: EpisodeOutcome) -> dict[str, Any]:
    return {
        "episode_id": outcome.episode_id,
        "scenario": job.scenario.id if job else None,
        "seed": job.seed if job else None,
        "step": outcome.step,
        "component": outcome.component,
        "error": outcome.error,
        "traceback": outcome.details,
    }


def make_jobs(config: RunConfig, out: Path, versions: Mapping[str, str],
              registry: RegistrySpec | Registry | None) -> list[EpisodeJob]:
    """Every episode of the sweep, scenario-major, seeds in order."""
    identity = config.to_json()
    jobs = []
    for scenario in config.scenarios:
        for seed in config.seeds:
            eid = episode_id(config.model.name, scenario.id, seed)
            jobs.append(EpisodeJob(eid, str(out / EPISODES_DIR / f"{eid}.mcap"), scenario, seed, config.model,
                                   config.simulator, config.controller, identity, dict(versions),
                                   config.log_images, registry))
    return jobs


# -- the output directory -----------------------------------------------------------------------------
def prepare_out(out: Path, manifest: Mapping[str, Any], *, optional: Iterable[str] = ()) -> None:
    """Check ``out`` can hold this run (resume or new) and write the manifest if it is new.

    ``optional`` names ``config`` keys that manifests written before they were recorded lack: a recorded
    manifest without one is accepted (unknown, as before) and left as it is; one with it must match."""
    check_output_directory(out)
    path = out / MANIFEST_NAME
    if path.exists():
        previous = read_manifest(path)
        now = {"config": _plain(manifest["config"]), "versions": _plain(manifest["versions"])}
        for key in optional:
            if key not in previous["config"]:
                now["config"].pop(key, None)
        for section in ("config", "versions"):
            difference = first_difference(previous.get(section), now[section], section)
            if difference:
                raise ConfigError(f"{out} holds a run with a different configuration ({difference}); "
                                  f"repeat that run's command to resume it, or use another --out")
        return
    if out.exists() and out.is_dir() and not _writable(out):
        raise ConfigError(f"--out {out}: cannot write in this directory (read-only); use another --out")
    episodes = out / EPISODES_DIR
    if episodes.is_dir() and any(episodes.iterdir()):
        raise ConfigError(f"{out} holds episode logs but no {MANIFEST_NAME}: not a run this command can "
                          f"resume; use another --out")
    episodes.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, manifest)


def read_manifest(path: Path) -> dict[str, Any]:
    """A run's ``run.json``: a JSON object with ``config`` and ``versions`` objects, or a one-line error."""
    try:
        previous = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: unreadable run manifest ({' '.join(str(exc).split())}); use another --out") from None
    if not isinstance(previous, dict) or not all(isinstance(previous.get(k), dict) for k in ("config", "versions")):
        raise ConfigError(f"{path}: not a run manifest (expected a JSON object with 'config' and 'versions' "
                          f"objects); use another --out")
    return previous


def check_output_directory(out: Path) -> None:
    """One line if ``out`` cannot be a run directory: a file, under a file, inside another run, read-only."""
    for parent in [out, *out.parents]:
        if parent.exists() and not parent.is_dir():
            what = "is a file" if parent == out else f"is under {parent}, which is a file"
            raise ConfigError(f"--out {out}: {what}; expected a directory")
    run = next((parent for parent in out.parents if (parent / MANIFEST_NAME).is_file()), None)
    if run is not None:
        raise ConfigError(f"--out {out}: inside the run directory {run}, which this command does not own; "
                          f"use a directory outside it")
    episodes = out / EPISODES_DIR
    if episodes.exists() and not episodes.is_dir():
        raise ConfigError(f"--out {out}: {episodes} is a file; expected the directory of episode logs")
    existing = next(p for p in [out, *out.parents] if p.exists())
    if not _writable(existing):
        raise ConfigError(f"--out {out}: cannot write in {existing} (read-only); use another --out")


def _writable(directory: Path) -> bool:
    """Whether files can be created in ``directory`` (tried for real: root ignores permission bits, a
    read-only mount does not)."""
    if not os.access(directory, os.W_OK | os.X_OK):
        return False
    try:
        probe = tempfile.NamedTemporaryFile(dir=directory, prefix=".vdb-write-probe-", delete=True)
    except OSError:
        return False
    probe.close()
    return True


_ABSENT = object()


def first_difference(before: Any, now: Any, where: str) -> str | None:
    """``"config.model.options.alpha: 1 now, 0 before"`` for the first place two JSON values differ."""
    if isinstance(before, dict) and isinstance(now, dict):
        for key in sorted(set(before) | set(now)):
            found = first_difference(before.get(key, _ABSENT), now.get(key, _ABSENT), f"{where}.{key}")
            if found:
                return found
        return None
    if before is _ABSENT or now is _ABSENT or before != now:
        return f"{where}: {_short(now)} now, {_short(before)} before"
    return None


def _short(value: Any) -> str:
    if value is _ABSENT:
        return "absent"
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


def load_failures(out: Path) -> dict[str, dict]:
    """Failed episodes recorded in ``out/failures.json`` by earlier sweeps (by episode id)."""
    path = out / FAILURES_NAME
    if not path.exists():
        return {}
    try:
        entries = json.loads(path.read_text(encoding="utf-8")).get("failures", [])
        return {e["episode_id"]: e for e in entries}
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        return {}  # a damaged failures file only means those episodes are retried


def write_failures(out: Path, failures: Mapping[str, dict]) -> None:
    write_json_atomic(out / FAILURES_NAME, {"failures": [failures[k] for k in sorted(failures)]})


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to ``path`` so that it is either the old or the new content, never half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f"{path.name}.{os.getpid()}{PARTIAL_SUFFIX}")
    with open(partial, "w", encoding="utf-8") as handle:
        json.dump(data, handle, indent=2, sort_keys=False)
        handle.write("\n")
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(partial, path)


def _remove_stale_partials(directory: Path) -> None:
    """Delete partial logs that no live writer holds (left by a killed sweep)."""
    if not directory.is_dir():
        return
    for path in directory.glob(f"*{PARTIAL_SUFFIX}"):
        if not partial_in_use(path):
            path.unlink(missing_ok=True)


# -- versions -----------------------------------------------------------------------------------------
def collect_versions(registry: Registry, components: Sequence[ComponentSpec]) -> dict[str, str]:
    """Python, the core, numpy, mcap, the distribution of every component that takes part and the packages
    those distributions require (e.g. torch, transformers and the adapter toolkit of a neural model; a
    required library that itself builds on vladrivebench contributes its requirements too)."""
    versions = {"python": platform.python_version()}
    for dist in ("vladrivebench", "numpy", "mcap"):
        versions[dist] = _dist_version(dist)
    for spec in components:
        dist = registry.get(spec.kind, spec.name).distribution
        if dist and dist != "(local)":
            _add_with_requirements(dist, versions)
    return versions


def _add_with_requirements(dist: str, versions: dict[str, str]) -> None:
    versions[dist] = _dist_version(dist)
    for requirement in _requirements(dist):
        if requirement in versions or _dist_version(requirement) == "-":
            continue
        if "vladrivebench" in _requirements(requirement):
            _add_with_requirements(requirement, versions)
        else:
            versions[requirement] = _dist_version(requirement)


def _requirements(dist: str) -> list[str]:
    """The names of ``dist``'s unconditional requirements (no extras, no environment markers)."""
    try:
        requires = metadata.requires(dist) or []
    except metadata.PackageNotFoundError:
        return []
    names = []
    for line in requires:
        if ";" in line:
            continue
        name = re.split(r"[\s<>=!~\[(]", line.strip(), maxsplit=1)[0]
        if name:
            names.append(re.sub(r"[-_.]+", "-", name).lower())
    return names


def effective_options(registry: Registry, spec: ComponentSpec) -> dict[str, Any]:
    """The options a component was built with: the run's, plus every default of its factory's signature."""
    import inspect

    factory = registry.get(spec.kind, spec.name).factory
    try:
        parameters = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):
        return _plain(dict(spec.options))
    kinds = (inspect.Parameter.KEYWORD_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    defaults = {p.name: p.default for p in parameters if p.kind in kinds and p.default is not p.empty}
    return _plain({**defaults, **dict(spec.options)})


def _dist_version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "-"


def _plain(value: Any) -> Any:
    """JSON round trip: tuples become lists, so stored and fresh configurations compare equal."""
    return json.loads(json.dumps(value, default=str))
