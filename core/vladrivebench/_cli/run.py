"""``vdb run`` (a sweep of closed-loop episodes into an output directory) and ``vdb demo``.

Results go to stdout (a per-scenario table, or JSON with ``--json``); progress goes to stderr.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from vladrivebench.errors import ConfigError, VdbError

CONFIG_KEYS: dict[str, str] = {
    "model": "str", "sim": "str", "controller": "str", "executor": "str", "address": "str", "out": "str",
    "scenarios": "scenarios", "seeds": "int", "seed_offset": "int", "workers": "int",
    "batch": "int",
    "log_images": "bool", "retry_failed": "bool",
    "model_options": "table", "sim_options": "table", "controller_options": "table", "executor_options": "table",
}
"""Keys a ``--config`` TOML file may hold, and their types."""

DEMO_SCENARIOS = ("P.1", "C.1", "TL.1-red", "E.1")
DEMO_SEEDS = 2
# Which model the demo runs, and how, is declared by the model plugins (``register_defaults("demo", …)``).


@dataclass
class RunSettings:
    """A ``vdb run`` request once the config file and the command line are merged."""

    model: str | None = None
    sim: str | None = None  # None: the simulator a plugin declares as the default
    controller: str = "pid"
    scenarios: Any = None
    seeds: int | None = None
    seed_offset: int = 0
    out: str | None = None
    workers: int | None = None
    batch: Any = 1  # lockstep batch size (checked by sweep.batch_size)
    executor: str | None = None
    address: str | None = None
    log_images: bool = False
    retry_failed: bool = False
    model_options: dict[str, Any] = field(default_factory=dict)
    sim_options: dict[str, Any] = field(default_factory=dict)
    controller_options: dict[str, Any] = field(default_factory=dict)
    executor_options: dict[str, Any] = field(default_factory=dict)


def load_run_config(path: Path | str) -> dict[str, Any]:
    """Read and check a run configuration file: unknown keys and wrong types are one-line errors."""
    from vladrivebench._engine.options import load_toml

    data = load_toml(path, "run configuration")
    for key, value in data.items():
        kind = CONFIG_KEYS.get(key)
        if kind is None:
            raise ConfigError(f"run configuration {path}: unknown key {key!r} "
                              f"(expected one of: {', '.join(sorted(CONFIG_KEYS))})")
        problem = _type_problem(kind, value)
        if problem:
            raise ConfigError(f"run configuration {path}: key {key!r} must be {problem}, got {value!r}")
    return data


def _type_problem(kind: str, value: Any) -> str | None:
    checks = {
        "str": (lambda v: isinstance(v, str) and v.strip() != "", "a non-empty string"),
        "int": (lambda v: isinstance(v, int) and not isinstance(v, bool), "a whole number"),
        "bool": (lambda v: isinstance(v, bool), "true or false"),
        "table": (lambda v: isinstance(v, dict), "a table of options"),
        "scenarios": (lambda v: (isinstance(v, str) and v.strip() != "")
                      or (isinstance(v, list) and v and all(isinstance(s, str) for s in v)),
                      "a string (\"all\", \"P.1,C.1\") or a list of scenario ids"),
    }
    ok, expected = checks[kind]
    return None if ok(value) else expected


def merge_settings(file_values: Mapping[str, Any], cli_values: Mapping[str, Any]) -> RunSettings:
    """Config-file values, overridden by the command-line values that were given (options tables merge)."""
    settings = RunSettings()
    for source in (file_values, cli_values):
        for key, value in source.items():
            if key.endswith("_options"):
                getattr(settings, key).update(value)
            else:
                setattr(settings, key, value)
    return settings


def build_request(settings: RunSettings, registry: Any):
    """The sweep's :class:`RunConfig`, its executor and the executor's description, all checked."""
    from vladrivebench._engine.sweep import ComponentSpec, RunConfig, batch_size, seed_list
    from vladrivebench._scenarios.spec import resolve_scenarios

    missing = [flag for flag, value in (("--model", settings.model), ("--scenarios", settings.scenarios),
                                        ("--seeds", settings.seeds), ("--out", settings.out)) if value is None]
    if missing:
        raise ConfigError(f"vdb run: missing {', '.join(missing)} (give them on the command line or in --config)")
    seeds = seed_list(settings.seeds, settings.seed_offset)
    batch = batch_size(settings.batch)
    scenarios = resolve_scenarios(settings.scenarios, registry)
    sim = settings.sim or registry.default("simulator", "--sim").name
    config = RunConfig(ComponentSpec("model", settings.model, settings.model_options),
                       ComponentSpec("simulator", sim, settings.sim_options),
                       ComponentSpec("controller", settings.controller, settings.controller_options),
                       tuple(scenarios), seeds, settings.log_images, batch)
    executor, executor_info = build_executor(registry, settings.executor, settings.workers, settings.address,
                                             settings.executor_options)
    return config, executor, executor_info


def build_executor(registry: Any, name: str | None, workers: int | None, address: str | None,
                   executor_options: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    """The executor ``--executor/--workers/--address/--executor-opt`` ask for (sequential unless ``--workers``
    is above 1 or another is named) and its description, every mistake one line."""
    from vladrivebench._engine.registry import check_options

    executor_name = name or ("process" if (workers or 1) > 1 else "sequential")
    _check_workers(executor_name, workers)
    options = dict(executor_options)
    if address is not None:
        options["address"] = address
    options["workers"] = workers if workers is not None else _default_workers(executor_name)
    check_options("executor", executor_name, registry.get("executor", executor_name).factory, options)
    return registry.create("executor", executor_name, options), {"name": executor_name, **options}


def _check_workers(executor_name: str, workers: Any) -> None:
    if workers is None:
        return
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise ConfigError(f"--workers must be a whole number from 1 to {MAX_WORKERS}, got {workers!r}")
    if executor_name == "sequential" and workers != 1:
        raise ConfigError(f"--executor sequential runs one episode at a time; got --workers {workers} "
                          f"(use --executor process for parallel workers)")


MAX_WORKERS = 512


def _default_workers(executor_name: str) -> int:
    if executor_name == "pipelined":  # two jobs in flight: one's model step while the other's harness runs
        return 2
    return 1 if executor_name == "sequential" else max(1, min(os.cpu_count() or 1, 8))


# -- progress and summary -----------------------------------------------------------------------------
def episode_progress(what: str) -> Callable[[Any, int, int], None]:
    """A sweep's ``on_outcome(outcome, done, todo)`` callback drawing the shared progress line."""
    from vladrivebench._cli.progress import Progress

    shown: list[Progress] = []

    def on_outcome(outcome: Any, done: int, todo: int) -> None:
        if not shown:
            shown.append(Progress(what, todo, unit="episodes", close=True, interval=2.0))
        progress = shown[0]
        progress.advance(failed=outcome.status != "ok", count=done - progress.done)

    return on_outcome


def format_summary(summary: Any) -> str:
    """The per-scenario results table and one line saying what happened and where the logs are."""
    header = ("scenario", "episodes", "failed", "collisions", "violations", "route compl.", "mean speed")
    rows = [header]
    for row in summary.per_scenario():
        completion = "-" if row["route_completion"] is None else f"{row['route_completion']:.2f}"
        speed = "-" if row["mean_speed"] is None else f"{row['mean_speed']:.2f} m/s"
        rows.append((row["scenario"], str(row["episodes"]), str(row["failed"]), str(row["collisions"]),
                     str(row["violations"]), completion, speed))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = ["  ".join(cell.ljust(w) if i == 0 else cell.rjust(w) for i, (cell, w) in enumerate(zip(r, widths, strict=True)))
             for r in rows]
    lines.append(f"{summary.total} episodes: {len(summary.results)} complete ({summary.ran} run now, "
                 f"{summary.skipped} already there), {len(summary.failures)} failed; "
                 f"{summary.seconds:.1f} s. Logs: {summary.out / 'episodes'}")
    return "\n".join(lines)


def report(summary: Any, *, as_json: bool) -> None:
    """Print the summary (table or JSON) and fail with one line if any episode failed."""
    click.echo(json.dumps(summary.to_json(), indent=2) if as_json else format_summary(summary))
    if summary.failures:
        first_id = sorted(summary.failures)[0]
        reason = summary.failures[first_id].get("error", "")
        raise VdbError(f"{len(summary.failures)} of {summary.total} episodes failed; first, {first_id}: "
                       f"{reason} (details: {summary.out / 'failures.json'})")


def execute(settings: RunSettings, *, quiet: bool):
    """Run the sweep a :class:`RunSettings` describes and return its summary."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.sweep import run_sweep

    registry = get_registry()
    config, executor, executor_info = build_request(settings, registry)
    return run_sweep(config, Path(settings.out), executor=executor, executor_info=executor_info,
                     retry_failed=settings.retry_failed, registry=registry,
                     on_outcome=None if quiet else episode_progress("vdb run"), on_note=print_note)


def print_note(text: str) -> None:
    """One ``note: …`` line on stderr (even with ``--quiet``): the command runs otherwise than asked, e.g. a
    ``--batch`` its model or paradigm cannot use. Results on stdout are unaffected."""
    click.echo(f"note: {text}", err=True)


# -- commands -----------------------------------------------------------------------------------------
@click.command("run")
@click.option("--model", help="Registered model name (see `vdb list-plugins`).")
@click.option("--sim", help="Simulator (default: kinematic).")
@click.option("--controller", help="Trajectory tracker: pid or mpc (default: pid).")
@click.option("--scenarios", help="'all', ids 'P.1,C.1', family names ('pedestrian') or globs ('TL.*').")
@click.option("--seeds", type=int, help="Number of seeds N: seeds 0 … N−1 (plus --seed-offset).")
@click.option("--seed-offset", type=int, help="First seed (default 0).")
@click.option("--out", type=click.Path(file_okay=False), help="Output directory (resumed if it holds this run).")
@click.option("--model-opt", multiple=True, metavar="KEY=VALUE", help="Model option (repeatable).")
@click.option("--sim-opt", multiple=True, metavar="KEY=VALUE", help="Simulator option (repeatable).")
@click.option("--controller-opt", multiple=True, metavar="KEY=VALUE", help="Controller option (repeatable).")
@click.option("--executor", help="sequential, process, pipelined, or a plugin's (e.g. ray); default: process if --workers > 1.")
@click.option("--executor-opt", multiple=True, metavar="KEY=VALUE", help="Executor option (repeatable).")
@click.option("--workers", type=int, help="Parallel workers (process: default = CPU count, at most 8; pipelined: batch jobs in flight, default 2).")
@click.option("--address", help="Cluster address for a distributed executor (e.g. --executor ray).")
@click.option("--batch", help="Episodes advancing in lockstep through one model (default 1; part of the "
                              "configuration: results may differ from unbatched in floating point).")
@click.option("--config", "config_file", type=click.Path(dir_okay=False),
              help="TOML run configuration; command-line flags override it.")
@click.option("--log-images", is_flag=True,
              help="Also log the camera images (PNG): the front image every step, each rig camera on /camera/NAME.")
@click.option("--retry-failed", is_flag=True, help="Redo episodes recorded as failed in OUT/failures.json.")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary on stdout.")
@click.pass_context
def run_command(ctx: click.Context, config_file: str | None, quiet: bool, as_json: bool, **_: Any) -> None:
    """Run closed-loop episodes (scenarios × seeds) and log each one to OUT/episodes/*.mcap.

    Example: vdb run --model scripted --scenarios P.1,C.1 --seeds 3 --out runs/first
    """
    from vladrivebench._engine.options import parse_options

    file_values = load_run_config(config_file) if config_file else {}
    given = {name: value for name, value in ctx.params.items()
             if name not in {"config_file", "quiet", "as_json"}
             and ctx.get_parameter_source(name) == click.core.ParameterSource.COMMANDLINE}
    for flag in ("model", "sim", "controller", "executor"):
        if f"{flag}_opt" in given:
            given[f"{flag}_options"] = parse_options(given.pop(f"{flag}_opt"), f"--{flag}-opt")
    for name in ("seeds", "workers", "seed_offset", "batch"):
        if name in given and given[name] is None:
            given.pop(name)
    settings = merge_settings(file_values, given)
    report(execute(settings, quiet=quiet), as_json=as_json)


@click.command("demo")
@click.option("--model", "model", default=None,
              help="A model whose plugin declares how to demo it (default: the highest-priority one, e.g. kv).")
@click.option("--out", type=click.Path(file_okay=False), help="Output directory (default: a new temporary one).")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary on stdout.")
def demo_command(model: str | None, out: str | None, quiet: bool, as_json: bool) -> None:
    """A small end-to-end evaluation: P.1, C.1, TL.1-red and E.1 × 2 seeds, labelled, summarised, reported."""
    from vladrivebench._cli.demo import label_and_summarise
    from vladrivebench._engine.registry import get_registry

    registry = get_registry()
    setup = demo_setup(registry, model)
    model = setup.name
    out = out or tempfile.mkdtemp(prefix="vdb-demo-")
    summary = run_demo(Path(out), model=model, quiet=quiet, registry=registry)
    report(summary, as_json=as_json)
    if as_json:
        return
    lines, report_path = label_and_summarise(Path(out), registry, quiet=quiet)
    labeler = registry.default("labeler", "a labeler plugin").name
    click.echo(f"\nCoT quality and alignment ({labeler} labels; 95 % Wilson intervals) — {setup.settings.get('about', model)}:")
    for line in lines:
        click.echo(f"  {line}")
    click.echo(f"\nReport: {report_path}\nMore: vdb metrics {out}   |   vdb report {out} --format md --out report.md"
               f"\nIntervention: vdb intervene --model {model} --controller {setup.settings.get('controller', 'pid')} "
               f"--route E.1 --mode open-loop --out {out}-ol")


def demo_setup(registry: Any, model: str | None) -> Any:
    """How ``vdb demo`` runs ``model`` (or the default demo model), as its plugin declared it."""
    if model is None:
        return registry.default("demo", "--model")
    for declared in registry.default_declarations("demo"):
        if declared.name == model:
            return declared
    offered = ", ".join(sorted({d.name for d in registry.default_declarations("demo")})) or "none installed"
    raise ConfigError(f"vdb demo --model: expected a model whose plugin declares a demo ({offered}), got "
                      f"{model!r} (use `vdb run` for any other model)")


def run_demo(out: Path, *, model: str | None = None, quiet: bool = False, workers: int = 1, registry: Any = None):
    """The demo sweep of ``model`` (as its plugin declares it) on the default simulator into ``out``."""
    from vladrivebench._engine.registry import get_registry

    declared = demo_setup(registry or get_registry(), model)
    setup = declared.settings
    settings = RunSettings(model=declared.name, controller=setup.get("controller", "pid"),
                           sim_options=dict(setup.get("sim_options", {})),
                           model_options=dict(setup.get("model_options", {})),
                           scenarios=list(DEMO_SCENARIOS), seeds=DEMO_SEEDS, out=str(out), workers=workers,
                           batch=setup.get("batch", 1))
    return execute(settings, quiet=quiet)


COMMANDS = [run_command, demo_command]
