"""Testing plugins: isolated registries, the CLI in-process, single episodes and small sweeps.

Everything a plugin's tests need without importing the core's internals. (Conformance checks for each kind
of plugin and the pytest fixtures of the ``vladrivebench`` pytest plugin live here too.)

Example (pytest)::

    from vladrivebench.testing import isolated_registry

    def test_my_model_registers():
        with isolated_registry(("mine", my_plugin_module)) as registry:
            assert "my-vla" in registry.names("model")
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from vladrivebench._analysis.dataset import label_items, load_dataset, read_directory
from vladrivebench._analysis.report import compute_all
from vladrivebench._engine.registry import Registry, check_options, get_registry, set_registry
from vladrivebench._engine.runner import EpisodeFailure, EpisodeResult, own_cot_policy, run_episode
from vladrivebench._engine.sweep import ComponentSpec, RegistrySpec, RunConfig, make_jobs, run_sweep
from vladrivebench._logs.episodes import EpisodeWriter, find_episodes, read_episode

__all__ = [
    "isolated_registry", "registered", "core_plugin", "Registry", "check_options", "get_registry", "run_cli",
    "build",
    "run_episode", "own_cot_policy", "EpisodeFailure", "EpisodeResult",
    "ComponentSpec", "RegistrySpec", "RunConfig", "make_jobs", "run_sweep",
    "EpisodeWriter", "find_episodes", "read_episode", "label_items", "load_dataset", "read_directory", "compute_all",
]


def core_plugin() -> tuple[str, object]:
    """The core's own plugin (controllers, executors, conditions, the scenario suite, built-in metrics),
    as a ``(name, module)`` pair for :func:`isolated_registry`."""
    from vladrivebench import _builtins

    return ("core", _builtins)


def run_cli(args: list[str]) -> int:
    """Run ``vdb ARGS`` in this process and return its exit status (0 on success, 2 for a user error)."""
    from vladrivebench._cli.main import main

    return main(list(args))


def build(kind: str, name: str, **options):
    """Build the registered component ``kind``/``name`` (e.g. ``build("controller", "pid")``) from the
    process-wide registry, checking ``options`` against its factory as the CLI does."""
    return get_registry().create(kind, name, options)


@contextlib.contextmanager
def isolated_registry(*plugins: tuple[str, object], entry_points: bool = False,
                      strict: bool = False, core: bool = False) -> Iterator[Registry]:
    """Make a registry of exactly ``plugins`` the process-wide one for the duration of the block.

    With ``core=True`` the core's own plugin (:func:`core_plugin`) comes first.
    With ``entry_points=True`` the installed plugins are loaded too and ``plugins`` are added on top.
    The previous registry is restored afterwards, so one test's plugins never leak into another's.
    """
    if core:
        plugins = (core_plugin(), *plugins)
    registry = Registry(plugins, entry_points=entry_points, strict=strict)
    previous = set_registry(registry)
    try:
        yield registry
    finally:
        set_registry(previous)


@contextlib.contextmanager
def registered(name: str, plugin: object) -> Iterator[Registry]:
    """The installed plugins plus ``plugin`` (registered as ``name``), for one block."""
    with isolated_registry((name, plugin), entry_points=True) as registry:
        yield registry
