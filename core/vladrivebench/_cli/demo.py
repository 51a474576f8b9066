"""What `vdb demo` shows after its sweep: labels, the headline figures per model, and a report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from vladrivebench._analysis.tables import wilson_interval


def label_and_summarise(out: Path, registry: Any, *, quiet: bool = True) -> tuple[list[str], Path]:
    """Label the demo's episodes, write an HTML report beside them; return summary lines and its path."""
    from vladrivebench._analysis.dataset import load_dataset
    from vladrivebench._analysis.report import compute_all, write_report
    from vladrivebench._cli.analysis import label_directory

    labeler = registry.default("labeler", "a labeler plugin (vdb label --labeler)").name
    label_directory(registry.create("labeler", labeler), labeler, out, quiet=quiet)
    dataset = load_dataset(out, labeler=labeler)
    report_path = out / "report.html"
    write_report(dataset, compute_all(dataset, registry), "html", report_path)
    return headline(dataset), report_path


def headline(dataset: Any) -> list[str]:
    """One line per model: mention, hallucination and contradiction rates and relaxed alignment, each with n."""
    from vladrivebench._analysis.alignment import spatial_alignment
    from vladrivebench._analysis.dataset import model_of, observational, step_views

    per_model: dict[str, dict[str, list]] = {}
    for episode in observational(dataset):
        tally = per_model.setdefault(model_of(dataset, episode), {"mention": [], "halluc": [], "contra": [],
                                                                   "align": []})
        views = step_views(dataset, episode)
        for view in views:
            if view.labels is None or view.labels.unlabelled:
                continue
            if view.labels.target_mentioned is not None and view.distance is not None and view.distance >= 0:
                tally["mention"].append(view.labels.target_mentioned)
            tally["halluc"].append(view.labels.hallucination)
            tally["contra"].append(view.labels.contradiction)
        rate = spatial_alignment([v.travelled for v in views], [v.aligned() for v in views])
        if rate is not None:
            tally["align"].append(rate)
    lines = []
    for model, tally in sorted(per_model.items()):
        align = tally["align"]
        mean_align = f"{100 * sum(align) / len(align):.1f} % (n={len(align)} episodes)" if align else "—"
        lines.append(f"{model}: target mentioned {_rate(tally['mention'])}, hallucination {_rate(tally['halluc'])}, "
                     f"contradiction {_rate(tally['contra'])}, relaxed alignment {mean_align}")
    return lines


def _rate(flags: list[bool]) -> str:
    if len(flags) < 2:
        return "—"
    hits = sum(bool(f) for f in flags)
    low, high = wilson_interval(hits, len(flags))
    return f"{100 * hits / len(flags):.1f} % [{100 * low:.1f}–{100 * high:.1f}] (n={len(flags)} steps)"
