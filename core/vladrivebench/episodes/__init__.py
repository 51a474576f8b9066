"""Running episodes in process: one closed-loop episode, and any registered component by name.

For plugins that drive the simulator themselves (an expert that collects training data, a model's own
closed-loop checks): :func:`run_episode` runs one episode of a model, a simulator and a controller under a
step policy (:func:`own_cot_policy` by default) and returns its :class:`EpisodeResult`; a component that
fails raises :class:`EpisodeFailure` naming it. :func:`build_component` builds any registered component
(``build_component("controller", "pid")``, ``build_component("simulator", "kinematic", width=320)``) from the
installed plugins, checking its options as the CLI does. Sweeps, logs and run directories are the
engine's: run them through ``vdb run``.

Reading logged episodes: :func:`read_episode` (one ``*.mcap``), :func:`load_episodes` / :func:`find_episodes`
(a directory) give :class:`Episode` objects whose ``steps`` are :class:`StepRecord` — typed records
(``step.ego.speed``, ``step.ground_truth.actors``, ``step.cot.text``, ``step.trajectory.xy``,
``step.control.brake``), not dictionaries.
"""

from vladrivebench._engine.runner import (
    EpisodeFailure,
    EpisodeResult,
    StepPolicy,
    own_cot_policy,
    run_episode,
)
from vladrivebench._logs.episodes import Episode, StepRecord, find_episodes, load_episodes, read_episode


def build_component(kind: str, name: str, **options):
    """The registered component ``kind``/``name`` built with ``options`` (checked against its factory)."""
    from vladrivebench._engine.registry import get_registry

    return get_registry().create(kind, name, options)


__all__ = ["EpisodeFailure", "EpisodeResult", "StepPolicy", "own_cot_policy", "run_episode", "build_component",
           "read_episode", "load_episodes", "find_episodes", "Episode", "StepRecord"]
