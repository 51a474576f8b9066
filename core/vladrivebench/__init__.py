"""VLADriveBench: is a driving VLA's chain-of-thought about the world, and connected to its action?

This module is the public API for plugin authors: everything in ``__all__`` (the hook marker, the
protocols every component satisfies, the optional model capabilities, the records that flow between
components, the user-facing errors and the RNG streams) plus the ``__all__`` of the public subpackages
listed in :data:`PUBLIC_SUBPACKAGES`. Every other module is private to the core (its name starts with an
underscore) and may change without notice; a test fails when a plugin or example imports one.

Importing this package must stay cheap: no torch, transformers or libsumo, ever.
"""

import pluggy

__version__ = "0.2.0"

PROJECT_NAME = "vladrivebench"
"""One name everywhere: the hook marker, the entry-point group and the import package."""

API_VERSION = "1.0"
"""The version of the plugin API (hooks, protocols, records, public subpackages). Hooks evolve compatibly:
arguments and hooks may be added within 1.x, never renamed or removed."""

hookimpl = pluggy.HookimplMarker(PROJECT_NAME)
"""Decorate a plugin's hook implementations with this marker (``@vladrivebench.hookimpl``)."""

PUBLIC_SUBPACKAGES = (
    "vladrivebench.world",
    "vladrivebench.metrics",
    "vladrivebench.labels",
    "vladrivebench.intervention",
    "vladrivebench.executors",
    "vladrivebench.episodes",
    "vladrivebench.cli",
    "vladrivebench.testing",
)
"""The public subpackages, one per kind of plugin author: simulators (world), metrics (tables and analysed
steps), labelers (label files and stores), paradigms and conditions (intervention), executors, and tests
of any plugin (testing). Each declares its API in ``__all__``."""

_LAZY = {
    'load_data_file': 'vladrivebench._engine.options',
    'load_toml': 'vladrivebench._engine.options',
    'episode_rng': 'vladrivebench._engine.rng',
    'step_rng': 'vladrivebench._engine.rng',
    'ActorSpec': 'vladrivebench._scenarios.spec',
    'EgoSpec': 'vladrivebench._scenarios.spec',
    'LightSpec': 'vladrivebench._scenarios.spec',
    'RoadSpec': 'vladrivebench._scenarios.spec',
    'Scenario': 'vladrivebench._scenarios.spec',
    'StopSignSpec': 'vladrivebench._scenarios.spec',
    'ConditionError': 'vladrivebench.errors',
    'ConfigError': 'vladrivebench.errors',
    'LogError': 'vladrivebench.errors',
    'ModelOutputError': 'vladrivebench.errors',
    'PluginLoadError': 'vladrivebench.errors',
    'ScenarioError': 'vladrivebench.errors',
    'UnknownNameError': 'vladrivebench.errors',
    'VdbError': 'vladrivebench.errors',
    'BatchedModel': 'vladrivebench.protocols',
    'BatchedParadigm': 'vladrivebench.protocols',
    'CoTExtras': 'vladrivebench.protocols',
    'EpisodeMemory': 'vladrivebench.protocols',
    'FidelityCheck': 'vladrivebench.protocols',
    'Condition': 'vladrivebench.protocols',
    'ConditionBatch': 'vladrivebench.protocols',
    'ConditionContext': 'vladrivebench.protocols',
    'Controller': 'vladrivebench.protocols',
    'Executor': 'vladrivebench.protocols',
    'Injection': 'vladrivebench.protocols',
    'Labeler': 'vladrivebench.protocols',
    'Metric': 'vladrivebench.protocols',
    'Paradigm': 'vladrivebench.protocols',
    'Simulator': 'vladrivebench.protocols',
    'TokenCounter': 'vladrivebench.protocols',
    'VLAModel': 'vladrivebench.protocols',
    'ACTOR_KINDS': 'vladrivebench.records',
    'Actor': 'vladrivebench.records',
    'CameraSpec': 'vladrivebench.records',
    'CameraView': 'vladrivebench.records',
    'CoT': 'vladrivebench.records',
    'CoTFormat': 'vladrivebench.records',
    'Control': 'vladrivebench.records',
    'EgoState': 'vladrivebench.records',
    'GroundTruth': 'vladrivebench.records',
    'LIGHT_COLOURS': 'vladrivebench.records',
    'LabelInput': 'vladrivebench.records',
    'Labels': 'vladrivebench.records',
    'NAV_COMMANDS': 'vladrivebench.records',
    'Observation': 'vladrivebench.records',
    'PoseHistory': 'vladrivebench.records',
    'STATED_ACTIONS': 'vladrivebench.records',
    'Trajectory': 'vladrivebench.records',
    'TrajectorySpec': 'vladrivebench.records',
}
"""Where each public name lives. Names are imported on first use, so that ``import vladrivebench`` (and so
``vdb --help`` and ``vdb list-plugins``) stays free of numpy and everything heavier."""

__all__ = [
    # plugin machinery
    "API_VERSION", "PROJECT_NAME", "PUBLIC_SUBPACKAGES", "__version__", "hookimpl",
    # protocols and optional model capabilities
    "Simulator", "VLAModel", "Controller", "Labeler", "Metric", "Executor", "Condition", "ConditionContext",
    "Injection", "Paradigm", "BatchedParadigm", "BatchedModel", "EpisodeMemory", "TokenCounter", "CoTExtras", "ConditionBatch", "FidelityCheck",
    # records
    "ACTOR_KINDS", "LIGHT_COLOURS", "NAV_COMMANDS", "STATED_ACTIONS", "Actor", "Control", "CoT", "CoTFormat",
    "EgoState", "GroundTruth", "LabelInput", "Labels", "Observation", "Trajectory", "TrajectorySpec",
    "CameraSpec", "CameraView", "PoseHistory",
    "Scenario", "ActorSpec", "EgoSpec", "LightSpec", "RoadSpec", "StopSignSpec",
    # errors
    "VdbError", "ConfigError", "ScenarioError", "ModelOutputError", "LogError", "UnknownNameError",
    "PluginLoadError", "ConditionError",
    # determinism and files
    "step_rng", "episode_rng", "load_toml", "load_data_file",
]



def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
