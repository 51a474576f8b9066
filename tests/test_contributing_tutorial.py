"""The tutorial of CONTRIBUTING.md builds a working model plugin: write its files, register it, run it."""

from __future__ import annotations

import importlib
import re
import sys
from pathlib import Path

import pytest
from vladrivebench.testing import core_plugin, isolated_registry, read_episode, run_cli

ROOT = Path(__file__).resolve().parents[1]
FILE_BLOCK = re.compile(r"<!-- file: (?P<path>[^ ]+) -->\n```\w*\n(?P<body>.*?)```", re.S)

pytest.importorskip("vdb_sim_kinematic", reason="the tutorial drives the kinematic simulator")


def tutorial_files() -> dict[str, str]:
    text = (ROOT / "CONTRIBUTING.md").read_text(encoding="utf-8")
    return {m["path"]: m["body"] for m in FILE_BLOCK.finditer(text)}


@pytest.fixture()
def hello_plugin(tmp_path, monkeypatch):
    files = tutorial_files()
    assert {"vdb-model-hello/pyproject.toml", "vdb-model-hello/vdb_model_hello/plugin.py",
            "vdb-model-hello/vdb_model_hello/model.py"} <= set(files)
    for path, body in files.items():
        target = tmp_path / path
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(body, encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path / "vdb-model-hello"))
    for name in [m for m in sys.modules if m.startswith("vdb_model_hello")]:
        del sys.modules[name]
    yield importlib.import_module("vdb_model_hello.plugin")


def test_the_tutorial_plugin_runs_labels_and_passes_the_selfsplice_gate(hello_plugin, tmp_path, capsys):
    import vdb_sim_kinematic.plugin as kinematic

    with isolated_registry(core_plugin(), ("kinematic", kinematic), ("hello", hello_plugin)) as registry:
        assert "hello" in registry.names("model")
        out = tmp_path / "run"
        assert run_cli(["run", "--model", "hello", "--scenarios", "TL.1-red", "--seeds", "1", "--out", str(out),
                        "--quiet"]) == 0
        episode = read_episode(next((out / "episodes").glob("*.mcap")))
        texts = {step.cot["text"] if isinstance(step.cot, dict) else step.cot.text for step in episode.steps}
        assert "Stop for the red light ahead." in texts  # it sees the red lamp
        gate = tmp_path / "ol"
        assert run_cli(["intervene", "--model", "hello", "--route", "E.1", "--mode", "open-loop", "--seeds", "2",
                        "--out", str(gate), "--quiet"]) == 0
    assert "INVALID RUN" not in capsys.readouterr().err


def test_the_tutorial_plugin_refuses_a_bad_option_in_one_line(hello_plugin, tmp_path, capsys):
    import vdb_sim_kinematic.plugin as kinematic

    with isolated_registry(core_plugin(), ("kinematic", kinematic), ("hello", hello_plugin)):
        code = run_cli(["run", "--model", "hello", "--model-opt", "cruise_speed=-1", "--scenarios", "E.1",
                        "--seeds", "1", "--out", str(tmp_path / "x"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == ["vdb: error: model 'hello': option 'cruise_speed' must be > 0 m/s, got -1"]


def test_the_tutorial_plugin_passes_its_own_conformance_test(hello_plugin, tmp_path):
    import os
    import subprocess

    folder = tmp_path / "vdb-model-hello"
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(folder / "tests")],
                            capture_output=True, text=True, timeout=600, cwd=folder,
                            env={**os.environ, "PYTHONPATH": str(folder)})
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 passed" in result.stdout
