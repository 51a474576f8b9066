"""``vdb run`` (a sweep of closed-loop episodes into an output directory) and ``vdb demo``.

Results go to stdout (a per-scenario table, or JSON with ``--json``); progress goes to stderr.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click

from vladrivebench.errors import ConfigError, VdbError

CONFIG_KEYS: dict[str, str] = {
    "model": "str", "sim": "str", "controller": "str", "executor": "str", "address": "str", "out": "str",
    "scenarios": "scenarios", "seeds": "int", "seed_offset": "int", "workers": "int",
    "log_images": "bool", "retry_failed": "bool",
    "model_options": "table", "sim_options": "table", "controller_options": "table", "executor_options": "table",
}
"""Keys a ``--config`` TOML file may hold, and their types."""

DEMO_SCENARIOS = ("P.1", "C.1", "TL.1-red", "E.1")
DEMO_SEEDS = 2
# Known error rates, so the scripted demo shows the benchmark recovering them from the CoTs alone.
DEMO_MODEL_OPTIONS = {"miss_rate": 0.2, "hallucination_rate": 0.1, "contradiction_rate": 0.05, "alpha": 0.5}
DEMO_SETUPS: dict[str, dict[str, Any]] = {
    # the neural reference sees only the camera, so the camera is rendered; it was trained with the MPC tracker
    "kv": {"controller": "mpc", "sim_options": {}, "model_options": {},
           "about": "the neural kv model (Alpamayo-like, trained here), camera only"},
    # the scripted model perceives through the ground truth: no camera needed (3x faster)
    "scripted": {"controller": "pid", "sim_options": {"render": False}, "model_options": DEMO_MODEL_OPTIONS,
                 "about": "the scripted model configured with "
                          + ", ".join(f"{k}={v}" for k, v in DEMO_MODEL_OPTIONS.items())},
}


@dataclass
class RunSettings:
    """A ``vdb run`` request once the config file and the command line are merged."""

    model: str | None = None
    sim: str = "kinematic"
    controller: str = "pid"
    scenarios: Any = None
    seeds: int | None = None
    seed_offset: int = 0
    out: str | None = None
    workers: int | None = None
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
    from vladrivebench._engine.registry import check_options
    from vladrivebench._engine.sweep import ComponentSpec, RunConfig, seed_list
    from vladrivebench._scenarios.spec import resolve_scenarios

    missing = [flag for flag, value in (("--model", settings.model), ("--scenarios", settings.scenarios),
                                        ("--seeds", settings.seeds), ("--out", settings.out)) if value is None]
    if missing:
        raise ConfigError(f"vdb run: missing {', '.join(missing)} (give them on the command line or in --config)")
    seeds = seed_list(settings.seeds, settings.seed_offset)
    scenarios = resolve_scenarios(settings.scenarios, registry)
    config = RunConfig(ComponentSpec("model", settings.model, settings.model_options),
                       ComponentSpec("simulator", settings.sim, settings.sim_options),
                       ComponentSpec("controller", settings.controller, settings.controller_options),
                       tuple(scenarios), seeds, settings.log_images)
    executor_name = settings.executor or ("process" if (settings.workers or 1) > 1 else "sequential")
    options = dict(settings.executor_options)
    if settings.address is not None:
        options["address"] = settings.address
    options["workers"] = settings.workers if settings.workers is not None else _default_workers(executor_name)
    check_options("executor", executor_name, registry.get("executor", executor_name).factory, options)
    executor = registry.create("executor", executor_name, options)
    return config, executor, {"name": executor_name, **options}


def _default_workers(executor_name: str) -> int:
    return 1 if executor_name == "sequential" else max(1, min(os.cpu_count() or 1, 8))


# -- progress and summary -----------------------------------------------------------------------------
class Progress:
    """Episodes done / to do, rate and ETA on stderr: one updating line on a terminal, else a line at most
    every ``interval`` seconds (and the last one)."""

    def __init__(self, stream: Any = None, interval: float = 2.0):
        self.stream = stream or sys.stderr
        self.interval = interval
        self.started = time.perf_counter()
        self.last_print = -1e9
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.failed = 0

    def __call__(self, outcome: Any, done: int, todo: int) -> None:
        self.failed += outcome.status != "ok"
        now = time.perf_counter()
        if done < todo and now - self.last_print < (0.1 if self.tty else self.interval):
            return
        self.last_print = now
        elapsed = now - self.started
        rate = done / elapsed if elapsed > 0 else 0.0
        eta = (todo - done) / rate if rate > 0 else 0.0
        failed = f", {self.failed} failed" if self.failed else ""
        line = f"vdb: {done}/{todo} episodes{failed}, {rate:.2f}/s, ETA {_duration(eta)}"
        if self.tty:
            self.stream.write("\r" + line.ljust(70) + ("\n" if done == todo else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    minutes, seconds = divmod(seconds, 60)
    if minutes < 60:
        return f"{minutes}m{seconds:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"


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
                     on_outcome=None if quiet else Progress())


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
@click.option("--executor", help="sequential, process, or a plugin's (e.g. ray); default: process if --workers > 1.")
@click.option("--executor-opt", multiple=True, metavar="KEY=VALUE", help="Executor option (repeatable).")
@click.option("--workers", type=int, help="Parallel workers (process: default = CPU count, at most 8).")
@click.option("--address", help="Cluster address for a distributed executor (e.g. --executor ray).")
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
    for name in ("seeds", "workers", "seed_offset"):
        if name in given and given[name] is None:
            given.pop(name)
    settings = merge_settings(file_values, given)
    report(execute(settings, quiet=quiet), as_json=as_json)


@click.command("demo")
@click.option("--model", "model", default=None,
              help="kv (the neural Alpamayo-like reference, the default when installed) or scripted.")
@click.option("--out", type=click.Path(file_okay=False), help="Output directory (default: a new temporary one).")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary on stdout.")
def demo_command(model: str | None, out: str | None, quiet: bool, as_json: bool) -> None:
    """A small end-to-end evaluation: P.1, C.1, TL.1-red and E.1 × 2 seeds, labelled, summarised, reported."""
    from vladrivebench._cli.demo import label_and_summarise
    from vladrivebench._engine.registry import get_registry

    registry = get_registry()
    model = model or ("kv" if "kv" in registry.names("model") else "scripted")
    if model not in DEMO_SETUPS:
        raise ConfigError(f"vdb demo --model: expected one of {', '.join(DEMO_SETUPS)}, got {model!r} "
                          f"(use `vdb run` for any other model)")
    out = out or tempfile.mkdtemp(prefix="vdb-demo-")
    summary = run_demo(Path(out), model=model, quiet=quiet)
    report(summary, as_json=as_json)
    if as_json:
        return
    lines, report_path = label_and_summarise(Path(out), registry, quiet=quiet)
    click.echo(f"\nCoT quality and alignment (lexicon labels; 95 % Wilson intervals) — {DEMO_SETUPS[model]['about']}:")
    for line in lines:
        click.echo(f"  {line}")
    click.echo(f"\nReport: {report_path}\nMore: vdb metrics {out}   |   vdb report {out} --format md --out report.md"
               f"\nIntervention: vdb intervene --model {model} --controller {DEMO_SETUPS[model]['controller']} "
               f"--route E.1 --mode open-loop --out {out}-ol")


def run_demo(out: Path, *, model: str = "scripted", quiet: bool = False, workers: int = 1):
    """The demo sweep of ``model`` (see :data:`DEMO_SETUPS`) on the kinematic simulator into ``out``."""
    setup = DEMO_SETUPS[model]
    settings = RunSettings(model=model, sim="kinematic", controller=setup["controller"],
                           sim_options=dict(setup["sim_options"]), model_options=dict(setup["model_options"]),
                           scenarios=list(DEMO_SCENARIOS), seeds=DEMO_SEEDS, out=str(out), workers=workers)
    return execute(settings, quiet=quiet)


COMMANDS = [run_command, demo_command]
