"""Testing plugins: conformance checks, sample inputs, isolated registries, the CLI in-process, episodes.

Everything a plugin's tests need without importing the core's internals:

- **Conformance checks** (:mod:`vladrivebench.testing.conformance`), one per kind of plugin, each raising
  :class:`AssertionError` naming the plugin and what broke: :func:`check_model` (protocol, selfsplice
  digest and bit-identical trajectory under a pinned RNG, token limits), :func:`check_batched_model` (every
  row of a lockstep batch gets what it gets alone, per-episode memory included; selfsplice bit-exact within
  a batch), :func:`check_bad_options` (one-line
  :class:`~vladrivebench.VdbError` naming the option), :func:`check_simulator` (determinism and ground-truth
  invariants), :func:`check_labeler` (label values, ``label_batch`` order, version) and
  :func:`check_metric` (tables and plots whose every cell has a count).
- **Sample inputs** (:mod:`vladrivebench.testing.samples`): :func:`observations` (camera images of 224 pixels
  and more on the short side), :func:`label_items`, :func:`write_episode_dir` (a tiny labelled episode
  directory) and the simple :class:`KeywordLabeler`.
- **pytest fixtures** from the ``vladrivebench`` pytest plugin (registered through the ``pytest11`` entry
  point, so installing the core is enough): ``vdb_registry``, ``vdb_observation``, ``vdb_observations``,
  ``vdb_label_items``, ``vdb_episode_dir`` and ``vdb_dataset``.

Example (pytest)::

    from vladrivebench.testing import check_model, isolated_registry

    def test_my_model_registers():
        with isolated_registry(("mine", my_plugin_module)) as registry:
            assert "my-vla" in registry.names("model")

    def test_my_model_conforms(vdb_observations):
        check_model(MyModel(), vdb_observations(3), name="my-vla")

Importing this package is cheap (names are imported on first use), so the pytest plugin never slows down
or breaks a test session.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from vladrivebench._engine.registry import Registry

_LAZY = {
    "Registry": "vladrivebench._engine.registry",
    "check_options": "vladrivebench._engine.registry",
    "get_registry": "vladrivebench._engine.registry",
    "run_episode": "vladrivebench._engine.runner",
    "own_cot_policy": "vladrivebench._engine.runner",
    "EpisodeFailure": "vladrivebench._engine.runner",
    "EpisodeResult": "vladrivebench._engine.runner",
    "ComponentSpec": "vladrivebench._engine.sweep",
    "RegistrySpec": "vladrivebench._engine.sweep",
    "RunConfig": "vladrivebench._engine.sweep",
    "make_jobs": "vladrivebench._engine.sweep",
    "run_sweep": "vladrivebench._engine.sweep",
    "EpisodeWriter": "vladrivebench._logs.episodes",
    "find_episodes": "vladrivebench._logs.episodes",
    "read_episode": "vladrivebench._logs.episodes",
    "label_items": "vladrivebench._analysis.dataset",
    "load_dataset": "vladrivebench._analysis.dataset",
    "read_directory": "vladrivebench._analysis.dataset",
    "compute_all": "vladrivebench._analysis.report",
    "check_model": "vladrivebench.testing.conformance",
    "check_batched_model": "vladrivebench.testing.conformance",
    "check_bad_options": "vladrivebench.testing.conformance",
    "check_simulator": "vladrivebench.testing.conformance",
    "check_labeler": "vladrivebench.testing.conformance",
    "check_metric": "vladrivebench.testing.conformance",
    "DEFAULT_CONTROLS": "vladrivebench.testing.conformance",
    "observations": "vladrivebench.testing.samples",
    "synthetic_observation": "vladrivebench.testing.samples",
    "sample_label_items": "vladrivebench.testing.samples",
    "write_episode_dir": "vladrivebench.testing.samples",
    "KeywordLabeler": "vladrivebench.testing.samples",
}
_RENAMED = {"sample_label_items": "label_items"}

__all__ = [
    "isolated_registry", "registered", "core_plugin", "Registry", "check_options", "get_registry", "run_cli",
    "build",
    "run_episode", "own_cot_policy", "EpisodeFailure", "EpisodeResult",
    "ComponentSpec", "RegistrySpec", "RunConfig", "make_jobs", "run_sweep",
    "EpisodeWriter", "find_episodes", "read_episode", "label_items", "load_dataset", "read_directory", "compute_all",
    # conformance checks
    "check_model", "check_batched_model", "check_bad_options", "check_simulator", "check_labeler", "check_metric", "DEFAULT_CONTROLS",
    # sample inputs
    "observations", "synthetic_observation", "sample_label_items", "write_episode_dir", "KeywordLabeler",
]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), _RENAMED.get(name, name))
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


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
    from vladrivebench._engine.registry import get_registry

    return get_registry().create(kind, name, options)


@contextlib.contextmanager
def isolated_registry(*plugins: tuple[str, object], entry_points: bool = False,
                      strict: bool = False, core: bool = False) -> Iterator[Registry]:
    """Make a registry of exactly ``plugins`` the process-wide one for the duration of the block.

    With ``core=True`` the core's own plugin (:func:`core_plugin`) comes first.
    With ``entry_points=True`` the installed plugins are loaded too and ``plugins`` are added on top.
    The previous registry is restored afterwards, so one test's plugins never leak into another's.
    """
    from vladrivebench._engine.registry import Registry, set_registry

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
