"""Registration is light: registering the ``sumo`` simulator (and ``vdb list-plugins``) never imports libsumo."""

from __future__ import annotations

import subprocess
import sys

import pytest
import vdb_sim_sumo.plugin
from vladrivebench import ConfigError
from vladrivebench.testing import Registry, check_options

HEAVY = ("libsumo", "sumolib", "traci", "torch", "transformers")


def imported_after(code: str) -> list[str]:
    probe = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    return [m for m in done.stdout.strip().splitlines()[-1].split(",") if m] if done.stdout.strip() else []


def test_importing_the_plugin_imports_nothing_heavy():
    assert imported_after("import vdb_sim_sumo.plugin") == []


def test_vdb_list_plugins_does_not_import_libsumo():
    heavy = imported_after("from vladrivebench.testing import run_cli\nrun_cli(['list-plugins'])")
    assert "libsumo" not in heavy and "sumolib" not in heavy


def test_the_simulator_registers_with_its_options():
    registry = Registry([("sumo", vdb_sim_sumo.plugin)], entry_points=False)
    assert registry.names("simulator") == ["sumo"]
    factory = registry.get("simulator", "sumo").factory
    check_options("simulator", "sumo", factory, {"background_vehicles_per_hour": 600.0, "net_file": "a.net.xml",
                                                  "route": "a,b", "pedestrians": "sumo"})
    with pytest.raises(ConfigError):
        check_options("simulator", "sumo", factory, {"vehicles_per_hour": 600.0})
