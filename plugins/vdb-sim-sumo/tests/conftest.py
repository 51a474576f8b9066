"""Fixtures for the SUMO simulator's tests.

libsumo holds one simulation per process, so every simulator a test makes is closed when the test ends
(``sumo_sim``). Built networks go to one cache per test session (or ``$VDB_SUMO_CACHE`` when set, to reuse
them across sessions), never to the user's own cache.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def net_cache(tmp_path_factory) -> str:
    return os.environ.get("VDB_SUMO_CACHE") or str(tmp_path_factory.mktemp("sumo-nets"))


@pytest.fixture
def sumo_sim(net_cache):
    """``sumo_sim(**options)`` builds a SUMO simulator (no rendering unless asked); all are closed after."""
    from vdb_sim_sumo.plugin import make_simulator

    made = []

    def make(**options):
        options.setdefault("render", False)
        options.setdefault("cache_dir", net_cache)
        sim = make_simulator(**options)
        made.append(sim)
        return sim

    yield make
    for sim in made:
        sim.close()
