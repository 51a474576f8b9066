"""The intervention report metric: the selfsplice gate table, then the run's paradigm's tables and plots.

The metric reads the results an intervention run computed from its logs (``intervention.json``, written by
:func:`vladrivebench._intervention.runs.analyse`); when a run directory has logs and a manifest but no results
yet, they are computed from the logs without writing anything. Directories without intervention runs give
``[]``.

The gate table is the core's (every paradigm runs the selfsplice gate); every other table or plot comes from
the registered paradigm named by the results' ``mode`` (``Paradigm.tables``): the metric gives each its id
suffix and run label, marks it INVALID when the gate failed and files it under this metric. The formatting
helpers here (:func:`signed`, :func:`p_text`, :func:`interval_text`, :func:`number_text`,
:func:`cell_value`) are public in :mod:`vladrivebench.intervention` for paradigm authors.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from vladrivebench._analysis.tables import Cell, Row, Table
from vladrivebench._intervention.stats import from_json_number


# -- formatting -----------------------------------------------------------------------------------------
def signed(value: Any, digits: int = 3) -> str:
    """A JSON number with its sign (``+0.123``), ``±inf`` kept, ``—`` when missing."""
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


def number_text(value: Any, digits: int = 2) -> str:
    """A JSON number with ``digits`` decimals, ``—`` for a missing one (NaN / null)."""
    v = from_json_number(value)
    return "—" if math.isnan(v) else f"{v:.{digits}f}"


def cell_value(value: Any) -> float | None:
    """A JSON number as a :class:`Cell` value: ``None`` when it is missing (NaN / null), ±inf kept."""
    v = from_json_number(value)
    return None if math.isnan(v) else v


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


def find_runs(directory: Path, registry: Any = None) -> list[tuple[str, dict[str, Any]]]:
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
                results = analyse(run_dir, write=False, registry=registry)
            except VdbError:
                continue  # not an intervention run, or an incomplete one: nothing to report
        label = str(run_dir.relative_to(directory)) if run_dir != directory else run_dir.name
        found.append((label, results))
    return found


def tables_for(results: Mapping[str, Any], label: str = "", registry: Any = None) -> list[Any]:
    """The tables and plots of one intervention run's results: the gate, then its paradigm's."""
    suffix = f".{label}" if label else ""
    paradigm, missing = _paradigm_of(results, registry)
    gate = gate_table(results, suffix)
    if missing:
        gate = dataclasses.replace(gate, notes=gate.notes + (missing,))
    items: list[Any] = [gate]
    for item in paradigm.tables(results) if paradigm is not None else []:
        items.append(dataclasses.replace(item, id=f"{item.id}{suffix}", title=f"{_validity(results)}{item.title}",
                                         metric="intervention"))
    if label:
        items = [dataclasses.replace(item, title=f"{item.title} [run {label}]") for item in items]
    return items


def _paradigm_of(results: Mapping[str, Any], registry: Any) -> tuple[Any, str]:
    """The run's registered paradigm, or ``None`` and a note saying why its tables are missing."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._intervention.runs import build_paradigm
    from vladrivebench.errors import UnknownNameError

    mode = results.get("mode")
    try:
        return build_paradigm(registry or get_registry(), mode, results.get("paradigm_options")), ""
    except UnknownNameError:
        return None, (f"This run's paradigm {mode!r} is not installed, so only the gate is shown; install the "
                      f"plugin that registers it (see `vdb list-plugins`) to see its tables.")


def _validity(results: Mapping[str, Any]) -> str:
    return "" if results.get("valid") else "INVALID (selfsplice gate failed) — "


def model_text(results: Mapping[str, Any]) -> str:
    """The run's model as tables name it: ``scripted (alpha=1)``."""
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
    return Table(f"intervention.gate{suffix}", f"{_validity(results)}Selfsplice gate — {model_text(results)}, "
                 f"{results.get('mode')}", ("Run",), columns,
                 (Row((", ".join(results.get("routes", [])),), cells),), notes=tuple(notes), metric="intervention")


FIDELITY_COLUMNS = ("Fidelity steps failed", "Max fidelity cache diff", "Max fidelity trajectory diff (m)")


def _fidelity_cells(gate: Mapping[str, Any]) -> tuple[Cell, ...]:
    checked = int(gate["fidelity_steps_checked"])
    failed, cache, traj = (float(gate.get(k, 0.0)) for k in
                           ("fidelity_steps_failed", "max_fidelity_cache_diff", "max_fidelity_trajectory_diff"))
    return (Cell(str(int(failed)), checked, failed), Cell(f"{cache:.3g}", checked, cache),
            Cell(f"{traj:.3g}", checked, traj))


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


def summary_text(results: Mapping[str, Any], *, notes: bool = False, registry: Any = None) -> str:
    """Every table of one run as plain text (notes only when asked)."""
    parts = []
    for item in tables_for(results, registry=registry):
        if isinstance(item, Table):
            text = table_text(item if notes else Table(item.id, item.title, item.label_columns, item.columns,
                                                        item.rows, item.groups, (), item.metric))
            parts.append(text)
    return "\n\n".join(parts)
