"""Real distributions installed during the test run: a working third-party plugin and broken ones.

They are installed with pip into a temporary directory that only the subprocesses of this module see,
so nothing leaks into the machine's environment.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

PLUGINS = {
    "vdb-model-toy": ("toy", "vdb_model_toy", """
        import vladrivebench

        class Toy:
            pass

        def make_toy(speed: float = 1.0):
            return Toy()

        @vladrivebench.hookimpl
        def register_models(register):
            register("toy", make_toy, description="a third-party toy model")
    """),
    "vdb-broken-import": ("brokenimport", "vdb_broken_import", """
        raise ImportError("this plugin needs a package that is missing")
    """),
    "vdb-broken-hook": ("brokenhook", "vdb_broken_hook", """
        import vladrivebench

        @vladrivebench.hookimpl
        def register_model(register):  # misspelt on purpose: the hook is register_models
            register("never", object)
    """),
    "vdb-model-toy-clash": ("toyclash", "vdb_model_toy_clash", """
        import vladrivebench

        @vladrivebench.hookimpl
        def register_models(register):
            register("toy", object)
    """),
}


def write_distribution(root: Path, dist: str, ep_name: str, module: str, source: str) -> Path:
    folder = root / dist
    (folder / module).mkdir(parents=True)
    (folder / module / "__init__.py").write_text(textwrap.dedent(source))
    (folder / "pyproject.toml").write_text(textwrap.dedent(f"""
        [build-system]
        requires = ["setuptools>=68"]
        build-backend = "setuptools.build_meta"

        [project]
        name = "{dist}"
        version = "1.2.3"

        [project.entry-points.vladrivebench]
        {ep_name} = "{module}"
    """))
    return folder


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory) -> str:
    root = tmp_path_factory.mktemp("dists")
    target = tmp_path_factory.mktemp("site")
    folders = [str(write_distribution(root, dist, *spec)) for dist, spec in PLUGINS.items()]
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
         "--disable-pip-version-check", "--target", str(target), *folders],
        check=True, capture_output=True,
    )
    return str(target)


def vdb(args: list[str], plugin_path: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=plugin_path)
    env.pop("VDB_STRICT_PLUGINS", None)
    return subprocess.run([sys.executable, "-m", "vladrivebench._cli.main", *args],
                          capture_output=True, text=True, env=env, timeout=120)


def test_list_plugins_reports_each_plugin_and_isolates_failures(plugin_path):
    result = vdb(["list-plugins", "--json"], plugin_path)
    assert result.returncode == 0, result.stderr
    listing = {p["name"]: p for p in json.loads(result.stdout)}
    toy = listing["toy"]
    assert (toy["status"], toy["distribution"], toy["version"]) == ("ok", "vdb-model-toy", "1.2.3")
    assert toy["registered"] == {"model": ["toy"]}
    assert listing["brokenimport"]["status"] == "error"
    assert "ImportError: this plugin needs a package that is missing" in listing["brokenimport"]["error"]
    assert listing["brokenhook"]["status"] == "error"
    assert "register_model" in listing["brokenhook"]["error"]
    assert listing["toyclash"]["status"] == "error"
    assert "'toy' is already registered by plugin 'toy'" in listing["toyclash"]["error"]
    assert listing["core"]["status"] == "ok"


def test_text_listing_names_kind_distribution_version_status(plugin_path):
    result = vdb(["list-plugins"], plugin_path)
    assert result.returncode == 0
    assert "toy  [ok]  kinds: model  (vdb-model-toy 1.2.3)" in result.stdout
    assert "brokenimport  [error]" in result.stdout


def test_strict_switch_makes_a_broken_plugin_fatal_in_one_line(plugin_path):
    result = vdb(["--strict-plugins", "list-plugins"], plugin_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdb: error: plugin ")
    assert "Traceback" not in result.stderr


def test_disabling_a_plugin_by_name(plugin_path):
    env_path = plugin_path
    result = subprocess.run(
        [sys.executable, "-m", "vladrivebench._cli.main", "list-plugins", "--json"],
        capture_output=True, text=True, timeout=120,
        env=dict(os.environ, PYTHONPATH=env_path, VDB_DISABLE_PLUGINS="brokenimport"),
    )
    listing = {p["name"]: p for p in json.loads(result.stdout)}
    assert listing["brokenimport"]["status"] == "disabled"


def test_every_plugin_and_example_declares_the_core_version_range_it_works_with():
    import re
    from pathlib import Path

    import vladrivebench
    from packaging.requirements import Requirement
    from packaging.version import Version

    root = Path(__file__).resolve().parents[1]
    for pyproject in sorted([*root.glob("plugins/*/pyproject.toml"), *root.glob("examples/*/pyproject.toml")]):
        text = pyproject.read_text(encoding="utf-8")
        found = [Requirement(r) for r in re.findall(r'"(vladrivebench[^"]*)"', text)]
        core = [r for r in found if r.name == "vladrivebench"]
        assert core, f"{pyproject} does not depend on vladrivebench"
        spec = core[0].specifier
        assert any(s.operator == "<" for s in spec), f"{pyproject}: no upper bound on the core ({spec})"
        assert Version(vladrivebench.__version__) in spec, f"{pyproject}: {spec} excludes the core's version"
