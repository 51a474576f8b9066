"""Writing a metric: the analysed dataset, the steps a metric reads, and the tables and plots it returns.

A metric plugin's ``compute(dataset)`` receives an :class:`AnalysisDataset` (the logged episodes, their
labels, the notes on what was left out) and returns :class:`Table` and :class:`Plot` objects whose every
:class:`Cell` carries the count behind it (a cell with fewer than :data:`MIN_COUNT` samples shows
:data:`MISSING`). :func:`observational` gives the models' own runs (not intervention episodes);
:func:`step_views` gives one :class:`StepView` per logged step (the CoT text, its labels, ego speed,
``v_des``, distance to the target, zone, scenario group). The alignment rules of the paper
(:func:`cot_action_set`, :func:`action_head_set`, :func:`relaxed_aligned`, :func:`strict_aligned`) and
Wilson intervals are here too, so a metric never re-implements them.
"""

from vladrivebench._analysis.alignment import (
    ACTION_CLASSES,
    SHORT_NAMES,
    action_head_set,
    bin_fractions,
    cot_action_set,
    relaxed_aligned,
    strict_aligned,
    time_to_collision,
)
from vladrivebench._analysis.dataset import (
    StepView,
    distance_zone,
    model_of,
    observational,
    scenario_group,
    step_views,
)
from vladrivebench._analysis.tables import (
    MIN_COUNT,
    MISSING,
    AnalysisDataset,
    Cell,
    Plot,
    Row,
    Series,
    Table,
    breakdown_text,
    episode_key,
    format_percent,
    wilson_interval,
)

__all__ = [
    "AnalysisDataset", "StepView", "step_views", "observational", "scenario_group", "model_of", "distance_zone",
    "episode_key",
    "Cell", "Row", "Table", "Series", "Plot", "MIN_COUNT", "MISSING", "breakdown_text", "format_percent",
    "wilson_interval",
    "ACTION_CLASSES", "SHORT_NAMES", "action_head_set", "bin_fractions", "cot_action_set", "relaxed_aligned",
    "strict_aligned", "time_to_collision",
]
