"""How every metric talks to reports: tables whose every cell carries its count, plots, and the dataset.

A metric plugin's ``compute(dataset)`` receives an :class:`AnalysisDataset` (the episode logs of one
directory, their labels when labelled, and notes on what is missing) and returns a list of
:class:`Table` and :class:`Plot` objects; a metric with nothing to say (e.g. no intervention results in
the directory) returns ``[]``. ``vdb metrics`` and ``vdb report`` render every registered metric, in
registry order, without knowing any of them.

Rendering never guesses: a cell with fewer observations than its table asks for shows "—" and still
carries the count, so a reader sees why.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from .records import Labels

MISSING = "—"
"""What a cell shows when it has too few observations (fewer than ``min_count``)."""

MIN_COUNT = 2
"""The paper's rule: a cell with fewer than 2 observations is shown as "—"."""


# -- table records -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Cell:
    """One table cell: what is shown, the number behind it and the count of observations it rests on.

    ``value`` is the raw number (a rate in [0, 1], a mean, …) or ``None`` for text cells and cells with
    too few observations; ``display`` is the text shown; ``count`` is how many observations (steps, bins,
    episodes, seeds — the table's notes say which) stand behind it; ``low``/``high`` an interval if any.
    """

    display: str
    count: int
    value: float | None = None
    low: float | None = None
    high: float | None = None

    @classmethod
    def rate(cls, successes: float, total: int, *, min_count: int = MIN_COUNT, digits: int = 1,
             interval: bool = False) -> Cell:
        """A percentage cell ``successes / total``; "—" below ``min_count``; Wilson 95 % CI if asked."""
        if total < min_count or total <= 0:
            return cls(MISSING, int(total))
        value = successes / total
        low = high = None
        if interval:
            low, high = wilson_interval(successes, total)
        return cls(format_percent(value, digits), int(total), value, low, high)

    @classmethod
    def mean(cls, values: Sequence[float], *, min_count: int = MIN_COUNT, digits: int = 1,
             scale: float = 100.0) -> Cell:
        """The mean of ``values`` (e.g. per-bin alignment fractions) shown ×``scale``; "—" when too few."""
        n = len(values)
        if n < min_count or n == 0:
            return cls(MISSING, n)
        value = math.fsum(values) / n
        shown = format_percent(value, digits) if scale == 100.0 else f"{value * scale:.{digits}f}"
        return cls(shown, n, value)

    @classmethod
    def text(cls, display: str, count: int) -> Cell:
        """A text cell (e.g. a breakdown ``slow=181, maint=23``) resting on ``count`` observations."""
        return cls(display, int(count))

    @property
    def missing(self) -> bool:
        return self.display == MISSING

    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {"display": self.display, "count": self.count, "value": self.value}
        if self.low is not None:
            data["low"], data["high"] = self.low, self.high
        return data


@dataclass(frozen=True)
class Row:
    """One table row: its label(s) (one per label column) and its cells (one per data column)."""

    labels: tuple[str, ...]
    cells: tuple[Cell, ...]

    def to_json(self) -> dict[str, Any]:
        return {"labels": list(self.labels), "cells": [c.to_json() for c in self.cells]}


@dataclass(frozen=True)
class Table:
    """A table of a metric, in the shape the paper prints it.

    ``label_columns`` head the row labels (e.g. ``("Scenario",)``); ``columns`` head the cells (e.g.
    ``("far", "med", "near")`` repeated per model); ``groups`` optionally spans the data columns with a
    header above them (``(("ORION", 3), ("Alp. R1", 3))``, models side by side). ``notes`` say what a
    count counts and what is missing. ``metric`` names the metric that produced it.
    """

    id: str
    title: str
    label_columns: tuple[str, ...]
    columns: tuple[str, ...]
    rows: tuple[Row, ...]
    groups: tuple[tuple[str, int], ...] = ()
    notes: tuple[str, ...] = ()
    metric: str = ""

    def __post_init__(self) -> None:
        for row in self.rows:
            if len(row.labels) != len(self.label_columns) or len(row.cells) != len(self.columns):
                raise ValueError(
                    f"table {self.id}: row {row.labels} has {len(row.labels)} labels / {len(row.cells)} cells, "
                    f"expected {len(self.label_columns)} / {len(self.columns)}"
                )
        if self.groups and sum(span for _, span in self.groups) != len(self.columns):
            raise ValueError(f"table {self.id}: column groups span {sum(s for _, s in self.groups)} "
                             f"columns, the table has {len(self.columns)}")

    def cell(self, row_labels: Sequence[str] | str, column: int) -> Cell:
        """The cell of the row whose labels are ``row_labels`` (or whose first label is a str) at ``column``."""
        want = (row_labels,) if isinstance(row_labels, str) else tuple(row_labels)
        for row in self.rows:
            if row.labels[: len(want)] == want:
                return row.cells[column]
        raise KeyError(f"table {self.id} has no row {want}")

    def to_json(self) -> dict[str, Any]:
        return {
            "type": "table",
            "id": self.id,
            "title": self.title,
            "metric": self.metric,
            "label_columns": list(self.label_columns),
            "columns": list(self.columns),
            "groups": [[name, span] for name, span in self.groups],
            "rows": [r.to_json() for r in self.rows],
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class Series:
    """One line of a plot: ``x`` and ``y`` (``None`` where undefined), an optional band and the counts."""

    label: str
    x: tuple[float, ...]
    y: tuple[float | None, ...]
    low: tuple[float | None, ...] = ()
    high: tuple[float | None, ...] = ()
    counts: tuple[int, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"label": self.label, "x": list(self.x), "y": list(self.y), "low": list(self.low),
                "high": list(self.high), "counts": list(self.counts)}


@dataclass(frozen=True)
class Plot:
    """A figure of a metric: either data (``panels`` of line series) or a ``draw`` function.

    ``panels`` maps a panel title to its series and is drawn as a grid of line plots with shared axes
    labels ``xlabel``/``ylabel``; ``draw(fig)`` (for anything else) receives a matplotlib ``Figure``.
    :meth:`to_png` renders with the Agg backend, importing matplotlib only then.
    """

    id: str
    title: str
    panels: tuple[tuple[str, tuple[Series, ...]], ...] = ()
    xlabel: str = ""
    ylabel: str = ""
    draw: Callable[[Any], None] | None = field(default=None, compare=False, repr=False)
    invert_x: bool = False
    ylim: tuple[float, float] | None = None
    notes: tuple[str, ...] = ()
    metric: str = ""

    def to_png(self, dpi: int = 110) -> bytes:
        """The figure as PNG bytes (deterministic: no timestamps in the metadata)."""
        import matplotlib

        matplotlib.use("Agg", force=False)
        from matplotlib.figure import Figure

        ncols = min(3, max(1, len(self.panels)))
        nrows = max(1, math.ceil(len(self.panels) / ncols))
        fig = Figure(figsize=(4.2 * ncols, 3.2 * nrows + 0.5), layout="constrained")
        if self.draw is not None:
            self.draw(fig)
        else:
            self._draw_panels(fig, nrows, ncols)
        fig.suptitle(self.title)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=dpi, metadata={"Software": None})
        return buffer.getvalue()

    def _draw_panels(self, fig: Any, nrows: int, ncols: int) -> None:
        axes = fig.subplots(nrows, ncols, squeeze=False, sharey=True)
        for ax in axes.flat[len(self.panels):]:
            ax.set_visible(False)
        for ax, (panel_title, series) in zip(axes.flat, self.panels, strict=False):
            for s in series:
                y = [math.nan if v is None else v for v in s.y]
                (line,) = ax.plot(s.x, y, marker="o", markersize=3, label=s.label)
                if s.low and s.high:
                    low = [math.nan if v is None else v for v in s.low]
                    high = [math.nan if v is None else v for v in s.high]
                    ax.fill_between(s.x, low, high, alpha=0.2, color=line.get_color())
            ax.set_title(panel_title, fontsize=9)
            ax.set_xlabel(self.xlabel)
            ax.set_ylabel(self.ylabel)
            if self.ylim:
                ax.set_ylim(*self.ylim)
            if self.invert_x:
                ax.invert_xaxis()
            ax.grid(alpha=0.3)
            if series:
                ax.legend(fontsize=7)

    def to_json(self) -> dict[str, Any]:
        return {
            "type": "plot",
            "id": self.id,
            "title": self.title,
            "metric": self.metric,
            "xlabel": self.xlabel,
            "ylabel": self.ylabel,
            "panels": [{"title": t, "series": [s.to_json() for s in series]} for t, series in self.panels],
            "notes": list(self.notes),
        }


# -- the dataset a metric receives ---------------------------------------------------------------------
@dataclass
class AnalysisDataset:
    """Everything a metric may read: the episodes of one directory and their labels.

    ``episodes`` are :class:`vladrivebench.logs.Episode` objects (logs are the single source of truth);
    ``labels`` maps ``(episode_key(episode), step)`` to the :class:`~vladrivebench.records.Labels` of that step's CoT
    when the directory has been labelled with ``labeler``; ``notes`` lists what is missing or was skipped
    (truncated logs, steps without labels, …) and every report prints them.
    """

    directory: Path
    episodes: list[Any]
    labels: dict[tuple[str, int], Labels] = field(default_factory=dict)
    labeler: str | None = None
    notes: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def labels_for(self, episode: Any, step: int) -> Labels | None:
        """The labels of ``episode``'s step ``step``, or ``None`` when it has none (or is unlabelled)."""
        found = self.labels.get((episode_key(episode), step))
        if found is None or found.unlabelled:
            return None
        return found

    @property
    def labelled(self) -> bool:
        return bool(self.labels)

    def note(self, text: str) -> None:
        """Record something the reader must know (what is missing, what was skipped); no duplicates."""
        if text not in self.notes:
            self.notes.append(text)


def episode_key(episode: Any) -> str:
    """A key unique within a dataset: the log's path (episode ids repeat across runs of one directory tree)."""
    return str(episode.path)


# -- statistics ------------------------------------------------------------------------------------------
def wilson_interval(successes: float, total: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of a binomial proportion ``successes / total``."""
    if total <= 0:
        raise ValueError("the Wilson interval needs at least one observation")
    if not 0 <= successes <= total:
        raise ValueError(f"successes must be in [0, {total}], got {successes}")
    p = successes / total
    z2 = z * z
    centre = (p + z2 / (2 * total)) / (1 + z2 / total)
    half = z * math.sqrt(p * (1 - p) / total + z2 / (4 * total * total)) / (1 + z2 / total)
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exact ends: no 1e-17 rounding residue
    high = 1.0 if successes == total else min(1.0, centre + half)
    return low, high


def format_percent(value: float, digits: int = 1) -> str:
    """0.9655 → ``"96.5"`` (percent, without the sign, as in the paper's tables); exactly 1 → ``"100"``."""
    text = f"{value * 100.0:.{digits}f}"
    return "100" if text == f"{100:.{digits}f}" else text


def tables_and_plots(results: Iterable[Any]) -> tuple[list[Table], list[Plot]]:
    """Split a metric's results into tables and plots, keeping their order."""
    tables, plots = [], []
    for item in results:
        (tables if isinstance(item, Table) else plots if isinstance(item, Plot) else []).append(item)
    return tables, plots


def breakdown_text(counts: Mapping[str, int], total: int) -> str:
    """``{"maint": 1357}`` of 1357 → ``"maint=1357 (100%)"``; several → ``"slow=181, maint=23, accel=20"``."""
    items = [(k, v) for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])) if v > 0]
    if len(items) == 1 and total > 0 and items[0][1] == total:
        return f"{items[0][0]}={total} (100%)"
    return ", ".join(f"{k}={v}" for k, v in items) or "-"


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
        from .analysis import model_of, observational, scenario_group, step_views

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
        from .analysis import observational, step_views

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
        from .analysis import model_of, observational, scenario_group, step_views

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
        from .analysis import model_of, observational, step_views

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
        from .alignment import bin_fractions
        from .analysis import model_of, observational, scenario_group, step_views

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
        from .alignment import SHORT_NAMES, relaxed_aligned, strict_aligned
        from .analysis import model_of, observational, step_views

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


BUILTIN_METRICS: tuple[tuple[str, type, str], ...] = (
    ("mention_rate", MentionRate, "target mention rate by scenario and distance zone"),
    ("tl_accuracy", LightAccuracy, "traffic-light colour accuracy conditional on mention"),
    ("hallucination", HallucinationRate, "hallucination rate by scenario and distance zone"),
    ("contradiction", ContradictionRate, "internal contradiction rate per model (Wilson 95 % CI)"),
    ("alignment_distance", AlignmentByDistance, "relaxed/strict action alignment by distance (1 m bins)"),
    ("alignment_command", AlignmentByCommand, "alignment by CoT command in a speed band, head breakdown"),
)
"""The built-in metrics, registered by the core's plugin through ``register_metrics``."""


def metric_order(metric: Any, position: int) -> tuple[int, int]:
    """Where a metric goes in reports: its ``order`` attribute (default 100), then registry position."""
    order = getattr(metric, "order", 100)
    return (order if isinstance(order, int) else 100, position)
