"""Defaults come from what plugins declare (``register_defaults``); the core names no plugin component."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import vladrivebench
from vladrivebench import ConfigError
from vladrivebench.testing import Registry, core_plugin

CORE = Path(vladrivebench.__file__).parent


class SimPlugin:
    """A plugin registering one simulator and declaring it the default with a given priority."""

    def __init__(self, name: str, priority: int | None, declare: str | None = None):
        self.name, self.priority, self.declare = name, priority, declare or name

    @vladrivebench.hookimpl
    def register_simulators(self, register):
        register(self.name, lambda: None, description="fake")

    @vladrivebench.hookimpl
    def register_defaults(self, register):
        if self.priority is not None:
            register("simulator", self.declare, priority=self.priority)


def registry_of(*plugins: SimPlugin) -> Registry:
    return Registry([core_plugin(), *((p.name, p) for p in plugins)], entry_points=False)


def test_the_highest_priority_wins_whatever_the_plugin_order():
    for order in ((SimPlugin("a", 1), SimPlugin("b", 5)), (SimPlugin("b", 5), SimPlugin("a", 1))):
        chosen = registry_of(*order).default("simulator", "--sim")
        assert (chosen.name, chosen.priority, chosen.plugin) == ("b", 5, "b")


def test_a_tie_at_the_top_is_refused_naming_both():
    with pytest.raises(ConfigError) as err:
        registry_of(SimPlugin("a", 3), SimPlugin("b", 3), SimPlugin("c", 1)).default("simulator", "--sim")
    message = str(err.value)
    assert "'a'" in message and "'b'" in message and "'c'" not in message and "--sim" in message
    assert "\n" not in message


def test_no_declaration_says_how_to_choose():
    with pytest.raises(ConfigError, match=r"no installed plugin declares a default simulator: choose one with "
                                          r"--sim \(available: a\)"):
        registry_of(SimPlugin("a", None)).default("simulator", "--sim")


def test_a_plugin_may_only_declare_its_own_component():
    registry = registry_of(SimPlugin("a", None), SimPlugin("b", 1, declare="a"))
    info = next(p for p in registry.plugins if p.name == "b")
    assert info.status == "error" and "not a simulator this plugin registers" in info.error
    assert "b" not in registry.names("simulator")  # a failing plugin registers nothing


def test_the_installed_plugins_declare_the_documented_defaults():
    registry = Registry()
    assert registry.default("simulator", "--sim").name == "kinematic"
    assert registry.default("labeler", "--labeler").name == "lexicon"
    demo = {d.name for d in registry.default_declarations("demo")}
    assert "scripted" in demo


def _code_strings(path: Path) -> list[tuple[int, str]]:
    """String literals of a module that are not docstrings (docstrings may name examples)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings]


def test_the_core_names_no_component_a_plugin_owns():
    registry = Registry()
    core_owned = {(c.kind, c.name) for kind in ("model", "simulator", "labeler", "executor", "controller")
                  for c in registry.components(kind) if c.plugin == "core"}
    plugin_owned = {c.name for kind in ("model", "simulator", "labeler", "executor", "controller")
                    for c in registry.components(kind) if c.plugin != "core"} - {n for _, n in core_owned}
    assert {"kinematic", "lexicon", "scripted"} <= plugin_owned  # the check has something to find
    from vladrivebench.world import RIG_PRESETS

    plugin_owned -= set(RIG_PRESETS)  # camera-rig presets are the core's vocabulary (a layout, not the model)
    found = [f"{path.relative_to(CORE)}:{line}: {value!r}" for path in sorted(CORE.rglob("*.py"))
             for line, value in _code_strings(path) if value in plugin_owned]
    assert not found, "the core names plugin components:\n" + "\n".join(found)
