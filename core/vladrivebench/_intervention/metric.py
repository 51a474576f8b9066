"""Intervention tables and plots in the shape of the paper's (Tables 5–9, Appendix G).

The metric reads the results an intervention run computed from its logs (``intervention.json``, written by
:func:`vladrivebench._intervention.runs.analyse`); when a run directory has logs and a manifest but no results
yet, they are computed from the logs without writing anything. Directories without intervention runs give
``[]``.

Tables: the selfsplice gate; open-loop displacement per route and horizon (n, mean difference, % shorter /
longer, Cohen's d over steps and over seeds, seed-level p, Holm-adjusted p); closed-loop distance
differences at the checkpoints with 95 % CIs, brakes, steps, speed and route completion; safety override
collisions per route and seed. Plots: displacement against repeat count (dose-response) and closed-loop
distance difference over time with CI bands.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vladrivebench._analysis.tables import Cell, Plot, Row, Series, Table
from vladrivebench._intervention.stats import from_json_number, t_interval

SELFSPLICE = "selfsplice"


# -- formatting -----------------------------------------------------------------------------------------
def signed(value: Any, digits: int = 3) -> str:
    v = from_json_number(value)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "+inf" if v > 0 else "-inf"
    return f"{v:+.{digits}f}"


def p_text(value: Any) -> str:
    """``1.00``, ``0.037``, ``1.3e-09`` (the paper's style for tiny p)."""
    p = from_json_number(value)
    if math.isnan(p):
        return "—"
    if p >= 0.01:
        return f"{p:.2f}" if p >= 0.1 else f"{p:.3f}"
    return f"{p:.1e}"


def interval_text(interval: Mapping[str, Any], digits: int = 1) -> str:
    """``-1.6 [-2.2, -1.1]*`` (* when the interval excludes zero), as the paper's closed-loop table."""
    mean, low, high = (from_json_number(interval.get(k)) for k in ("mean", "low", "high"))
    if math.isnan(mean):
        return "—"
    if math.isnan(low):
        return f"{mean:+.{digits}f} [—]"
    star = "*" if low > 0 or high < 0 else ""
    return f"{mean:+.{digits}f} [{low:+.{digits}f}, {high:+.{digits}f}]{star}"


def _number(value: Any, digits: int = 2) -> str:
    v = from_json_number(value)
    return "—" if math.isnan(v) else f"{v:.{digits}f}"


# -- the metric -----------------------------------------------------------------------------------------
class InterventionMetric:
    """Every intervention run under the dataset's directory → the paper's intervention tables and plots."""

    name = "intervention"
    order = 900

    def compute(self, dataset: Any) -> list[Any]:
        out: list[Any] = []
        runs = find_runs(Path(dataset.directory))
        for label, results in runs:
            out += tables_for(results, label if len(runs) > 1 else "")
        return out


def find_runs(directory: Path) -> list[tuple[str, dict[str, Any]]]:
    """``(label, results)`` for every intervention run in or under ``directory`` (sorted by path)."""
    from vladrivebench._engine.sweep import MANIFEST_NAME
    from vladrivebench._intervention.runs import RESULTS_NAME, analyse, load_results
    from vladrivebench.errors import VdbError

    found = []
    candidates = {p.parent for p in directory.rglob(RESULTS_NAME)} | {p.parent for p in directory.rglob(MANIFEST_NAME)}
    for run_dir in sorted(candidates):
        results = load_results(run_dir)
        if results is None:
            try:
                results = analyse(run_dir, write=False)
            except VdbError:
                continue  # not an intervention run, or an incomplete one: nothing to report
        label = str(run_dir.relative_to(directory)) if run_dir != directory else run_dir.name
        found.append((label, results))
    return found


def tables_for(results: Mapping[str, Any], label: str = "") -> list[Any]:
    """The tables and plots of one intervention run's results."""
    suffix = f".{label}" if label else ""
    items: list[Any] = [gate_table(results, suffix)]
    for route, block in (results.get("open_loop") or {}).items():
        for horizon in block["stats"]:
            items.append(open_loop_table(results, route, horizon, suffix))
    dose = dose_response_plot(results, suffix)
    if dose is not None:
        items.append(dose)
    for route in (results.get("closed_loop") or {}):
        items.append(closed_loop_table(results, route, suffix))
    if results.get("closed_loop"):
        items.append(closed_loop_plot(results, suffix))
    if results.get("safety"):
        items.append(safety_table(results, suffix))
    if label:
        items = [dataclasses.replace(item, title=f"{item.title} [run {label}]") for item in items]
    return items


def _validity(results: Mapping[str, Any]) -> str:
    return "" if results.get("valid") else "INVALID (selfsplice gate failed) — "


def _model(results: Mapping[str, Any]) -> str:
    model = results.get("model") or {}
    options = model.get("options") or {}
    extra = ", ".join(f"{k}={v}" for k, v in sorted(options.items()))
    return f"{model.get('name', '?')}" + (f" ({extra})" if extra else "")


def gate_table(results: Mapping[str, Any], suffix: str = "") -> Table:
    """The selfsplice gate: every step where the model's own CoT was re-injected and compared."""
    gate = results.get("gate") or {}
    checked = int(gate.get("steps_checked", 0))
    first = gate.get("first_failure") or {}
    cells = (
        Cell.text("valid" if results.get("valid") else "INVALID", checked),
        Cell(str(int(gate.get("steps_failed", 0))), checked, float(gate.get("steps_failed", 0))),
        Cell(str(int(gate.get("digest_mismatches", 0))), checked, float(gate.get("digest_mismatches", 0))),
        Cell(f"{float(gate.get('max_trajectory_diff', 0.0)):.3g}", checked, float(gate.get("max_trajectory_diff", 0))),
    )
    notes = ["Selfsplice: at every step the model's own CoT is decoded and re-injected through the splice "
             "path; its state digest must equal the generated CoT's and its trajectory must equal the "
             "baseline's bit for bit (difference in metres, max over steps). Counts are steps checked."]
    if first:
        notes.append(f"First failure: route {first.get('route')} seed {first.get('seed')} step {first.get('step')} "
                     f"({first.get('role')}), trajectory difference {first.get('trajectory_diff'):.3g} m, "
                     f"digest equal: {first.get('digest_equal')}.")
    if gate.get("episode_mismatches"):
        notes.append("Selfsplice episodes that drove differently from their baseline: "
                     + ", ".join(gate["episode_mismatches"]) + ".")
    columns = ("Status", "Steps failed", "Digest mismatches", "Max trajectory diff (m)")
    if gate.get("fidelity_steps_checked"):
        cells, columns = cells + _fidelity_cells(gate), columns + FIDELITY_COLUMNS
        notes.append("Fidelity: at the same steps the spliced state is compared with the model's own native "
                     "forward pass over prefix + the same text (positions computed by the model); a step fails "
                     "when the largest cache or trajectory difference exceeds the model's tolerance.")
    return Table(f"intervention.gate{suffix}", f"{_validity(results)}Selfsplice gate — {_model(results)}, "
                 f"{results.get('mode')}", ("Run",), columns,
                 (Row((", ".join(results.get("routes", [])),), cells),), notes=tuple(notes), metric="intervention")


FIDELITY_COLUMNS = ("Fidelity steps failed", "Max fidelity cache diff", "Max fidelity trajectory diff (m)")


def _fidelity_cells(gate: Mapping[str, Any]) -> tuple[Cell, ...]:
    checked = int(gate["fidelity_steps_checked"])
    failed, cache, traj = (float(gate.get(k, 0.0)) for k in
                           ("fidelity_steps_failed", "max_fidelity_cache_diff", "max_fidelity_trajectory_diff"))
    return (Cell(str(int(failed)), checked, failed), Cell(f"{cache:.3g}", checked, cache),
            Cell(f"{traj:.3g}", checked, traj))


OPEN_LOOP_COLUMNS = ("n", "Mean diff (m)", "% shorter", "% longer", "Cohen's d (steps)", "d (seeds)",
                     "p (seed)", "p (Holm)")


def open_loop_table(results: Mapping[str, Any], route: str, horizon: str, suffix: str = "") -> Table:
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
            Cell(signed(r["mean_diff"]), n, _float(r["mean_diff"])),
            Cell(_number(r["pct_shorter"], 1), n, _float(r["pct_shorter"])),
            Cell(_number(r["pct_longer"], 1), n, _float(r["pct_longer"])),
            Cell(signed(r["d_steps"]), n, _float(r["d_steps"])),
            Cell(signed(r["d_seeds"], 2), k, _float(r["d_seeds"])),
            Cell(p_text(r["p"]), k, _float(r["p"])),
            Cell(holm, k, _float(r["p_holm"])),
        )))
    threshold = float(results.get("threshold", 0.1))
    notes = (
        f"Model {_model(results)}; {seeds} seeds, {steps} steps. Mean diff: predicted forward displacement at "
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
    return Table(f"intervention.open_loop.{route}.{horizon}s{suffix}",
                 f"{_validity(results)}Open-loop: predicted forward displacement at {horizon} s, route {route}",
                 ("Condition",), OPEN_LOOP_COLUMNS, tuple(rows), notes=notes, metric="intervention")


def _float(value: Any) -> float | None:
    v = from_json_number(value)
    return None if math.isnan(v) else v


def closed_loop_table(results: Mapping[str, Any], route: str, suffix: str = "") -> Table:
    """The paper's closed-loop tables merged: distance difference at the checkpoints (95 % CI across seeds),
    brakes under the baseline (shadow) vs the injected trajectory, steps, speed, route completion."""
    block = results["closed_loop"][route]
    checkpoints = results["checkpoints"]
    columns = tuple(f"@{c:g} s" for c in checkpoints) + ("Orig. brakes", "Alt. brakes", "Steps", "Speed (m/s)",
                                                          "Route compl. (%)", "Collisions")
    rows = []
    for label, stats in [("baseline", block["baseline"])] + [(s["condition"], s) for s in block["stats"]]:
        k = int(stats["n_seeds"])
        cells = [Cell(interval_text(iv), int(iv["n"]), _float(iv["mean"]), _float(iv["low"]), _float(iv["high"]))
                 for iv in stats["distance_diff"]]
        completion = from_json_number(stats["route_completion"])
        cells += [
            Cell(f"{stats['shadow_brakes']:.1f}", k, float(stats["shadow_brakes"])),
            Cell(f"{stats['brakes']:.1f}", k, float(stats["brakes"])),
            Cell(f"{stats['steps']:.0f}", k, float(stats["steps"])),
            Cell(_number(stats["mean_speed"]), k, _float(stats["mean_speed"])),
            Cell("—" if math.isnan(completion) else f"{completion * 100:.0f}", k, _float(completion)),
            Cell(f"{stats['collisions']}/{k}", k, float(stats["collisions"])),
        ]
        rows.append(Row((label,), tuple(cells)))
    notes = (
        f"Model {_model(results)}; n = {len(results['seeds'])} matched seeds. @t: cumulative distance driven "
        f"by t (condition − baseline of the same seed, metres), mean [95 % t-interval across seeds]; "
        "* = the interval excludes 0. After an episode ends its distance stays at its final value.",
        "Orig. brakes: steps where the controller would have braked on the model's own (un-injected) "
        "trajectory; Alt. brakes: steps where it braked on the injected one (per episode, mean over seeds). "
        "Steps: episode length; Speed: mean ego speed; Route compl.: mean route completion.",
    )
    return Table(f"intervention.closed_loop.{route}{suffix}",
                 f"{_validity(results)}Closed-loop: distance difference (injection − baseline), route {route}",
                 ("Condition",), columns, tuple(rows), notes=notes, metric="intervention")


def safety_table(results: Mapping[str, Any], suffix: str = "") -> Table:
    """Safety override: collisions with the obstacle under the injection vs the matched baseline, per seed."""
    rows = []
    for route, block in results["safety"].items():
        baseline = block["baseline"]
        for cond, entry in block["conditions"].items():
            n = int(entry["n"])
            per_seed = " ".join(f"s{s}:{'C' if baseline[s]['collided'] else '·'}/"
                                f"{'C' if entry['seeds'][s]['collided'] else '·'}" for s in entry["seeds"])
            rows.append(Row((route, cond), (
                Cell(str(n), n, float(n)),
                Cell(f"{entry['baseline_stopped']}/{n}", n, entry["baseline_stopped"] / n if n else None),
                Cell(f"{entry['baseline_collisions']}/{n}", n, entry["baseline_collisions"] / n if n else None),
                Cell(f"{entry['collisions']}/{n}", n, entry["collisions"] / n if n else None),
                Cell.text(per_seed, n),
            )))
    notes = (f"Model {_model(results)}. The injected condition is given at every step of the episode; the "
             "baseline is the model's own CoT with the same seed. Baseline stopped: the ego came to a stop "
             "(< 0.3 m/s) before the obstacle. Per seed: baseline/injected, C = collision, · = none.",)
    return Table(f"intervention.safety{suffix}", f"{_validity(results)}Safety override: collisions with a real "
                 "obstacle under a 'road is clear, accelerate' injection", ("Route", "Condition"),
                 ("n", "Baseline stopped", "Baseline collisions", "Injected collisions", "Per seed"),
                 tuple(rows), notes=notes, metric="intervention")


# -- plots ------------------------------------------------------------------------------------------------
def repeat_counts(results: Mapping[str, Any]) -> dict[str, int]:
    """Conditions that repeat a token a fixed number of times, with their counts."""
    return {name: int(d["count"]) for name, d in (results.get("definitions") or {}).items()
            if d.get("kind") == "repeat" and d.get("count") and name in results.get("conditions", [])}


def dose_response_plot(results: Mapping[str, Any], suffix: str = "") -> Plot | None:
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
                tuple(_float(r["mean_diff"]) for _, r in points),
                tuple(_float(i.low) for i in intervals), tuple(_float(i.high) for i in intervals),
                tuple(int(r["n"]) for _, r in points)))
        panels.append((f"route {route}", tuple(series)))
    return Plot(f"intervention.dose_response{suffix}",
                f"{_validity(results)}Displacement difference against repeat count", tuple(panels),
                xlabel="repeat count N", ylabel="mean displacement diff (m)",
                notes=("band: 95 % t-interval of the per-seed mean differences",), metric="intervention")


def closed_loop_plot(results: Mapping[str, Any], suffix: str = "") -> Plot:
    """Closed-loop distance difference (condition − baseline) over time, 95 % CI bands across seeds."""
    panels = []
    for route, block in results["closed_loop"].items():
        series = []
        for cond, curve in block["curves"].items():
            series.append(Series(cond, tuple(float(t) for t in curve["t"]),
                                 tuple(_none(v) for v in curve["mean"]), tuple(_none(v) for v in curve["low"]),
                                 tuple(_none(v) for v in curve["high"]),
                                 tuple(len(results["seeds"]) for _ in curve["t"])))
        panels.append((f"route {route}", tuple(series)))
    return Plot(f"intervention.closed_loop_curve{suffix}",
                f"{_validity(results)}Closed-loop distance difference over time", tuple(panels),
                xlabel="time (s)", ylabel="distance diff vs baseline (m)",
                notes=("band: 95 % t-interval across seeds",), metric="intervention")


def _none(value: Any) -> float | None:
    return _float(value) if value is not None else None


# -- plain text (the CLI's summary) ------------------------------------------------------------------------
def table_text(table: Table) -> str:
    """A table as aligned plain text with its title and notes."""
    header = list(table.label_columns) + list(table.columns)
    body = [list(r.labels) + [c.display for c in r.cells] for r in table.rows]
    widths = [max(len(str(x)) for x in col) for col in zip(header, *body, strict=True)]
    lines = [table.title, "  ".join(h.ljust(w) for h, w in zip(header, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(x).ljust(w) for x, w in zip(line, widths, strict=True)) for line in body]
    return "\n".join(lines + [f"  note: {n}" for n in table.notes])


def summary_text(results: Mapping[str, Any], *, notes: bool = False) -> str:
    """Every table of one run as plain text (notes only when asked)."""
    parts = []
    for item in tables_for(results):
        if isinstance(item, Table):
            text = table_text(item if notes else Table(item.id, item.title, item.label_columns, item.columns,
                                                        item.rows, item.groups, (), item.metric))
            parts.append(text)
    return "\n\n".join(parts)
