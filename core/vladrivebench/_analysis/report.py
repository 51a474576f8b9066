"""Rendering what the metrics computed: plain text, Markdown, LaTeX (booktabs, like the paper) and HTML.

Every registered metric is computed (built-in or third-party) and rendered in report order; a metric that
raises is reported as a note (or, with ``strict=True``, stops the report). Cells show their value and
the count behind it; plots are PNG files (embedded as base64 in HTML, written beside Markdown and LaTeX).
"""

from __future__ import annotations

import base64
import html
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vladrivebench._analysis.tables import AnalysisDataset, Cell, Plot, Table, metric_order
from vladrivebench.errors import ConfigError, VdbError

FORMATS = ("md", "latex", "html")


@dataclass
class Section:
    """What one metric returned."""

    metric: str
    description: str
    tables: list[Table] = field(default_factory=list)
    plots: list[Plot] = field(default_factory=list)


def compute_all(dataset: AnalysisDataset, registry: Any, *, strict: bool = False) -> list[Section]:
    """Compute every registered metric, in report order; failures become notes unless ``strict``."""
    metrics = []
    for position, component in enumerate(registry.components("metric")):
        try:
            metric = component.factory()
        except Exception as exc:
            _metric_failed(dataset, component, "could not be built", exc, strict)
            continue
        metrics.append((metric_order(metric, position), component, metric))
    sections = []
    for _, component, metric in sorted(metrics, key=lambda item: item[0]):
        try:
            results = list(metric.compute(dataset) or [])
        except VdbError:
            raise
        except Exception as exc:
            _metric_failed(dataset, component, "failed", exc, strict)
            continue
        section = Section(component.name, component.description)
        for item in results:
            if isinstance(item, Table):
                section.tables.append(item)
            elif isinstance(item, Plot):
                section.plots.append(item)
            else:
                dataset.note(f"metric {component.name!r} returned a {type(item).__name__}, not a Table or Plot; "
                             f"it was ignored")
        if section.tables or section.plots:
            sections.append(section)
    return sections


def _metric_failed(dataset: AnalysisDataset, component: Any, what: str, exc: Exception, strict: bool) -> None:
    message = f"metric {component.name!r} (plugin {component.plugin}, {component.distribution}) {what}: " \
              f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    if strict:
        raise VdbError(message) from None
    dataset.note(message)


def _heading(section: Section) -> str:
    text = section.description or section.metric
    return text[:1].upper() + text[1:]


# -- cell text ---------------------------------------------------------------------------------------------
def cell_text(cell: Cell, count_format: str = "{display} ({count})") -> str:
    """A cell with its count, unless the display already is the count or is text (its count is in the JSON)."""
    if _shows_its_count(cell) or (cell.value is None and not cell.missing):
        return cell.display
    return count_format.format(display=cell.display, count=cell.count)


def _shows_its_count(cell: Cell) -> bool:
    """A count cell (its text and value are its count); a 100 % rate over 100 bins is not one."""
    return cell.display == str(cell.count) and (cell.value is None or cell.value == cell.count)


# -- plain text (vdb metrics) ---------------------------------------------------------------------------------
def render_text(dataset: AnalysisDataset, sections: Sequence[Section]) -> str:
    """Aligned plain-text tables for the terminal (cell = value (count))."""
    lines = [f"VLADriveBench metrics: {dataset.directory} ({len(dataset.episodes)} episodes, labels: "
             f"{dataset.labeler or 'none'})", ""]
    for section in sections:
        for table in section.tables:
            lines += _text_table(table) + [""]
        for plot in section.plots:
            lines.append(f"[plot] {plot.title} (vdb report … --format html to see it)")
        if section.plots:
            lines.append("")
    lines += _notes_lines(dataset, prefix="note: ")
    return "\n".join(lines).rstrip() + "\n"


def _text_table(table: Table) -> list[str]:
    header = list(table.label_columns) + [
        f"{group}:{col}" if group else col for group, col in zip(_column_owners(table), table.columns, strict=True)]
    body = [list(r.labels) + [cell_text(c) for c in r.cells] for r in table.rows]
    widths = [max(len(str(row[i])) for row in [header] + body) for i in range(len(header))]
    out = [table.title, "-" * len(table.title)]
    for row in [header] + body:
        out.append("  ".join(str(v).ljust(w) if i < len(table.label_columns) else str(v).rjust(w)
                             for i, (v, w) in enumerate(zip(row, widths, strict=True))))
    out += [f"  ({note})" for note in table.notes]
    return out


def _column_owners(table: Table) -> list[str]:
    owners = []
    for name, span in table.groups or ():
        owners += [name] * span
    return owners or [""] * len(table.columns)


def _notes_lines(dataset: AnalysisDataset, prefix: str) -> list[str]:
    return [prefix + note for note in dataset.notes]


# -- Markdown -------------------------------------------------------------------------------------------------
def render_markdown(dataset: AnalysisDataset, sections: Sequence[Section], plot_files: dict[str, str]) -> str:
    out = ["# VLADriveBench report", "", f"Directory `{dataset.directory}`: {len(dataset.episodes)} episodes; "
           f"labels: {dataset.labeler or 'none'}. Cells show the value and, in parentheses, the count behind it.", ""]
    if dataset.notes:
        out += ["**What is missing or was left out:**", ""] + [f"- {n}" for n in dataset.notes] + [""]
    for section in sections:
        out += [f"## {_heading(section)}", ""]
        for table in section.tables:
            out += [f"### {table.title}", ""]
            header = list(table.label_columns) + [
                f"{g} {c}".strip() for g, c in zip(_column_owners(table), table.columns, strict=True)]
            out.append("| " + " | ".join(_md(h) for h in header) + " |")
            out.append("|" + "|".join([" --- "] * len(table.label_columns) + [" ---: "] * len(table.columns)) + "|")
            for row in table.rows:
                out.append("| " + " | ".join([_md(v) for v in row.labels] + [_md(cell_text(c)) for c in row.cells])
                           + " |")
            out += [""] + [f"*{_md(n)}*" for n in table.notes] + [""]
        for plot in section.plots:
            out += [f"![{_md(plot.title)}]({plot_files[plot.id]})", ""]
    return "\n".join(out)


def _md(text: str) -> str:
    return str(text).replace("|", "\\|")


# -- LaTeX ----------------------------------------------------------------------------------------------------
def render_latex(dataset: AnalysisDataset, sections: Sequence[Section], plot_files: dict[str, str]) -> str:
    """A LaTeX fragment of booktabs tables (the paper's style) and figures; \\input it in a document."""
    out = ["% VLADriveBench report; needs \\usepackage{booktabs,graphicx}",
           f"% directory: {_tex(str(dataset.directory))}; labels: {_tex(dataset.labeler or 'none')}", ""]
    for note in dataset.notes:
        out.append(f"% note: {note}")
    for section in sections:
        for table in section.tables:
            out += _latex_table(table) + [""]
        for plot in section.plots:
            out += ["\\begin{figure}[t]", "\\centering", f"\\includegraphics[width=\\linewidth]{{{plot_files[plot.id]}}}",
                    f"\\caption{{{_tex(plot.title)}.}}", f"\\label{{fig:{plot.id}}}", "\\end{figure}", ""]
    if dataset.notes:
        out += ["\\paragraph{Missing data.}", "\\begin{itemize}"] + [f"\\item {_tex(n)}" for n in dataset.notes] \
            + ["\\end{itemize}"]
    return "\n".join(out) + "\n"


def _latex_table(table: Table) -> list[str]:
    n_labels, n_cols = len(table.label_columns), len(table.columns)
    spec = "l" * n_labels + " " + "c" * n_cols
    notes = " ".join(table.notes)
    out = ["\\begin{table}[t]", "\\centering", f"\\caption{{{_tex(table.title)}. {_tex(notes)}}}",
           f"\\label{{tab:{table.id}}}", "\\small", f"\\begin{{tabular}}{{{spec}}}", "\\toprule"]
    if table.groups:
        heads, rules, col = [], [], n_labels + 1
        for name, span in table.groups:
            heads.append(f"\\multicolumn{{{span}}}{{c}}{{{_tex(name)}}}")
            rules.append(f"\\cmidrule(lr){{{col}-{col + span - 1}}}")
            col += span
        out += ["&" * n_labels + " " + " & ".join(heads) + " \\\\", " ".join(rules)]
    out.append(" & ".join(_tex(h) for h in list(table.label_columns) + list(table.columns)) + " \\\\")
    out.append("\\midrule")
    for row in table.rows:
        cells = [_tex(v) for v in row.labels] + [_latex_cell(c) for c in row.cells]
        out.append(" & ".join(cells) + " \\\\")
    out += ["\\bottomrule", "\\end{tabular}", "\\end{table}"]
    return out


def _latex_cell(cell: Cell) -> str:
    if _shows_its_count(cell):
        return _tex(cell.display)
    display = "---" if cell.missing else _tex(cell.display)
    return f"{display}\\,{{\\tiny({cell.count})}}"


_TEX_ESCAPES = {"\\": "\\textbackslash{}", "&": "\\&", "%": "\\%", "$": "\\$", "#": "\\#", "_": "\\_",
                "{": "\\{", "}": "\\}", "~": "\\textasciitilde{}", "^": "\\textasciicircum{}", "—": "---",
                "–": "--", "<": "$<$", ">": "$>$", "×": "$\\times$"}


def _tex(text: str) -> str:
    return "".join(_TEX_ESCAPES.get(ch, ch) for ch in str(text))


# -- HTML -----------------------------------------------------------------------------------------------------
_CSS = """body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:14px}th,td{padding:3px 8px;text-align:right}
th.l,td.l{text-align:left}thead tr:last-child th{border-bottom:1px solid #333}
table{border-top:2px solid #333;border-bottom:2px solid #333}th.group{border-bottom:1px solid #999}
.n{color:#888;font-size:11px;margin-left:2px}.missing{color:#aaa}.notes{color:#555;font-size:13px}
img{max-width:100%;border:1px solid #eee}.warn{background:#fff6e0;padding:.5em 1em;border-left:4px solid #e0a000}"""


def render_html(dataset: AnalysisDataset, sections: Sequence[Section], plot_png: dict[str, bytes]) -> str:
    """One self-contained HTML page: tables with counts, plots embedded as base64 PNG, notes."""
    esc = html.escape
    out = ["<!DOCTYPE html>", "<html><head><meta charset='utf-8'><title>VLADriveBench report</title>",
           f"<style>{_CSS}</style></head><body>", "<h1>VLADriveBench report</h1>",
           f"<p>Directory <code>{esc(str(dataset.directory))}</code>: {len(dataset.episodes)} episodes; labels: "
           f"{esc(dataset.labeler or 'none')}. Every cell shows its value and, in grey, the count behind it.</p>"]
    if dataset.notes:
        out.append("<div class='warn'><b>What is missing or was left out</b><ul>"
                   + "".join(f"<li>{esc(n)}</li>" for n in dataset.notes) + "</ul></div>")
    for section in sections:
        out.append(f"<h2>{esc(_heading(section))}</h2>")
        for table in section.tables:
            out += _html_table(table)
        for plot in section.plots:
            data = base64.b64encode(plot_png[plot.id]).decode("ascii")
            out.append(f"<figure><img alt='{esc(plot.title)}' src='data:image/png;base64,{data}'>"
                       f"<figcaption class='notes'>{esc(plot.title)}. {esc(' '.join(plot.notes))}</figcaption></figure>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"


def _html_table(table: Table) -> list[str]:
    esc = html.escape
    out = [f"<h3>{esc(table.title)}</h3>", f"<table id='{esc(table.id)}'><thead>"]
    if table.groups:
        out.append("<tr>" + "<th></th>" * len(table.label_columns)
                   + "".join(f"<th class='group' colspan='{span}'>{esc(name)}</th>" for name, span in table.groups)
                   + "</tr>")
    out.append("<tr>" + "".join(f"<th class='l'>{esc(h)}</th>" for h in table.label_columns)
               + "".join(f"<th>{esc(h)}</th>" for h in table.columns) + "</tr></thead><tbody>")
    for row in table.rows:
        cells = "".join(f"<td class='l'>{esc(v)}</td>" for v in row.labels)
        for cell in row.cells:
            title = f" title='{cell.low * 100:.1f}–{cell.high * 100:.1f} % (95 % CI)'" if cell.low is not None else ""
            shown = f"<span class='missing'>{esc(cell.display)}</span>" if cell.missing else esc(cell.display)
            count = "" if _shows_its_count(cell) else f"<span class='n'>{cell.count}</span>"
            cells += f"<td{title}>{shown}{count}</td>"
        out.append(f"<tr>{cells}</tr>")
    out.append("</tbody></table>")
    out += [f"<p class='notes'>{esc(n)}</p>" for n in table.notes]
    return out


# -- JSON and files -------------------------------------------------------------------------------------------
def to_json(dataset: AnalysisDataset, sections: Sequence[Section]) -> dict[str, Any]:
    """Everything ``vdb metrics --json`` prints: tables and plot data with counts, and the notes."""
    return {
        "directory": str(dataset.directory),
        "episodes": len(dataset.episodes),
        "labeler": dataset.labeler,
        "labels": dataset.extra.get("label_summary"),
        "notes": list(dataset.notes),
        "metrics": [{"name": s.metric, "description": s.description,
                     "results": [t.to_json() for t in s.tables] + [p.to_json() for p in s.plots]} for s in sections],
    }


def write_report(dataset: AnalysisDataset, sections: Sequence[Section], fmt: str, out: Path | str) -> list[Path]:
    """Write the report (and, for md/latex, its PNG plots beside it); returns every file written."""
    if fmt not in FORMATS:
        raise ConfigError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    out = Path(out)
    if out.is_dir():
        raise ConfigError(f"--out {out}: is a directory; give a file name such as {out / ('report.' + fmt)}")
    if not out.parent.is_dir():
        raise ConfigError(f"--out {out}: the folder {out.parent} does not exist")
    pngs = {plot.id: plot.to_png() for s in sections for plot in s.plots}
    written = []
    if fmt == "html":
        text = render_html(dataset, sections, pngs)
    else:
        folder = out.parent / f"{out.stem}_plots"
        files = {}
        if pngs:
            folder.mkdir(exist_ok=True)
        for plot_id, png in pngs.items():
            path = folder / f"{plot_id}.png"
            _atomic_write(path, png)
            written.append(path)
            files[plot_id] = f"{folder.name}/{path.name}"
        text = (render_markdown if fmt == "md" else render_latex)(dataset, sections, files)
    _atomic_write(out, text.encode("utf-8"))
    return [out] + written


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None


def dumps(data: Any) -> str:
    return json.dumps(data, indent=2, ensure_ascii=False)
