"""Writing a condition or a paradigm: injection texts, the selfsplice gate and seed-level statistics.

Conditions (:class:`~vladrivebench.Condition`) say what text replaces the CoT; :class:`TextCondition` is the
common kind and :data:`PAPER_TEXTS` holds the paper's injection texts (Appendix F) verbatim. Paradigms
(:class:`~vladrivebench.Paradigm`) plan, analyse and tabulate intervention runs with the helpers here:
:func:`gate_record` (the selfsplice check of one step), :func:`trajectory_difference`, and the seed-level
statistics (:func:`one_sample_t_test`, :func:`t_interval`, :func:`holm_adjust`, :func:`cohens_d`).
"""

from vladrivebench._intervention.conditions import (
    PAPER_TEXTS,
    SelfSplice,
    TextCondition,
)
from vladrivebench._intervention.runs import gate_record, trajectory_difference
from vladrivebench._intervention.stats import cohens_d, holm_adjust, one_sample_t_test, t_interval

__all__ = [
    "PAPER_TEXTS", "SelfSplice", "TextCondition", "gate_record", "trajectory_difference", "cohens_d",
    "holm_adjust", "one_sample_t_test", "t_interval",
]
