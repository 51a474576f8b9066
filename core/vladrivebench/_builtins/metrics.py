"""The built-in observational metrics: metric plugins on the public metric API (vladrivebench.metrics)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

from vladrivebench.metrics import (
    MIN_COUNT,
    MISSING,
    SHORT_NAMES,
    AnalysisDataset,
    Cell,
    Plot,
    Row,
    Series,
    Table,
    bin_fractions,
    breakdown_text,
    format_percent,
    model_of,
    observational,
    relaxed_aligned,
    scenario_group,
    step_views,
    strict_aligned,
)

# -- built-in observational metrics ---------------------------------------------------------------------
# Each reads the models' own runs (not intervention episodes) and, for labelled properties, only the
# steps that have labels; the dataset's notes say what was left out. ``order`` places a metric in
# reports (the paper's order); metrics without one come after, in registry order.

ZONE_COLUMNS = ("far", "med", "near")
TL_ZONE_COLUMNS = ("far", "med", "near", "past")
SPEED_BAND = (2.0, 4.0)
"""The speed band (m/s) of the alignment-by-command table."""
DISTANCE_BIN_M = 5.0
"""Width of the distance bins of the plots against distance to the target."""


PAPER_ROWS = ("Pedestrian (in-lane)", "Pedestrian (crossing)", "Stopped car (blocking)", "Stopped car (non-blocking)",
              "Traffic light (red)", "Traffic light (green)", "Stop sign", "Baseline")
"""The paper's row order; other scenario groups follow in alphabetical order."""


def ordered_groups(groups: Iterable[str]) -> list[str]:
    """Scenario groups in the paper's row order, unknown ones after, alphabetically."""
    unique = set(groups)
    return [g for g in PAPER_ROWS if g in unique] + sorted(unique - set(PAPER_ROWS))


class _ZoneRate:
    """A rate per (scenario group, model, zone) over labelled steps; subclasses say which steps and what."""

    name = ""
    title = ""
    order = 100
    zones: tuple[str, ...] = ZONE_COLUMNS
    count_note = "counts are labelled steps in the cell"
    plot_ylabel = ""

    def include(self, view: Any) -> bool:
        """Whether a labelled step enters the denominator."""
        raise NotImplementedError

    def success(self, view: Any) -> bool:
        raise NotImplementedError

    def compute(self, dataset: AnalysisDataset) -> list[Any]:

        cells: dict[tuple[str, str, str], list[int]] = {}
        by_distance: dict[tuple[str, str], dict[float, list[int]]] = {}
        models: list[str] = []
        groups: list[str] = []
        for episode in observational(dataset):
            model, group = model_of(dataset, episode), scenario_group(episode)
            for view in step_views(dataset, episode):
                if view.labels is None or view.zone is None or not self.include(view):
                    continue
                ok = int(self.success(view))
                if view.zone in self.zones:
                    tally = cells.setdefault((group, model, view.zone), [0, 0])
                    tally[0] += ok
                    tally[1] += 1
                    models.append(model)
                    groups.append(group)
                bin_centre = (math.floor(view.distance / DISTANCE_BIN_M) + 0.5) * DISTANCE_BIN_M
                point = by_distance.setdefault((group, model), {}).setdefault(bin_centre, [0, 0])
                point[0] += ok
                point[1] += 1
        if not cells:
            return []
        models, groups = list(dict.fromkeys(models)), ordered_groups(groups)
        rows = tuple(
            Row((group,), tuple(Cell.rate(*cells.get((group, m, z), (0, 0)), interval=True)
                                for m in models for z in self.zones))
            for group in groups
        )
        notes = (f"% of steps; {self.count_note}; cells with fewer than {MIN_COUNT} observations show "
                 f"{MISSING}; 95 % Wilson intervals in the JSON output.",) + self.extra_notes(dataset)
        table = Table(self.name, self.title, ("Scenario",), self.zones * len(models), rows,
                      groups=tuple((m, len(self.zones)) for m in models), notes=notes, metric=self.name)
        return [table, self._plot(by_distance, groups, models)]

    def extra_notes(self, dataset: AnalysisDataset) -> tuple[str, ...]:
        return ()

    def _plot(self, by_distance: dict, groups: list[str], models: list[str]) -> Plot:
        panels = []
        for group in groups:
            series = []
            for model in models:
                points = by_distance.get((group, model), {})
                xs = tuple(sorted(points))
                ys = tuple(points[x][0] / points[x][1] * 100 if points[x][1] >= MIN_COUNT else None for x in xs)
                series.append(Series(model, xs, ys, counts=tuple(points[x][1] for x in xs)))
            panels.append((group, tuple(series)))
        return Plot(f"{self.name}_by_distance", f"{self.title} against distance to the target", tuple(panels),
                    xlabel="distance to target (m)", ylabel=self.plot_ylabel, invert_x=True, ylim=(-2, 102),
                    notes=(f"{DISTANCE_BIN_M:g} m bins; points with fewer than {MIN_COUNT} steps are not drawn",),
                    metric=self.name)


class MentionRate(_ZoneRate):
    """Target mention rate by scenario and distance zone (the paper's Table 1)."""

    name = "mention_rate"
    title = "Target mention rate (%) by distance zone"
    order = 10
    plot_ylabel = "mention rate (%)"

    def include(self, view: Any) -> bool:
        return view.labels.target_mentioned is not None

    def success(self, view: Any) -> bool:
        return bool(view.labels.target_mentioned)


class LightAccuracy(_ZoneRate):
    """Traffic-light colour accuracy conditional on mention, by zone (the paper's Appendix C table)."""

    name = "tl_accuracy"
    title = "Traffic light colour accuracy (%) conditional on mention"
    order = 20
    zones = TL_ZONE_COLUMNS
    count_note = "counts are labelled steps that mention the light and state a colour"
    plot_ylabel = "colour accuracy (%)"

    def include(self, view: Any) -> bool:
        return (view.critical_kind == "traffic_light" and bool(view.labels.target_mentioned)
                and view.labels.light_colour is not None and view.light_state is not None)

    def success(self, view: Any) -> bool:
        return view.labels.light_colour == view.light_state

    def extra_notes(self, dataset: AnalysisDataset) -> tuple[str, ...]:

        silent = sum(1 for e in observational(dataset) for v in step_views(dataset, e)
                     if v.labels is not None and v.critical_kind == "traffic_light" and v.labels.target_mentioned
                     and v.labels.light_colour is None)
        return (f"{silent} steps mention the light without stating a colour and are not in the table",) if silent else ()


class HallucinationRate(_ZoneRate):
    """Hallucination rate by scenario and distance zone (the paper's Appendix D table)."""

    name = "hallucination"
    title = "Hallucination rate (%) by distance zone"
    order = 30
    plot_ylabel = "hallucination rate (%)"

    def include(self, view: Any) -> bool:
        return True

    def success(self, view: Any) -> bool:
        return bool(view.labels.hallucination)

    def extra_notes(self, dataset: AnalysisDataset) -> tuple[str, ...]:

        notes = []
        summary = dataset.extra.get("label_summary") or {}
        if any("phantom-filtered" in v for v in summary.get("versions", {})):
            notes.append("ORION's phantom 'Car at <0, 30>' artifact is filtered (labeler option filter_phantom_car)")
        outside: dict[tuple[str, str], list[int]] = {}
        for episode in observational(dataset):
            for view in step_views(dataset, episode):
                if view.labels is not None and view.zone is None:
                    t = outside.setdefault((scenario_group(episode), model_of(dataset, episode)), [0, 0])
                    t[0] += bool(view.labels.hallucination)
                    t[1] += 1
        for (group, model), (k, n) in outside.items():
            notes.append(f"{group} (no target), {model}: {Cell.rate(k, n).display} % of {n} steps")
        return tuple(notes)


class ContradictionRate:
    """Internal contradiction rate per model, with 95 % Wilson intervals."""

    name = "contradiction"
    title = "Internal contradiction rate per model"
    order = 40

    def compute(self, dataset: AnalysisDataset) -> list[Any]:

        tallies: dict[str, list[int]] = {}
        formats: dict[str, str] = {}
        for episode in observational(dataset):
            model = model_of(dataset, episode)
            fmt = ((episode.meta.get("model") or {}).get("cot_format") or {}).get("kind")
            formats.setdefault(model, fmt or "?")
            for view in step_views(dataset, episode):
                if view.labels is not None:
                    t = tallies.setdefault(model, [0, 0])
                    t[0] += bool(view.labels.contradiction)
                    t[1] += 1
        if not tallies:
            return []
        rows = []
        for model, (k, n) in tallies.items():
            cell = Cell.rate(k, n, interval=True)
            ci = Cell.text(MISSING if cell.missing else
                           f"{format_percent(cell.low)}–{format_percent(cell.high)}", n)
            rows.append(Row((model, formats[model]), (Cell(str(n), n, float(n)), cell, ci)))
        return [Table(self.name, self.title, ("Model", "CoT format"), ("n", "Contradiction (%)", "95 % CI"),
                      tuple(rows), notes=("n = labelled steps; Wilson score interval",), metric=self.name)]


class AlignmentByDistance:
    """Relaxed (and strict) action alignment by scenario and zone, aggregated in 1 m travel bins."""

    name = "alignment_distance"
    title = "Relaxed alignment (%) by distance to target"
    order = 50

    def compute(self, dataset: AnalysisDataset) -> list[Any]:

        fractions: dict[tuple[str, str, str, bool], list[float]] = {}
        whole: dict[tuple[str, str, bool], list[float]] = {}
        plot_points: dict[tuple[str, str], dict[float, list[float]]] = {}
        models: list[str] = []
        groups: list[str] = []
        for episode in observational(dataset):
            model, group = model_of(dataset, episode), scenario_group(episode)
            views = step_views(dataset, episode)
            for strict in (False, True):
                aligned = [v.aligned(strict) for v in views]
                if all(a is None for a in aligned):
                    continue
                models.append(model)
                groups.append(group)
                whole.setdefault((group, model, strict), []).extend(
                    bin_fractions([v.travelled for v in views], aligned).fractions)
                for zone in ZONE_COLUMNS:
                    in_zone = [a if v.zone == zone else None for v, a in zip(views, aligned, strict=True)]
                    fractions.setdefault((group, model, zone, strict), []).extend(
                        bin_fractions([v.travelled for v in views], in_zone).fractions)
                if not strict:
                    _distance_points(views, aligned, plot_points.setdefault((group, model), {}))
        if not whole:
            return []
        models, groups = list(dict.fromkeys(models)), ordered_groups(groups)
        tables = []
        for strict in (False, True):
            kind = "Strict" if strict else "Relaxed"
            rows = tuple(Row((g,), tuple(Cell.mean(fractions.get((g, m, z, strict), [])) for m in models
                                         for z in ZONE_COLUMNS)) for g in groups)
            rows = tuple(r for r in rows if any(c.count for c in r.cells))
            if rows:
                tables.append(Table(
                    f"{self.name}{'_strict' if strict else ''}", f"{kind} alignment (%) by distance to target",
                    ("Scenario",), ZONE_COLUMNS * len(models), rows, groups=tuple((m, 3) for m in models),
                    notes=(f"{kind.lower()} alignment (Appendix B) averaged over 1 m bins of travelled distance "
                           f"(bins of all runs pooled, unweighted); counts are bins; cells with fewer than "
                           f"{MIN_COUNT} bins show {MISSING}",), metric=self.name))
        run_rows = tuple(Row((g,), tuple(Cell.mean(whole.get((g, m, s), [])) for m in models for s in (False, True)))
                         for g in groups)
        tables.append(Table("alignment_runs", "Alignment (%) over whole runs", ("Scenario",),
                            ("relaxed", "strict") * len(models), run_rows, groups=tuple((m, 2) for m in models),
                            notes=("every step of the runs, with or without a target; counts are 1 m bins",),
                            metric=self.name))
        return tables + [self._plot(plot_points, groups, models)]

    def _plot(self, points: dict, groups: list[str], models: list[str]) -> Plot:
        panels = []
        for group in groups:
            series = []
            for model in models:
                by_bin = points.get((group, model), {})
                xs = tuple(sorted(by_bin))
                ys = tuple(math.fsum(by_bin[x]) / len(by_bin[x]) * 100 if len(by_bin[x]) >= MIN_COUNT else None
                           for x in xs)
                series.append(Series(model, xs, ys, counts=tuple(len(by_bin[x]) for x in xs)))
            if any(s.x for s in series):
                panels.append((group, tuple(series)))
        return Plot("alignment_by_distance", "Relaxed alignment against distance to the target", tuple(panels),
                    xlabel="distance to target (m)", ylabel="relaxed alignment (%)", invert_x=True,
                    ylim=(-2, 102), notes=(f"{DISTANCE_BIN_M:g} m distance bins of 1 m travel-bin fractions",),
                    metric=self.name)


def _distance_points(views: Sequence[Any], aligned: Sequence[bool | None], out: dict[float, list[float]]) -> None:
    """Per 1 m travel bin: its aligned fraction, placed at its mean distance to the target."""
    bins: dict[int, list[tuple[float, bool]]] = {}
    for view, ok in zip(views, aligned, strict=True):
        if ok is not None and view.distance is not None:
            bins.setdefault(math.floor(view.travelled), []).append((view.distance, ok))
    for entries in bins.values():
        distance = math.fsum(d for d, _ in entries) / len(entries)
        centre = (math.floor(distance / DISTANCE_BIN_M) + 0.5) * DISTANCE_BIN_M
        out.setdefault(centre, []).append(sum(ok for _, ok in entries) / len(entries))


class AlignmentByCommand:
    """Alignment by the CoT's command within a speed band, with the action head's breakdown."""

    name = "alignment_command"
    order = 60

    def __init__(self, band: tuple[float, float] = SPEED_BAND):
        self.band = band
        self.title = f"Relaxed alignment (%) by CoT command in the {band[0]:g}–{band[1]:g} m/s band"

    def compute(self, dataset: AnalysisDataset) -> list[Any]:

        tallies: dict[tuple[str, str], dict[str, Any]] = {}
        totals: dict[str, int] = {}
        for episode in observational(dataset):
            model = model_of(dataset, episode)
            for view in step_views(dataset, episode):
                if not self.band[0] <= view.speed <= self.band[1]:
                    continue
                cot, head = view.cot_set(), view.head_set()
                if cot is None or head is None:
                    continue
                t = tallies.setdefault((model, SHORT_NAMES[cot[0]]), {"n": 0, "relaxed": 0, "strict": 0, "head": {}})
                t["n"] += 1
                t["relaxed"] += relaxed_aligned(cot, head)
                t["strict"] += strict_aligned(cot, head)
                short = SHORT_NAMES[head[0]]
                t["head"][short] = t["head"].get(short, 0) + 1
                totals[model] = totals.get(model, 0) + 1
        if not tallies:
            return []
        order = {"accel": 0, "maint": 1, "slow": 2}
        rows = []
        for (model, command), t in sorted(tallies.items(), key=lambda kv: (list(totals).index(kv[0][0]),
                                                                            order[kv[0][1]])):
            n = t["n"]
            rows.append(Row((model, command), (
                Cell(str(n), n, float(n)),
                Cell.rate(t["relaxed"], n),
                Cell.rate(t["strict"], n),
                Cell(f"{format_percent(n / totals[model])}%", totals[model], n / totals[model]),
                Cell.text(breakdown_text(t["head"], n), n),
            )))
        return [Table(self.name, self.title, ("Model", "CoT cmd"), ("n", "Relaxed", "Strict", "Share",
                                                                   "Action head breakdown"), tuple(rows),
                      notes=("n = labelled steps in the band whose CoT states an action; the command is the CoT "
                             "set's primary action; share = fraction of the model's steps with that command "
                             "(its count is the model's total); the breakdown counts the action head's primary "
                             "action",), metric=self.name)]
