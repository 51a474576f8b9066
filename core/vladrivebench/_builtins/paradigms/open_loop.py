"""The open-loop paradigm (paper Section 3.6, Tables 5-7): one episode per seed driven by the model's own CoT.

At every step each condition is spliced and decoded on the same observation (:class:`OpenLoopPolicy`), and
the predicted forward displacement at each horizon is logged in the episode's ``/extras``. Everything that
does not depend on the CoT (simulation, rendering, the model's vision prefix when it caches it per
observation) is done once per step: every condition receives the identical observation. Results: per route
and horizon, each condition's per-step differences against selfsplice (selfsplice: against the baseline),
grouped by seed, with seed-level t-tests and Holm's correction.

Built only from the public API, the way a third-party paradigm would be.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from vladrivebench.intervention import (
    SELFSPLICE,
    GateTally,
    LaneStep,
    LoggedEpisodes,
    OpenLoopPolicy,
    PlannedEpisode,
    RunContext,
    cell_value,
    from_json_number,
    horizon_key,
    model_text,
    number_text,
    open_loop_stats,
    open_loop_step_batch,
    p_text,
    signed,
    t_interval,
    with_holm,
)
from vladrivebench.metrics import Cell, Plot, Row, Series, Table

DEFAULT_CONDITIONS = ("selfsplice", "accel", "pedestrian", "car")


class OpenLoopParadigm:
    """``--mode open-loop``: conditions spliced beside the model's own CoT at every step of one episode."""

    name = "open-loop"
    default_conditions = DEFAULT_CONDITIONS

    def check(self, config: Any) -> None:
        """Any route and any conditions will do."""

    def plan(self, config: Any) -> list[PlannedEpisode]:
        """One ``openloop`` episode per route and seed."""
        return [PlannedEpisode(route, seed, "openloop") for route in config.routes for seed in config.seeds]

    def policy(self, episode: PlannedEpisode, context: RunContext) -> OpenLoopPolicy:
        """The own CoT drives; every tested condition is spliced and decoded at each step."""
        c = context.config
        return OpenLoopPolicy(context.splicer, c.tested, c.horizons, c.batch_conditions)

    def step_batch(self, model: Any, lanes: Sequence[LaneStep], context: RunContext) -> list[Any]:
        """``--batch``: the seeds' episodes in lockstep, each condition spliced for every lane in one call."""
        return open_loop_step_batch(model, lanes, context)

    def lockstep_group(self, episode: PlannedEpisode) -> Any:
        """The episodes are independent of each other."""
        return None

    def analyse(self, config: Mapping[str, Any], episodes: LoggedEpisodes, gate: GateTally) -> dict[str, Any]:
        """``{"open_loop": {route: {"stats": {horizon: [row, …]}, "steps": …}}}``."""
        return {"open_loop": {route: open_loop_route(route, config, episodes, gate) for route in config["routes"]}}

    def tables(self, results: Mapping[str, Any]) -> list[Any]:
        """One table per route and horizon, and the dose-response plot when repeat counts vary."""
        items: list[Any] = [open_loop_table(results, route, horizon)
                            for route, block in results["open_loop"].items() for horizon in block["stats"]]
        dose = dose_response_plot(results)
        plots = [displacement_plot(results), step_distribution_plot(results)]
        return items + plots + ([dose] if dose is not None else [])

    def pilot_effects(self, results: Mapping[str, Any], route: str) -> list[tuple[str, list[float], str]]:
        """The per-seed mean differences at the first horizon."""
        h = horizon_key(results["horizons"][0])
        rows = results["open_loop"][route]["stats"][h]
        return [(r["condition"], [float(v) for v in r["seed_means"]], f"open-loop displacement @{h}s") for r in rows]


def open_loop_route(route: str, config: Mapping[str, Any], episodes: LoggedEpisodes,
                    gate: GateTally) -> dict[str, Any]:
    """One route's open-loop results: per horizon and condition, the per-step differences by seed."""
    horizons = [horizon_key(h) for h in config["horizons"]]
    diffs: dict[str, dict[str, dict[int, list[float]]]] = {h: {c: {} for c in config["conditions"]}
                                                           for h in horizons}
    for seed in config["seeds"]:
        episode = episodes.require(route, seed, "openloop")
        gate.add_episode(episode, route, seed, "openloop")
        for step in episode.steps:
            info = step.extras.get("intervention") or {}
            for h in horizons:
                disp = info["displacement"][h]
                for cond in config["conditions"]:
                    reference = disp["baseline"] if cond == SELFSPLICE else disp[SELFSPLICE]
                    diffs[h][cond].setdefault(seed, []).append(disp[cond] - reference)
    intents = {name: d.get("intent", "none") for name, d in config["definitions"].items()}
    table = {}
    for h, horizon in zip(horizons, config["horizons"], strict=True):
        rows = [open_loop_stats(c, horizon, diffs[h][c], config["threshold"], intents.get(c, "none"))
                for c in config["conditions"]]
        table[h] = [r.to_json() for r in with_holm(rows, config["alpha"])]
    return {"stats": table, "steps": {h: {c: {str(s): v for s, v in by_seed.items()}
                                          for c, by_seed in diffs[h].items()} for h in horizons}}


# -- tables -----------------------------------------------------------------------------------------------
OPEN_LOOP_COLUMNS = ("n", "Mean diff (m)", "% shorter", "% longer", "Cohen's d (steps)", "d (seeds)",
                     "p (seed)", "p (Holm)")


def open_loop_table(results: Mapping[str, Any], route: str, horizon: str) -> Table:
    """The paper's open-loop table: one row per condition at one horizon."""
    rows = []
    stats = results["open_loop"][route]["stats"][horizon]
    seeds = max((r["n_seeds"] for r in stats), default=0)
    steps = max((r["n"] for r in stats), default=0)
    for r in stats:
        n, k = int(r["n"]), int(r["n_seeds"])
        holm = "(control)" if r["condition"] == SELFSPLICE else p_text(r["p_holm"]) + ("*" if r["significant"] else "")
        rows.append(Row((r["condition"],), (
            Cell(str(n), n, float(n)),
            Cell(signed(r["mean_diff"]), n, cell_value(r["mean_diff"])),
            Cell(number_text(r["pct_shorter"], 1), n, cell_value(r["pct_shorter"])),
            Cell(number_text(r["pct_longer"], 1), n, cell_value(r["pct_longer"])),
            Cell(signed(r["d_steps"]), n, cell_value(r["d_steps"])),
            Cell(signed(r["d_seeds"], 2), k, cell_value(r["d_seeds"])),
            Cell(p_text(r["p"]), k, cell_value(r["p"])),
            Cell(holm, k, cell_value(r["p_holm"])),
        )))
    threshold = float(results.get("threshold", 0.1))
    notes = (
        f"Model {model_text(results)}; {seeds} seeds, {steps} steps. Mean diff: predicted forward displacement at "
        f"{horizon} s under the condition minus under selfsplice, with the same pinned RNG, averaged over "
        f"steps (selfsplice row: selfsplice minus the baseline, 0 when the gate holds).",
        f"% shorter / % longer: steps whose difference is below −{threshold:g} m / above +{threshold:g} m.",
        "Cohen's d (steps): mean / sd of the per-step differences (as the paper's Alpamayo tables). "
        "d (seeds): mean / sd of the per-seed mean differences.",
        "p (seed): two-sided one-sample t-test of the per-seed mean differences against 0 (n = seeds). "
        f"p (Holm): Holm-adjusted across the {len(stats) - 1} tested conditions; * = significant at "
        f"α = {results.get('alpha', 0.05):g}. Counts: steps for n, mean, %, d (steps); seeds for d (seeds), p.",
    )
    if any(r["condition"] != SELFSPLICE and from_json_number(r["p"]) != from_json_number(r["p"]) for r in stats):
        notes += ("— in d (seeds) / p: every seed gave the same per-seed mean (the seed changed nothing for this "
                  "model on this route), so the seeds are not independent replications and no seed-level test "
                  "exists; vary something with the seed (e.g. --sim-opt position_jitter, more routes).",)
    return Table(f"intervention.open_loop.{route}.{horizon}s",
                 f"Open-loop: predicted forward displacement at {horizon} s, route {route}",
                 ("Condition",), OPEN_LOOP_COLUMNS, tuple(rows), notes=notes, metric="intervention")



def repeat_counts(results: Mapping[str, Any]) -> dict[str, int]:
    """Conditions that repeat a token a fixed number of times, with their counts."""
    return {name: int(d["count"]) for name, d in (results.get("definitions") or {}).items()
            if d.get("kind") == "repeat" and d.get("count") and name in results.get("conditions", [])}


def dose_response_plot(results: Mapping[str, Any]) -> Plot | None:
    """Displacement difference against repeat count (e.g. depicts-3 … depicts-150), one series per horizon,
    with the 95 % t-interval of the per-seed means as a band; ``None`` with fewer than two counts."""
    counts = repeat_counts(results)
    if len(set(counts.values())) < 2 or not results.get("open_loop"):
        return None
    panels = []
    for route, block in results["open_loop"].items():
        series = []
        for horizon, rows in block["stats"].items():
            by_name = {r["condition"]: r for r in rows}
            points = sorted((counts[n], by_name[n]) for n in counts if n in by_name)
            intervals = [t_interval([from_json_number(v) for v in r["seed_means"]]) for _, r in points]
            series.append(Series(
                f"@{horizon} s", tuple(float(c) for c, _ in points),
                tuple(cell_value(r["mean_diff"]) for _, r in points),
                tuple(cell_value(i.low) for i in intervals), tuple(cell_value(i.high) for i in intervals),
                tuple(int(r["n"]) for _, r in points)))
        panels.append((f"route {route}", tuple(series)))
    return Plot("intervention.dose_response",
                "Displacement difference against repeat count", tuple(panels),
                xlabel="repeat count N", ylabel="mean displacement diff (m)",
                notes=("band: 95 % t-interval of the per-seed mean differences",), metric="intervention")




def displacement_plot(results: Mapping[str, Any]) -> Plot:
    """The mean displacement difference of every condition against the horizon, with the 95 % t-interval of
    the per-seed mean differences as a band and the steps behind every point."""
    panels = []
    for route, block in results["open_loop"].items():
        horizons = list(block["stats"])
        series = []
        for condition in results["conditions"]:
            rows = [next(r for r in block["stats"][h] if r["condition"] == condition) for h in horizons]
            intervals = [t_interval([from_json_number(v) for v in r["seed_means"]]) for r in rows]
            series.append(Series(condition, tuple(float(r["horizon_s"]) for r in rows),
                                 tuple(cell_value(r["mean_diff"]) for r in rows),
                                 tuple(cell_value(i.low) for i in intervals),
                                 tuple(cell_value(i.high) for i in intervals), tuple(int(r["n"]) for r in rows)))
        panels.append((f"route {route}", tuple(series)))
    return Plot("intervention.open_loop_displacement", "Open-loop: displacement difference per condition",
                tuple(panels), xlabel="horizon (s)", ylabel="mean displacement diff (m)",
                notes=("selfsplice: minus the baseline (0 when the gate holds); other conditions: minus selfsplice. "
                       "Band: 95 % t-interval of the per-seed mean differences; counts: steps.",),
                metric="intervention")


def step_distribution_plot(results: Mapping[str, Any]) -> Plot:
    """The per-step distribution of the displacement difference at the first horizon: one empirical CDF per
    condition over every step of every seed."""
    panels = []
    for route, block in results["open_loop"].items():
        horizon = next(iter(block["steps"]))
        series = []
        for condition in results["conditions"]:
            values = sorted(float(v) for by_seed in [block["steps"][horizon][condition]]
                            for steps in by_seed.values() for v in steps)
            n = len(values)
            series.append(Series(condition, tuple(values), tuple((i + 1) / n for i in range(n)),
                                 counts=tuple(n for _ in values)))
        panels.append((f"route {route}, @{horizon} s", tuple(series)))
    return Plot("intervention.open_loop_steps", "Open-loop: per-step displacement difference",
                tuple(panels), xlabel="displacement diff (m)", ylabel="fraction of steps ≤ x",
                notes=("Empirical CDF over every step of every seed; a condition that changes nothing is a step "
                       "at 0.",), metric="intervention")
