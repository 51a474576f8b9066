"""The metric: per episode, the distance to the target at the first step whose CoT mentions it.

A metric receives a :class:`vladrivebench._analysis.tables.AnalysisDataset` and returns :class:`Table` and
:class:`Plot` records whose cells carry their counts; it reads logs and labels only.
"""

from __future__ import annotations

import statistics
from typing import Any

from vladrivebench.metrics import (
    MIN_COUNT,
    MISSING,
    Cell,
    Row,
    Table,
    model_of,
    observational,
    scenario_group,
    step_views,
)


class FirstMentionDistance:
    name = "first_mention"
    order = 15  # right after the built-in mention-rate table in reports

    def compute(self, dataset: Any) -> list[Any]:
        first: dict[tuple[str, str], list[float]] = {}
        never: dict[tuple[str, str], int] = {}
        for episode in observational(dataset):
            key = (scenario_group(episode), model_of(dataset, episode))
            views = [v for v in step_views(dataset, episode)
                     if v.labels is not None and v.labels.target_mentioned is not None and v.distance is not None]
            if not views:
                continue  # no target, or no labels: nothing to say about this episode
            hit = next((v.distance for v in views if v.labels.target_mentioned), None)
            if hit is None:
                never[key] = never.get(key, 0) + 1
            else:
                first.setdefault(key, []).append(hit)
        keys = set(first) | set(never)
        if not keys:
            return []
        groups = sorted({g for g, _ in keys})
        models = sorted({m for _, m in keys})
        rows = []
        for group in groups:
            cells = []
            for model in models:
                values = first.get((group, model), [])
                missed = never.get((group, model), 0)
                n = len(values) + missed
                if len(values) < MIN_COUNT:
                    cells += [Cell(MISSING, len(values)), Cell(str(missed), n, float(missed))]
                else:
                    median = statistics.median(values)
                    cells += [Cell(f"{median:.1f}", len(values), median), Cell(str(missed), n, float(missed))]
            rows.append(Row((group,), tuple(cells)))
        return [Table(
            "first_mention", "Distance (m) to the target at its first mention", ("Scenario",),
            ("median m", "never") * len(models), tuple(rows), groups=tuple((m, 2) for m in models),
            notes=("median over episodes of the distance at the first labelled step that mentions the target "
                   "(count: episodes with a mention); never: episodes whose CoT never mentions it (count: "
                   "episodes)",), metric=self.name)]
