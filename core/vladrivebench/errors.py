"""User-facing errors.

Every mistake a user can make (a wrong name, a malformed file, a bad option) is raised as a
:class:`VdbError`; the CLI prints its message as one line and exits with status 2, without a traceback.
Messages say what is wrong, where, and what is expected.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


class VdbError(Exception):
    """A user error: printed as one line by the CLI, exit status 2."""

    exit_code = 2


class UnknownNameError(VdbError):
    """A plugin, model, simulator, scenario, condition … name that nobody registered."""

    def __init__(self, kind: str, name: str, available: Iterable[str]):
        self.kind, self.name = kind, name
        self.available = sorted(available)
        super().__init__(unknown_name_message(kind, name, self.available))


class PluginLoadError(VdbError):
    """A plugin failed to load or register while strict loading was asked for."""


class ConfigError(VdbError):
    """A malformed option, configuration file or command-line value."""


class ScenarioError(VdbError):
    """A scenario file that is missing, malformed, or asks for something a simulator cannot do."""


class ConditionError(ConfigError):
    """A condition that cannot be resolved or that the model's format or tokenizer cannot take."""


class ModelOutputError(VdbError):
    """A model returned something the benchmark cannot use (NaN, wrong shape, wrong type)."""


class LogError(VdbError):
    """An episode log that is missing, corrupt, truncated or written by an incompatible version."""


def unknown_name_message(kind: str, name: str, available: list[str]) -> str:
    """``unknown model 'kvv': did you mean 'kv'? (available: kv, qa, scripted)``"""
    close = difflib.get_close_matches(name, available, n=3, cutoff=0.6)
    hint = f" did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    listing = ", ".join(available) if available else "none installed"
    return f"unknown {kind} {name!r}:{hint} (available: {listing})"
