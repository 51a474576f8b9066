"""Helpers for testing plugins and the core without depending on what is installed on the machine.

Example (pytest)::

    from vladrivebench.testing import isolated_registry

    def test_my_model_registers():
        with isolated_registry(("mine", my_plugin_module)) as registry:
            assert "my-vla" in registry.names("model")
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from .plugins import Registry, set_registry


@contextlib.contextmanager
def isolated_registry(*plugins: tuple[str, object], entry_points: bool = False,
                      strict: bool = False) -> Iterator[Registry]:
    """Make a registry of exactly ``plugins`` the process-wide one for the duration of the block.

    With ``entry_points=True`` the installed plugins are loaded too and ``plugins`` are added on top.
    The previous registry is restored afterwards, so one test's plugins never leak into another's.
    """
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
