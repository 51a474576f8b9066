"""Docs held by tests (as datasette does): every hook and every ``vdb`` command has a section in
CONTRIBUTING.md, and every hook is implemented by at least one test."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import pytest
from vladrivebench import hookspecs

ROOT = Path(__file__).resolve().parents[1]
CONTRIBUTING = (ROOT / "CONTRIBUTING.md").read_text(encoding="utf-8")
HEADINGS = [line for line in CONTRIBUTING.splitlines() if line.startswith("#")]
HOOKS = sorted(name for name, fn in inspect.getmembers(hookspecs, inspect.isfunction)
               if hasattr(fn, "vladrivebench_spec"))
TEST_TREES = [ROOT / "tests", *sorted((ROOT / "plugins").glob("*/tests")), *sorted((ROOT / "examples").glob("*/tests"))]


def core_commands() -> list[str]:
    from vladrivebench._cli.main import cli

    return sorted(cli.commands)


def test_the_hook_list_is_the_hookspec_module():
    assert {"register_models", "register_simulators", "register_labelers", "register_metrics",
            "register_commands", "register_defaults"} <= set(HOOKS)


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_has_a_section(hook):
    assert any(f"`{hook}`" in heading for heading in HEADINGS), f"CONTRIBUTING.md has no heading for `{hook}`"


@pytest.mark.parametrize("command", core_commands())
def test_every_command_has_a_section(command):
    assert any(f"`vdb {command}`" in heading for heading in HEADINGS), \
        f"CONTRIBUTING.md has no heading for `vdb {command}`"


def _implemented_hooks(path: Path) -> set[str]:
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except SyntaxError:
        return set()
    return {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef) and node.name in HOOKS
            and any("hookimpl" in ast.unparse(d) for d in node.decorator_list)}


@pytest.mark.parametrize("hook", HOOKS)
def test_every_hook_is_implemented_by_a_test(hook):
    tested = set().union(*(_implemented_hooks(p) for tree in TEST_TREES for p in tree.rglob("*.py")))
    assert hook in tested, f"no test implements the hook {hook} (write a test plugin that uses it)"
