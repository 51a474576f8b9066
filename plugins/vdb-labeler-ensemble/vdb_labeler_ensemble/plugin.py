"""Entry point of the ``vdb-labeler-ensemble`` distribution: registers the ``ensemble`` labeler.

Registration imports nothing heavy: the HTTP client, the SQLite cache and numpy are imported by the
factory, when a labeler is first built.
"""

from __future__ import annotations

from typing import Any

import vladrivebench

from . import LABELER_NAME


def make_ensemble_labeler(
    backends: Any,
    tie_breaker: Any = "",
    cache: Any = "",
    concurrency: Any = 4,
    max_retries: Any = 5,
    timeout: Any = 60.0,
    prompt: Any = "",
    min_votes: Any = 0,
    max_retry_after: Any = 300.0,
    progress: Any = True,
    seed: Any = 0,
):
    """Build the ``ensemble`` labeler; every option is checked before any call is spent.

    ``backends``: comma-separated ``KIND:MODEL[@BASE_URL][?key_env=VAR&name=ALIAS…]`` (or a list);
    ``tie_breaker``: one more backend, asked only when a label's vote is split; ``cache``: SQLite file
    (default: the user's cache dir; ``off`` for none); ``concurrency``: calls in flight per backend;
    ``max_retries``, ``timeout``, ``max_retry_after`` (seconds); ``prompt``: your prompt file;
    ``min_votes``: valid answers needed (default: a majority of the backends).
    """
    from .labeler import build_labeler

    return build_labeler(backends, tie_breaker, cache, concurrency, max_retries, timeout, prompt, min_votes,
                         max_retry_after, progress, seed)


@vladrivebench.hookimpl
def register_labelers(register):
    register(LABELER_NAME, make_ensemble_labeler,
             description="majority vote of LLM backends (OpenAI-compatible, Anthropic, Gemini) with a shared prompt")
