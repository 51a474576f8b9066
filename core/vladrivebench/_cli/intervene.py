"""``vdb intervene`` (the CoT intervention protocol) and ``vdb conditions`` (the condition library).

Results go to stdout (the paper-shaped tables, or JSON with ``--json``); progress goes to stderr. A run
whose selfsplice gate fails prints one loud ``vdb: error: INVALID RUN …`` line on stderr and exits with status 3.
"""

from __future__ import annotations

import json
import shlex
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from vladrivebench.errors import ConfigError, VdbError


class InvalidRunError(VdbError):
    """The run completed but its selfsplice gate failed: results are written, marked invalid; exit 3."""

    exit_code = 3



class ParadigmChoice(click.ParamType):
    """``--mode``: the name of a registered paradigm (the choices are the registry's, read when needed, so
    defining the command loads no plugin); an unknown name is one line with suggestions."""

    name = "paradigm"

    def names(self) -> list[str]:
        from vladrivebench._engine.registry import get_registry

        return get_registry().names("paradigm")

    def get_metavar(self, param: click.Parameter, ctx: click.Context | None = None) -> str:
        return "[" + "|".join(self.names()) + "]"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> str:
        from vladrivebench.errors import UnknownNameError

        names = self.names()
        if value not in names:
            raise UnknownNameError("paradigm", str(value), names)
        return value

    def shell_complete(self, ctx: click.Context, param: click.Parameter, incomplete: str) -> list[Any]:
        from click.shell_completion import CompletionItem

        return [CompletionItem(n) for n in self.names() if n.startswith(incomplete)]


def parse_seconds(text: str, flag: str) -> tuple[float, ...]:
    """``"2,4,5.9"`` → (2.0, 4.0, 5.9); anything else is a one-line ConfigError naming the flag."""
    try:
        values = tuple(float(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise ConfigError(f"{flag} {text!r}: expected seconds separated by commas, e.g. {flag} 2,3") from None
    if not values:
        raise ConfigError(f"{flag} {text!r}: expected at least one number of seconds")
    return values


def parse_names(text: str, flag: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(part.strip() for part in text.split(",") if part.strip()))
    if not names:
        raise ConfigError(f"{flag} {text!r}: expected names separated by commas, e.g. {flag} selfsplice,car")
    return names


def episode_progress(what: str) -> Callable[[str, int, int], None]:
    """An intervention run's ``progress(label, done, total)`` callback drawing the shared progress line."""
    from vladrivebench._cli.progress import Progress

    shown: list[Progress] = []

    def progress(label: str, done: int, total: int) -> None:
        if not shown:
            shown.append(Progress(what, total, unit="episodes", close=True))
        shown[0].advance(count=done - shown[0].done, note=label)

    return progress


def build_config(opts: dict[str, Any], registry: Any) -> Any:
    """The :class:`InterventionConfig` of the command-line options (every mistake one line)."""
    from vladrivebench._engine.options import parse_options
    from vladrivebench._engine.sweep import ComponentSpec, batch_size, seed_list
    from vladrivebench._intervention.runs import InterventionConfig, build_paradigm
    from vladrivebench._scenarios.spec import resolve_scenarios

    if not opts["model"]:
        raise ConfigError("--model is required (see `vdb list-plugins` for the registered models)")
    if not opts["route"]:
        raise ConfigError("--route is required (e.g. --route E.1; safety: --route SAFE.kerb-ped)")
    mode = opts["mode"]
    paradigm_options = parse_options(opts["paradigm_opt"], "--paradigm-opt")
    paradigm = build_paradigm(registry, mode, paradigm_options)
    routes = tuple(resolve_scenarios(list(parse_names(opts["route"], "--route")), registry))
    harvest = resolve_scenarios(opts["harvest_route"], registry)[0] if opts["harvest_route"] else None
    given = opts["conditions"]  # an empty --conditions '' is refused, not read as the default
    if given is not None:
        conditions = parse_names(given, "--conditions")
    else:
        conditions = tuple(paradigm.default_conditions) or ("selfsplice",)
    checkpoints = parse_seconds(opts["checkpoints"], "--checkpoints")
    longest = min(route.max_time_s for route in routes)
    if mode == "closed-loop" and (beyond := [t for t in checkpoints if t >= longest]):
        raise ConfigError(f"--checkpoints {opts['checkpoints']!r}: {beyond[0]:g} s is not within the route's "
                          f"episode ({longest:g} s); expected checkpoints below {longest:g} s")
    return InterventionConfig(
        mode=mode, paradigm_options=paradigm_options,
        model=ComponentSpec("model", opts["model"], parse_options(opts["model_opt"], "--model-opt")),
        simulator=ComponentSpec("simulator", opts["sim"] or registry.default("simulator", "--sim").name,
                                parse_options(opts["sim_opt"], "--sim-opt")),
        controller=ComponentSpec("controller", opts["controller"],
                                 parse_options(opts["controller_opt"], "--controller-opt")),
        routes=routes, conditions=conditions, seeds=seed_list(opts["seeds"], opts["seed_offset"]),
        horizons=parse_seconds(opts["horizons"], "--horizons"),
        checkpoints=checkpoints,
        threshold=opts["threshold"], alpha=opts["alpha"], harvest_route=harvest,
        condition_files=tuple(str(Path(f)) for f in opts["condition_file"]),
        batch_conditions=opts["batch_conditions"],
        batch=batch_size(1 if opts["batch"] is None else opts["batch"]),
    )


def print_plan(plans: list[dict[str, Any]], as_json: bool) -> None:
    if as_json:
        click.echo(json.dumps({"plan": plans}, indent=2))
        return
    click.echo("Seeds needed (two-sided seed-level t-test, statsmodels TTestPower; α divided by the number of "
               "tested conditions, Holm's first step)")
    header = ("route", "condition", "measure", "pilot seeds", "effect (m)", "seed sd (m)", "d", "power", "α",
              "seeds needed")
    rows = [(p["route"], p["condition"], p["measure"], str(p["pilot_seeds"]), _num(p["effect_m"]),
             _num(p["seed_sd"]), _num(p["effect_size"]), f"{p['power']:g}", f"{p['alpha']:.3g}",
             "not detectable (zero effect)" if p["seeds"] is None else str(p["seeds"])) for p in plans]
    widths = [max(len(x) for x in col) for col in zip(header, *rows, strict=True)]
    for line in [header, tuple("-" * w for w in widths), *rows]:
        click.echo("  ".join(x.ljust(w) for x, w in zip(line, widths, strict=True)))


def _num(value: Any) -> str:
    if isinstance(value, str):
        return value
    return "—" if value is None else f"{value:.3g}"


@click.command("intervene")
@click.option("--model", help="Registered model name (see `vdb list-plugins`).")
@click.option("--sim", default=None, help="Simulator (default: the one a simulator plugin declares, e.g. kinematic).")
@click.option("--controller", default="pid", show_default=True, help="Trajectory tracker (pid or mpc).")
@click.option("--route", help="Route id(s), comma-separated: E.1, E.2; safety: SAFE.kerb-ped, SAFE.centre-ped, SAFE.car.")
@click.option("--mode", type=ParadigmChoice(), default="open-loop", show_default=True,
              help="Intervention paradigm: any registered one (`vdb list-plugins`).")
@click.option("--paradigm-opt", multiple=True, metavar="KEY=VALUE", help="Paradigm option (repeatable).")
@click.option("--conditions", help="Comma-separated condition names (default: the paradigm's; open-loop and "
              "closed-loop: selfsplice,accel,pedestrian,car; safety: accel). See `vdb conditions`.")
@click.option("--condition-file", multiple=True, type=click.Path(dir_okay=False),
              help="TOML/JSON file of extra conditions (repeatable).")
# 5 = intervention.DEFAULT_SEEDS, written out so that `vdb --help` does not import the protocol (numpy, mcap)
@click.option("--seeds", type=int, default=5, show_default=True,
              help="Number of seeds N: seeds 0 … N−1 (plus --seed-offset).")
@click.option("--seed-offset", type=int, default=0, help="First seed (default 0).")
@click.option("--out", type=click.Path(file_okay=False), help="Output directory (resumed if it holds this run).")
@click.option("--model-opt", multiple=True, metavar="KEY=VALUE", help="Model option (repeatable).")
@click.option("--sim-opt", multiple=True, metavar="KEY=VALUE", help="Simulator option (repeatable).")
@click.option("--controller-opt", multiple=True, metavar="KEY=VALUE", help="Controller option (repeatable).")
@click.option("--horizons", default="2,3", show_default=True, help="Open-loop horizons (s).")
@click.option("--checkpoints", default="2,4,5.9", show_default=True, help="Closed-loop checkpoints (s).")
@click.option("--threshold", type=float, default=0.1, show_default=True,
              help="A step is shorter/longer when it differs by more than this (m).")
@click.option("--alpha", type=float, default=0.05, show_default=True, help="Significance level (Holm).")
@click.option("--harvest-route", help="Route whose baseline gives harvested conditions (origbrake) their text "
              "(default: the first --route).")
@click.option("--batch-conditions", is_flag=True,
              help="Decode a step's open-loop conditions in one batch when the model has decode_batch.")
@click.option("--batch", help="Planned episodes advancing in lockstep through one model (default 1; part of the "
              "configuration: results may differ from unbatched in floating point).")
@click.option("--executor", help="sequential, process, pipelined, or a plugin's (e.g. ray); default: process if --workers > 1. "
                                 "Workers run the batches (or episodes) in parallel: the same bytes as one process.")
@click.option("--executor-opt", multiple=True, metavar="KEY=VALUE", help="Executor option (repeatable).")
@click.option("--workers", type=int, help="Parallel workers (process: default = CPU count, at most 8; pipelined: batch jobs in flight, default 2).")
@click.option("--address", help="Cluster address for a distributed executor (e.g. --executor ray).")
@click.option("--plan", is_flag=True, help="Print how many seeds each condition needs (from OUT's results, or "
              "after running this pilot).")
@click.option("--effect", type=float, help="--plan: the effect to detect, in metres (default: the pilot's).")
@click.option("--power", type=float, default=0.8, show_default=True, help="--plan: the power wanted.")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON.")
def intervene_command(**opts: Any) -> None:
    """Inject CoT conditions and measure what they do to the action (paper Section 3.6).

    \b
    Examples:
      vdb intervene --model scripted --route E.1 --mode open-loop --seeds 5 --out out/ol
      vdb intervene --model scripted --route E.1 --mode closed-loop --conditions selfsplice,car --seeds 5 --out out/cl
      vdb intervene --model scripted --route SAFE.kerb-ped --mode safety --seeds 4 --out out/safe
      vdb intervene --plan --out out/ol --effect 0.1
    """
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._intervention.metric import summary_text
    from vladrivebench._intervention.runs import InterventionRun, gate_message, load_results, seed_plan

    if not opts["out"]:
        raise ConfigError("--out is required (the directory for the logs and results)")
    out = Path(opts["out"])
    if not 0 < opts["power"] < 1:
        raise ConfigError(f"--power must be in (0, 1), got {opts['power']}")
    results = load_results(out) if opts["plan"] and not opts["model"] else None
    if opts["plan"] and results is None and not opts["model"]:
        raise ConfigError(f"--plan: {out} holds no intervention results; give the pilot's options (--model, "
                          f"--route, --seeds …) to run it first")
    if results is None:
        registry = get_registry()
        config = build_config(opts, registry)
        progress = None if opts["quiet"] else episode_progress("vdb intervene")
        from vladrivebench._cli.run import build_executor, print_note
        from vladrivebench._engine.options import parse_options

        executor, _ = build_executor(registry, opts["executor"], opts["workers"], opts["address"],
                                     parse_options(opts["executor_opt"], "--executor-opt"))
        results = InterventionRun(config, out, registry=registry, progress=progress, on_note=print_note,
                                  executor=executor).run()
    if opts["plan"]:
        plans = seed_plan(results, effect_m=opts["effect"], power=opts["power"], alpha=opts["alpha"],
                          registry=get_registry())
        print_plan(plans, opts["as_json"])
        from vladrivebench._engine.sweep import write_json_atomic

        write_json_atomic(out / "plan.json", {"plan": plans})
    elif opts["as_json"]:
        click.echo(json.dumps(results, indent=2))
    else:
        click.echo(summary_text(results))
        report = shlex.quote(str(out / "report.html"))
        click.echo(f"\nlogs and results: {out} (intervention.json); `vdb report {shlex.quote(str(out))} --out "
                   f"{report}` for plots")
    message = gate_message(results)
    if message:
        raise InvalidRunError(message)


@click.command("conditions")
@click.option("--condition-file", multiple=True, type=click.Path(dir_okay=False),
              help="Also load conditions from this TOML/JSON file (repeatable).")
@click.option("--json", "as_json", is_flag=True, help="Print the library as JSON.")
def conditions_command(condition_file: tuple[str, ...], as_json: bool) -> None:
    """List the intervention conditions (built-in, from plugins, from files)."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._intervention.conditions import build_library

    library = build_library(get_registry(), condition_file)
    entries = [{**library.get(n).to_json(), "source": library.sources.get(n, "")} for n in library.names()]
    if as_json:
        click.echo(json.dumps(entries, indent=2))
        return
    width = max(len(e["name"]) for e in entries)
    for e in entries:
        click.echo(f"{e['name'].ljust(width)}  {e['kind']:<10} {e['intent']:<10} {e['description']}  [{e['source']}]",
                   color=False)
    click.echo("\nparametric: depicts-<N> ('depicts' repeated N times), <condition>-swap-<slot> (that slot "
               "replaced by the model's own)", err=False)


COMMANDS = [intervene_command, conditions_command]
