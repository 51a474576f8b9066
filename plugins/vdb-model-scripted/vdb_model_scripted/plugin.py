"""Entry point ``scripted``: registers the scripted reference model. Importing this module is cheap."""

from __future__ import annotations

import vladrivebench


def make_scripted(alpha: float = 0.5, miss_rate: float = 0.0, hallucination_rate: float = 0.0,
                  contradiction_rate: float = 0.0, light_error_rate: float = 0.0, cot_format: str = "sentence",
                  cruise_speed: float = 6.5, perception_range: float = 80.0, noise: float = 0.05):
    """Build a :class:`~vdb_model_scripted.model.ScriptedModel`.

    ``alpha`` ∈ [0, 1]: CoT–action coupling (0: the CoT cannot change the action; 1: the action follows
    the CoT only). ``miss_rate``, ``hallucination_rate``, ``contradiction_rate``, ``light_error_rate`` ∈
    [0, 1]: exact per-step probabilities of the CoT's errors. ``cot_format``: ``sentence`` (Alpamayo-like)
    or ``qa`` (ORION-like scene/objects/decision). ``cruise_speed`` (m/s), ``perception_range`` (m),
    ``noise`` (std of the action head's speed noise, m/s).
    """
    from .model import ScriptedModel

    return ScriptedModel(alpha=alpha, miss_rate=miss_rate, hallucination_rate=hallucination_rate,
                         contradiction_rate=contradiction_rate, light_error_rate=light_error_rate,
                         cot_format=cot_format, cruise_speed=cruise_speed, perception_range=perception_range,
                         noise=noise)


@vladrivebench.hookimpl
def register_models(register):
    register("scripted", make_scripted,
             description="scripted reference VLA: ground-truth perception, known CoT error rates, coupling alpha")


DEMO_MODEL_OPTIONS = {"miss_rate": 0.2, "hallucination_rate": 0.1, "contradiction_rate": 0.05, "alpha": 0.5}
"""Known error rates, so the scripted demo shows the benchmark recovering them from the CoTs alone."""


@vladrivebench.hookimpl
def register_defaults(register):
    # it perceives through the ground truth: no camera needed (3x faster); below kv, the demo's first choice
    register("demo", "scripted", priority=0, controller="pid", sim_options={"render": False},
             model_options=dict(DEMO_MODEL_OPTIONS),
             about="the scripted model configured with " + ", ".join(f"{k}={v}" for k, v in DEMO_MODEL_OPTIONS.items()))
