"""The core's built-in plugin: registered through the same entry-point group and hooks as any other.

Registration imports nothing heavy: factories are referenced by import path and built on first use.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from vladrivebench import hookimpl


def suite_directory() -> Path:
    """Where the scenario suite (the top-level ``scenarios/`` folder) is installed."""
    return Path(str(importlib.resources.files("vladrivebench.suite")))


@hookimpl
def register_scenarios(register):
    register(suite_directory(), description="the paper's scenario suite (Appendix A) and intervention routes")


@hookimpl
def register_conditions(register):
    from vladrivebench._intervention.conditions import (
        builtin_conditions,  # numpy only: registration stays light
    )

    for condition in builtin_conditions():
        register(condition.name, _constant(condition), description=condition.description)


@hookimpl
def register_paradigms(register):
    register("open-loop", "vladrivebench._builtins.paradigms.open_loop:OpenLoopParadigm",
             description="conditions spliced beside the model's own CoT at every step; displacement vs selfsplice")
    register("closed-loop", "vladrivebench._builtins.paradigms.closed_loop:ClosedLoopParadigm",
             description="the injected CoT drives whole episodes; distance, brakes and speed vs the baseline")
    register("safety", "vladrivebench._builtins.paradigms.safety:SafetyParadigm",
             description="closed loop on obstacle routes under 'road is clear'; collisions per seed")


@hookimpl
def register_controllers(register):
    register("pid", "vladrivebench._builtins.controllers:PIDController",
             description="Bench2Drive-style PID tracker (throttle/steer/brake)")
    register("mpc", "vladrivebench._builtins.controllers:MPCController",
             description="AlpaSim-style MPC tracker that sets the next ego state")


@hookimpl
def register_executors(register):
    from vladrivebench._engine.executors import (  # standard library only
        PipelinedExecutor,
        ProcessExecutor,
        SequentialExecutor,
    )

    register("sequential", SequentialExecutor, description="one episode after the other, in this process")
    register("process", ProcessExecutor, description="a pool of spawned worker processes (--workers N)")
    register("pipelined", PipelinedExecutor,
             description="--workers N batch jobs on threads here, their models in one model-server process")


BUILTIN_METRICS: tuple[tuple[str, str, str], ...] = (
    ("mention_rate", "MentionRate", "target mention rate by scenario and distance zone"),
    ("tl_accuracy", "LightAccuracy", "traffic-light colour accuracy conditional on mention"),
    ("hallucination", "HallucinationRate", "hallucination rate by scenario and distance zone"),
    ("contradiction", "ContradictionRate", "internal contradiction rate per model (Wilson 95 % CI)"),
    ("alignment_distance", "AlignmentByDistance", "relaxed/strict action alignment by distance (1 m bins)"),
    ("alignment_command", "AlignmentByCommand", "alignment by CoT command in a speed band, head breakdown"),
)
"""The built-in metrics (name, class in ``vladrivebench._builtins.metrics``, description), registered by import
path so that ``vdb list-plugins`` does not import the analysis stack."""


@hookimpl
def register_metrics(register):
    for name, cls, description in BUILTIN_METRICS:
        register(name, f"vladrivebench._builtins.metrics:{cls}", description=description)
    register("intervention", "vladrivebench._intervention.metric:InterventionMetric", description="open-loop, closed-loop and safety intervention "
             "tables (paper Tables 5-9) with the selfsplice gate")


def _constant(value):
    def factory():
        return value

    return factory
