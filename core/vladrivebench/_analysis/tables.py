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
    from vladrivebench.records import Labels

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

    ``episodes`` are :class:`vladrivebench._logs.episodes.Episode` objects (logs are the single source of truth);
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


def metric_order(metric: Any, position: int) -> tuple[int, int]:
    """Where a metric goes in reports: its ``order`` attribute (default 100), then registry position."""
    order = getattr(metric, "order", 100)
    return (order if isinstance(order, int) else 100, position)
