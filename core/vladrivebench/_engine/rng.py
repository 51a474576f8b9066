"""Random-number streams pinned to (seed, step, purpose).

Pinning every draw to its step is what makes interventions comparable: the baseline and a spliced
condition at the same step draw exactly the same action-head noise, so any difference is the CoT's.
"""

from __future__ import annotations

import zlib

import numpy as np

STREAMS = ("simulator", "cot", "action", "condition", "labeler")


def stream_id(purpose: str) -> int:
    """A stable integer for a purpose name (CRC32, the same on every machine and Python version)."""
    return zlib.crc32(purpose.encode("utf-8"))


def step_rng(seed: int, step: int, purpose: str, scope: str = "") -> np.random.Generator:
    """The generator for one purpose at one step of the episode with ``seed``.

    ``scope`` names the episode's scenario (``Observation.scenario_id``): without it, every scenario run
    with seed 0 would draw the same numbers at the same step, and a sweep over scenarios would count one
    set of draws many times over.
    """
    if seed < 0 or step < 0:
        raise ValueError(f"seed and step must be non-negative, got seed={seed}, step={step}")
    entropy = [seed, step, stream_id(purpose)] + ([stream_id(scope)] if scope else [])
    return np.random.default_rng(entropy)


def episode_rng(seed: int, purpose: str) -> np.random.Generator:
    """The generator for one purpose over a whole episode (e.g. the simulator's scenario variation)."""
    if seed < 0:
        raise ValueError(f"seed must be non-negative, got {seed}")
    return np.random.default_rng([seed, stream_id(purpose)])
