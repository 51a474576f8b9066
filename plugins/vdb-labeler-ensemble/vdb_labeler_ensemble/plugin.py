"""Entry point of the ``vdb-labeler-ensemble`` distribution: registers the ``ensemble`` labeler.

Registration imports nothing heavy: the factory is given by its import path, so the HTTP client, the
SQLite cache and numpy are imported when a labeler is first built (see ``labeler.build_labeler`` for the
options; they are checked against its signature).
"""

from __future__ import annotations

import vladrivebench

from . import LABELER_NAME


@vladrivebench.hookimpl
def register_labelers(register):
    register(LABELER_NAME, "vdb_labeler_ensemble.labeler:build_labeler",
             description="majority vote of LLM backends (OpenAI-compatible, Anthropic, Gemini) with a shared prompt")
