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
