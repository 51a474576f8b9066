"""The closed-loop paradigm (paper Section 3.6, Tables 8-9): the injected CoT drives whole episodes.

Per route and seed: a baseline episode driven by the model's own CoT and one episode per condition driven
by the injected CoT at every step (:class:`InjectionPolicy`); each injected step also logs the *shadow*:
the model's own CoT, its trajectory and the control the controller would have produced from it (the
paper's *orig. brakes*, via a :class:`~vladrivebench.intervention.ShadowController`). Results: distance
differences against the matched-seed baseline at the checkpoints (t-intervals across seeds), brakes,
steps, speed, route completion, collisions, and the difference curves over time. The selfsplice episode
must drive exactly as its baseline (else the gate fails).

Built only from the public API, the way a third-party paradigm would be.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from vladrivebench.intervention import (
    SELFSPLICE,
    BaselinePolicy,
    EpisodeSummary,
    GateTally,
    InjectionPolicy,
    LaneStep,
    LoggedEpisodes,
    PlannedEpisode,
    RunContext,
    cell_value,
    closed_loop_stats,
    cumulative_distance,
    episode_summary,
    from_json_number,
    horizon_key,
    injection_step_batch,
    interval_text,
    json_number,
    model_text,
    number_text,
    t_interval,
)
from vladrivebench.metrics import Cell, Plot, Row, Series, Table

DEFAULT_CONDITIONS = ("selfsplice", "accel", "pedestrian", "car")
CURVE_STEP_S = 0.5
"""Spacing (s) of the closed-loop distance-difference curves drawn in reports."""


class ClosedLoopParadigm:
    """``--mode closed-loop``: per seed a baseline and one episode per condition, each driven by its CoT."""

    name = "closed-loop"
    default_conditions = DEFAULT_CONDITIONS

    def check(self, config: Any) -> None:
        """Any route and any conditions will do."""

    def plan(self, config: Any) -> list[PlannedEpisode]:
        """Per route and seed: the baseline, then one ``injected`` episode per tested condition."""
        plan = []
        for route in config.routes:
            for seed in config.seeds:
                plan.append(PlannedEpisode(route, seed, "baseline"))
                plan += [PlannedEpisode(route, seed, "injected", name) for name in config.tested]
        return plan

    def policy(self, episode: PlannedEpisode, context: RunContext) -> Any:
        """The own CoT for the baseline; the condition's text (with the shadow alongside) otherwise."""
        if episode.condition is None:
            return BaselinePolicy()
        return InjectionPolicy(context.splicer, episode.condition, context.config.horizons)

    def step_batch(self, model: Any, lanes: Sequence[LaneStep], context: RunContext) -> list[Any]:
        """``--batch``: the lanes' own CoTs, the selfsplice mirror and the other injections in batched calls."""
        return injection_step_batch(model, lanes, context)

    def lockstep_group(self, episode: PlannedEpisode) -> Any:
        """A seed's baseline and selfsplice episodes advance together: they are compared bit for bit."""
        if episode.condition is None or episode.condition == SELFSPLICE:
            return (episode.route.id, episode.seed)
        return None

    def analyse(self, config: Mapping[str, Any], episodes: LoggedEpisodes, gate: GateTally) -> dict[str, Any]:
        """``{"closed_loop": {route: {"baseline", "stats", "episodes", "curves"}}}``."""
        return {"closed_loop": {route: closed_loop_route(route, config, episodes, gate)
                                for route in config["routes"]}}

    def tables(self, results: Mapping[str, Any]) -> list[Any]:
        """One table per route and the distance-difference curves."""
        items: list[Any] = [closed_loop_table(results, route) for route in results["closed_loop"]]
        return items + [closed_loop_plot(results)]

    def pilot_effects(self, results: Mapping[str, Any], route: str) -> list[tuple[str, list[float], str]]:
        """The per-seed distance differences at the last checkpoint."""
        block = results["closed_loop"][route]
        last = len(results["checkpoints"]) - 1
        base = block["episodes"]["baseline"]
        effects = []
        for cond in results["conditions"]:
            eps = block["episodes"][cond]
            diffs = [float(eps[s]["distances"][last]) - float(base[s]["distances"][last]) for s in eps if s in base]
            effects.append((cond, diffs, f"closed-loop distance @{horizon_key(results['checkpoints'][last])}s"))
        return effects


def closed_loop_route(route: str, config: Mapping[str, Any], episodes: LoggedEpisodes,
                      gate: GateTally) -> dict[str, Any]:
    """One route's closed-loop results against the matched-seed baselines."""
    checkpoints = list(config["checkpoints"])
    intents = {name: d.get("intent", "none") for name, d in config["definitions"].items()}
    baselines = {s: episode_summary(episodes.require(route, s, "baseline"), checkpoints, baseline=True)
                 for s in config["seeds"]}
    summaries: dict[str, dict[int, EpisodeSummary]] = {}
    curves: dict[str, Any] = {}
    grid = _curve_grid(checkpoints, [episodes[(route, s, "baseline")] for s in config["seeds"]])
    base_curves = {s: cumulative_distance(*_path(episodes[(route, s, "baseline")]), grid) for s in config["seeds"]}
    for cond in config["conditions"]:
        summaries[cond] = {}
        per_seed = []
        for seed in config["seeds"]:
            episode = episodes.require(route, seed, cond)
            summaries[cond][seed] = episode_summary(episode, checkpoints, baseline=False)
            gate.add_episode(episode, route, seed, cond)
            curve = cumulative_distance(*_path(episode), grid)
            per_seed.append([a - b for a, b in zip(curve, base_curves[seed], strict=True)])
            if cond == SELFSPLICE and not _same_drive(episode, episodes[(route, seed, "baseline")]):
                gate.episode_mismatches.append(f"{route} seed {seed}")
        columns = list(zip(*per_seed, strict=True))
        intervals = [t_interval(col, config["confidence"]) for col in columns]
        curves[cond] = {"t": grid, "mean": [json_number(i.mean) for i in intervals],
                        "low": [json_number(i.low) for i in intervals], "high": [json_number(i.high) for i in intervals]}
    stats = [closed_loop_stats(c, summaries[c], baselines, checkpoints, config["confidence"], intents.get(c, "none"))
             for c in config["conditions"]]
    baseline_row = closed_loop_stats("baseline", baselines, baselines, checkpoints, config["confidence"])
    return {
        "baseline": baseline_row.to_json(),
        "stats": [s.to_json() for s in stats],
        "episodes": {"baseline": {str(s): e.to_json() for s, e in baselines.items()},
                     **{c: {str(s): e.to_json() for s, e in by_seed.items()} for c, by_seed in summaries.items()}},
        "curves": curves,
    }


def _path(episode: Any) -> tuple[list[float], list[tuple[float, float]]]:
    return [s.time for s in episode.steps], [(s.ego.x, s.ego.y) for s in episode.steps]


def _curve_grid(checkpoints: Sequence[float], baselines: Sequence[Any]) -> list[float]:
    durations = [ep.steps[-1].time - ep.steps[0].time for ep in baselines if ep.steps]
    end = max([max(checkpoints)] + ([float(np.median(durations))] if durations else []))
    count = int(math.floor(end / CURVE_STEP_S + 1e-9))
    return [round(i * CURVE_STEP_S, 6) for i in range(count + 1)]


def _same_drive(a: Any, b: Any) -> bool:
    """Whether two episodes drove identically (ego states and controls at every step)."""
    if len(a.steps) != len(b.steps):
        return False
    return all(x.ego == y.ego and x.control == y.control for x, y in zip(a.steps, b.steps, strict=True))


# -- tables -----------------------------------------------------------------------------------------------
def closed_loop_table(results: Mapping[str, Any], route: str) -> Table:
    """The paper's closed-loop tables merged: distance difference at the checkpoints (95 % CI across seeds),
    brakes under the baseline (shadow) vs the injected trajectory, steps, speed, route completion."""
    block = results["closed_loop"][route]
    checkpoints = results["checkpoints"]
    columns = tuple(f"@{c:g} s" for c in checkpoints) + ("Orig. brakes", "Alt. brakes", "Steps", "Speed (m/s)",
                                                          "Route compl. (%)", "Collisions")
    rows = []
    for label, stats in [("baseline", block["baseline"])] + [(s["condition"], s) for s in block["stats"]]:
        k = int(stats["n_seeds"])
        cells = [Cell(interval_text(iv), int(iv["n"]), cell_value(iv["mean"]), cell_value(iv["low"]), cell_value(iv["high"]))
                 for iv in stats["distance_diff"]]
        completion = from_json_number(stats["route_completion"])
        cells += [
            Cell(f"{stats['shadow_brakes']:.1f}", k, float(stats["shadow_brakes"])),
            Cell(f"{stats['brakes']:.1f}", k, float(stats["brakes"])),
            Cell(f"{stats['steps']:.0f}", k, float(stats["steps"])),
            Cell(number_text(stats["mean_speed"]), k, cell_value(stats["mean_speed"])),
            Cell("—" if math.isnan(completion) else f"{completion * 100:.0f}", k, cell_value(completion)),
            Cell(f"{stats['collisions']}/{k}", k, float(stats["collisions"])),
        ]
        rows.append(Row((label,), tuple(cells)))
    notes = (
        f"Model {model_text(results)}; n = {len(results['seeds'])} matched seeds. @t: cumulative distance driven "
        f"by t (condition − baseline of the same seed, metres), mean [95 % t-interval across seeds]; "
        "* = the interval excludes 0. After an episode ends its distance stays at its final value.",
        "Orig. brakes: steps where the controller would have braked on the model's own (un-injected) "
        "trajectory; Alt. brakes: steps where it braked on the injected one (per episode, mean over seeds). "
        "Steps: episode length; Speed: mean ego speed; Route compl.: mean route completion.",
    )
    return Table(f"intervention.closed_loop.{route}",
                 f"Closed-loop: distance difference (injection − baseline), route {route}",
                 ("Condition",), columns, tuple(rows), notes=notes, metric="intervention")



def closed_loop_plot(results: Mapping[str, Any]) -> Plot:
    """Closed-loop distance difference (condition − baseline) over time, 95 % CI bands across seeds."""
    panels = []
    for route, block in results["closed_loop"].items():
        series = []
        for cond, curve in block["curves"].items():
            series.append(Series(cond, tuple(float(t) for t in curve["t"]),
                                 tuple(_optional(v) for v in curve["mean"]), tuple(_optional(v) for v in curve["low"]),
                                 tuple(_optional(v) for v in curve["high"]),
                                 tuple(len(results["seeds"]) for _ in curve["t"])))
        panels.append((f"route {route}", tuple(series)))
    return Plot("intervention.closed_loop_curve",
                "Closed-loop distance difference over time", tuple(panels),
                xlabel="time (s)", ylabel="distance diff vs baseline (m)",
                notes=("band: 95 % t-interval across seeds",), metric="intervention")




def _optional(value: Any) -> float | None:
    return cell_value(value) if value is not None else None
