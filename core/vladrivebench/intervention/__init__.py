"""Writing a condition or a paradigm: injection texts, planned episodes, step policies, the selfsplice gate
and seed-level statistics.

Conditions (:class:`~vladrivebench.Condition`) say what text replaces the CoT; :class:`TextCondition` is the
common kind and :data:`PAPER_TEXTS` holds the paper's injection texts (Appendix F) verbatim.

Paradigms (:class:`~vladrivebench.Paradigm`, registered with ``register_paradigms``) say how a run intervenes
and what it measures. The core's own (open-loop, closed-loop, safety) are built from exactly these names:

- planning: :class:`InterventionConfig` (what the paradigm is asked to run), :class:`PlannedEpisode`;
- step policies: :class:`RunContext` (the run's :class:`Splicer`: resolve, check, splice and decode a
  condition with the pinned RNG streams), :func:`own_step`, :class:`BaselinePolicy`,
  :class:`OpenLoopPolicy`, :class:`InjectionPolicy`, :class:`ShadowController`, :class:`WrapsController`;
- lockstep batches (``--batch B``): :class:`BatchedParadigm` (the optional capability), :class:`LaneStep`,
  the batched steps of the built-in policies :func:`injection_step_batch` and :func:`open_loop_step_batch`,
  :func:`selfsplice_many` (the gate within a batch) and the :class:`Splicer`'s ``own_many`` /
  ``splice_many`` / ``decode_many``;
- the selfsplice gate: :func:`gate_record` (one step's check, logged by a policy) and :class:`GateTally`
  (what ``analyse`` adds the logged records to); :func:`trajectory_difference`;
- analysis from the logs: :class:`LoggedEpisodes`, :func:`episode_summary`, :class:`EpisodeSummary`,
  :func:`cumulative_distance`, :func:`displacements`, :func:`horizon_key`;
- statistics (the seed is the unit of replication): :func:`open_loop_stats` / :class:`OpenLoopStats`,
  :func:`with_holm`, :func:`closed_loop_stats` / :class:`ClosedLoopStats`, :func:`one_sample_t_test`,
  :func:`t_interval` / :class:`Interval`, :func:`holm_adjust`, :func:`cohens_d`, :func:`json_number`,
  :func:`from_json_number`;
- tables: :func:`signed`, :func:`p_text`, :func:`interval_text`, :func:`number_text`, :func:`cell_value`,
  :func:`model_text` (cells and tables themselves are in :mod:`vladrivebench.metrics`); :class:`PilotEffects` for
  ``vdb intervene --plan``;
- resuming: :class:`EffectiveOptions` (the optional capability stating every setting a paradigm runs with,
  defaults included, recorded in ``run.json`` so that a resume under other settings is refused).
"""

from vladrivebench._intervention.conditions import (
    PAPER_TEXTS,
    SELFSPLICE,
    SelfSplice,
    TextCondition,
)
from vladrivebench._intervention.metric import (
    cell_value,
    interval_text,
    model_text,
    number_text,
    p_text,
    signed,
)
from vladrivebench._intervention.runs import (
    BaselinePolicy,
    GateTally,
    InjectionPolicy,
    InterventionConfig,
    LaneStep,
    LoggedEpisodes,
    OpenLoopPolicy,
    PlannedEpisode,
    RunContext,
    ShadowController,
    Splicer,
    WrapsController,
    came_to_stop,
    displacements,
    episode_summary,
    gate_record,
    horizon_key,
    injection_step_batch,
    open_loop_step_batch,
    own_step,
    selfsplice_many,
    trajectory_difference,
)
from vladrivebench._intervention.stats import (
    ClosedLoopStats,
    EpisodeSummary,
    Interval,
    OpenLoopStats,
    closed_loop_stats,
    cohens_d,
    cumulative_distance,
    from_json_number,
    holm_adjust,
    json_number,
    one_sample_t_test,
    open_loop_stats,
    t_interval,
    with_holm,
)
from vladrivebench.protocols import BatchedParadigm, EffectiveOptions, PilotEffects

__all__ = [
    # conditions
    "PAPER_TEXTS", "SELFSPLICE", "SelfSplice", "TextCondition",
    # planning and step policies
    "InterventionConfig", "PlannedEpisode", "RunContext", "Splicer", "own_step", "BaselinePolicy",
    "OpenLoopPolicy", "InjectionPolicy", "ShadowController", "WrapsController",
    # lockstep batches (vdb intervene --batch)
    "BatchedParadigm", "LaneStep", "injection_step_batch", "open_loop_step_batch", "selfsplice_many",
    # the selfsplice gate
    "gate_record", "GateTally", "trajectory_difference",
    # analysis from the logs
    "LoggedEpisodes", "episode_summary", "EpisodeSummary", "cumulative_distance", "displacements", "horizon_key",
    "came_to_stop",
    # statistics
    "open_loop_stats", "OpenLoopStats", "with_holm", "closed_loop_stats", "ClosedLoopStats", "cohens_d",
    "holm_adjust", "one_sample_t_test", "t_interval", "Interval", "json_number", "from_json_number",
    # tables
    "signed", "p_text", "interval_text", "number_text", "cell_value", "model_text", "PilotEffects",
    # resuming
    "EffectiveOptions",
]
