"""The scripted reference VLA: ground-truth perception, a templated CoT with exactly known error rates, and
an action head that mixes a CoT-driven and a perception-driven speed policy with weight ``alpha``.

Importing this package is cheap: the model and its helpers load on first use.

- :class:`ScriptedModel` — the model (the plugin registers it as ``scripted``);
- :func:`cot_truth` — what the model knows it wrote in a CoT it generated (mention, hallucination, …);
  (``ScriptedModel.cot_extras`` hands it to the runner, which logs it in ``/extras`` as ``scripted_truth``).
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
__all__ = ["ScriptedModel", "cot_truth", "__version__"]


def __getattr__(name: str) -> Any:
    if name in {"ScriptedModel", "cot_truth"}:
        from . import model

        return getattr(model, name)
    raise AttributeError(f"module 'vdb_model_scripted' has no attribute {name!r}")
