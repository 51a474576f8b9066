"""Shared fakes of the core's tests, as fixtures.

The fake modules (``runner_fakes``, ``intervention_fakes``, ``analysis_episodes``) stay plain modules in
this folder because spawned worker processes and ``RegistrySpec`` import them *by name*; this conftest puts
the folder on ``sys.path`` once (pytest runs with ``--import-mode=importlib``, which does not), so a test
module may ``import runner_fakes as fakes`` at its top or take the module as a fixture.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

import pytest

TESTS = str(Path(__file__).resolve().parent)
if TESTS not in sys.path:
    sys.path.insert(0, TESTS)


@pytest.fixture(scope="session")
def runner_fakes() -> ModuleType:
    """Fake components of the episode loop and sweeps: an echo model, line simulators, a speed controller,
    fake scenarios and ``fake_registry()`` / ``vdb_main()``."""
    return importlib.import_module("runner_fakes")


@pytest.fixture(scope="session")
def intervention_fakes() -> ModuleType:
    """Fake components of intervention runs: a keyword model, a line simulator and ``fake_registry()``."""
    return importlib.import_module("intervention_fakes")


@pytest.fixture(scope="session")
def analysis_episodes() -> ModuleType:
    """Hand-written episode logs and fake labelers for the analysis, metric and report tests."""
    return importlib.import_module("analysis_episodes")


@pytest.fixture(scope="session")
def fx(analysis_episodes: ModuleType) -> ModuleType:
    """Short name of :func:`analysis_episodes` used throughout the metric and report tests."""
    return analysis_episodes
