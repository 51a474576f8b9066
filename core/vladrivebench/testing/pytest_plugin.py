"""The ``vladrivebench`` pytest plugin: fixtures for testing any VLADriveBench plugin.

Registered through the ``pytest11`` entry point of the core distribution, so every test session in an
environment with ``vladrivebench`` installed has these fixtures, with nothing to import or configure.
Importing this module imports only pytest and the standard library; the fixtures import what they need
when a test asks for them, and none of them needs any plugin to be installed.

Fixtures:

``vdb_registry``
    A factory ``vdb_registry(*plugins, core=False, entry_points=False)`` making a registry of exactly
    ``plugins`` (modules, or ``(name, module)`` pairs) the process-wide one until the test ends.
``vdb_observations`` / ``vdb_observation``
    A factory ``vdb_observations(count=3, height=224, width=448, seed=0)`` of consecutive observations of
    a pedestrian approach whose camera images are large enough for a real vision encoder (rendered by the
    default simulator the installed plugins declare, else synthesised deterministically); and its first one.
``vdb_label_items``
    CoTs (sentences and slots, with and without a critical feature) with the context a labeler reads.
``vdb_episode_dir`` / ``vdb_dataset``
    A tiny directory of logged episodes (two models × two seeds, 60 steps each), labelled with the simple
    keyword labeler; and that directory loaded as the analysis dataset a metric's ``compute`` receives.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import pytest


@pytest.fixture
def vdb_registry():
    """A factory of isolated registries: ``vdb_registry(plugin_module, ..., core=True)`` returns the
    :class:`~vladrivebench.testing.Registry`, process-wide until the test ends (then the previous one)."""
    from vladrivebench.testing import isolated_registry

    with contextlib.ExitStack() as stack:
        def make(*plugins: Any, core: bool = False, entry_points: bool = False, strict: bool = False):
            named = tuple(_named(p) for p in plugins)
            return stack.enter_context(isolated_registry(*named, core=core, entry_points=entry_points, strict=strict))

        yield make


def _named(plugin: Any) -> tuple[str, object]:
    if isinstance(plugin, tuple):
        return plugin
    return (getattr(plugin, "__name__", type(plugin).__name__), plugin)


_OBSERVATIONS: dict[tuple, list] = {}


@pytest.fixture(scope="session")
def vdb_observations():
    """A factory ``vdb_observations(count=3, *, height=224, width=448, seed=0, render=True, simulator=None)``
    of consecutive :class:`~vladrivebench.Observation` s (rendered by ``simulator``, by default the installed
    default simulator, else synthesised); results are cached for the session, so treat them as read-only."""
    from vladrivebench.testing.samples import observations

    def make(count: int = 3, *, height: int = 224, width: int = 448, seed: int = 0, render: bool = True,
             simulator: str | None = None) -> list:
        key = (count, height, width, seed, render, simulator)
        if key not in _OBSERVATIONS:
            _OBSERVATIONS[key] = observations(count, height=height, width=width, seed=seed, render=render,
                                              simulator=simulator)
        return list(_OBSERVATIONS[key])

    return make


@pytest.fixture(scope="session")
def vdb_observation(vdb_observations):
    """One realistic observation: 448 × 224 camera image, a pedestrian in the lane ahead."""
    return vdb_observations(1)[0]


@pytest.fixture(scope="session")
def vdb_label_items():
    """:func:`vladrivebench.testing.sample_label_items`: CoTs with the ground-truth context of their step."""
    from vladrivebench.testing.samples import label_items

    return label_items()


@pytest.fixture(scope="session")
def vdb_episode_dir(tmp_path_factory) -> Path:
    """A tiny labelled episode directory (read-only: copy it before writing into it)."""
    from vladrivebench.testing.samples import write_episode_dir

    return write_episode_dir(tmp_path_factory.mktemp("vdb_episodes"))


@pytest.fixture
def vdb_dataset(vdb_episode_dir):
    """:data:`vdb_episode_dir` loaded as an :class:`~vladrivebench.metrics.AnalysisDataset` (fresh per test)."""
    from vladrivebench.testing import load_dataset

    return load_dataset(vdb_episode_dir)
