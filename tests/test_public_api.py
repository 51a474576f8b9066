"""Plugins and examples use only the declared public API: names in ``vladrivebench.__all__`` or in the
``__all__`` of a public subpackage (``PUBLIC_SUBPACKAGES``). Everything else is private to the core."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest
import vladrivebench

ROOT = Path(__file__).resolve().parents[1]
PLUGIN_TREES = [ROOT / "plugins", ROOT / "examples"]


def public_names() -> dict[str, set[str]]:
    """Module → the names a plugin may import from it."""
    names = {"vladrivebench": set(vladrivebench.__all__)}
    for module in vladrivebench.PUBLIC_SUBPACKAGES:
        names[module] = set(importlib.import_module(module).__all__)
    return names


def plugin_modules() -> list[Path]:
    return sorted(p for tree in PLUGIN_TREES for p in tree.rglob("*.py") if "build" not in p.parts)


def private_imports(path: Path, allowed: dict[str, set[str]]) -> list[str]:
    """Every ``import vladrivebench…`` / ``from vladrivebench… import`` in ``path`` that is not public."""
    problems = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module.split(".")[0] != "vladrivebench":
                continue
            if node.module not in allowed:
                problems.append(f"{path.relative_to(ROOT)}:{node.lineno}: module {node.module}")
                continue
            for alias in node.names:
                if alias.name not in allowed[node.module]:
                    problems.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.module}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "vladrivebench" and alias.name not in allowed:
                    problems.append(f"{path.relative_to(ROOT)}:{node.lineno}: module {alias.name}")
    return problems


def test_plugins_and_examples_import_only_public_names():
    allowed = public_names()
    problems = [p for path in plugin_modules() for p in private_imports(path, allowed)]
    assert not problems, f"{len(problems)} private imports:\n" + "\n".join(problems)


def test_the_checker_catches_a_private_import(tmp_path):
    module = tmp_path / "bad.py"
    module.write_text("from vladrivebench._engine.runner import run_episode\n"
                      "from vladrivebench import hookimpl, _builtins\nimport vladrivebench._logs\n")
    global ROOT
    saved, ROOT = ROOT, tmp_path
    try:
        found = private_imports(module, public_names())
    finally:
        ROOT = saved
    assert found == ["bad.py:1: module vladrivebench._engine.runner", "bad.py:2: vladrivebench._builtins",
                     "bad.py:3: module vladrivebench._logs"]


@pytest.mark.parametrize("module", ["vladrivebench", *vladrivebench.PUBLIC_SUBPACKAGES])
def test_every_public_name_exists_and_has_a_docstring(module):
    mod = importlib.import_module(module)
    assert mod.__doc__, f"{module} has no docstring"
    for name in mod.__all__:
        value = getattr(mod, name)  # raises when __all__ names something missing
        if isinstance(value, type) or callable(value) and getattr(value, "__module__", "").startswith("vladrivebench"):
            assert value.__doc__, f"{module}.{name} has no docstring"
