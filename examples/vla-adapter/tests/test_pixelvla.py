"""The example adapter works the way CONTRIBUTING.md says a third-party plugin does.

It is installed with pip into a temporary directory during the test and driven through the real CLI; the
model itself is checked with the conformance kit of ``vladrivebench.testing`` and its pytest fixtures.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from vdb_model_pixelvla import plugin
from vdb_model_pixelvla.model import PixelVLA
from vladrivebench.testing import check_bad_options, check_model

EXAMPLE = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> str:
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--disable-pip-version-check", "--target", str(target), str(EXAMPLE)],
                   check=True, capture_output=True)
    return str(target)


def vdb(args, site):
    return subprocess.run([sys.executable, "-m", "vladrivebench", *args], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=site), timeout=300)


def test_installed_adapter_is_listed(site):
    result = vdb(["list-plugins", "--json"], site)
    listing = {p["name"]: p for p in json.loads(result.stdout)}
    assert listing["pixelvla"]["status"] == "ok"
    assert listing["pixelvla"]["registered"] == {"model": ["pixel-vla"]}
    assert listing["pixelvla"]["distribution"] == "vdb-model-pixelvla"


def test_adapter_drives_a_scenario_and_stops_for_the_blocking_car(site, tmp_path):
    result = vdb(["run", "--model", "pixel-vla", "--scenarios", "C.1", "--seeds", "1", "--out",
                  str(tmp_path / "run"), "--quiet", "--json"], site)
    assert result.returncode == 0, result.stderr
    assert list((tmp_path / "run").rglob("*.mcap"))
    (row,) = json.loads(result.stdout)["scenarios"]
    assert (row["scenario"], row["collisions"], row["failed"]) == ("C.1", 0, 0)
    assert row["route_completion"] < 0.6  # it stopped behind the car instead of completing the route


def test_bad_option_is_one_line(site, tmp_path):
    result = vdb(["run", "--model", "pixel-vla", "--model-opt", "coupling=2", "--scenarios", "C.1",
                  "--seeds", "1", "--out", str(tmp_path / "bad")], site)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "coupling" in result.stderr


def test_the_adapter_conforms(vdb_registry, vdb_observations):
    """The conformance kit: protocol, selfsplice (digest and trajectory bit for bit), token limit."""
    registry = vdb_registry(("pixelvla", plugin))
    for options in ({}, {"coupling": 0.0}, {"red_threshold": 0.0}):
        check_model(registry.create("model", "pixel-vla", options), vdb_observations(5), name="pixel-vla")


def test_bad_options_are_one_line_errors_in_process(vdb_registry):
    registry = vdb_registry(("pixelvla", plugin))
    check_bad_options(lambda options: registry.create("model", "pixel-vla", options),
                      [{"coupling": 2.0}, {"coupling": -0.5}], name="pixel-vla")


def test_the_cot_drives_the_action(vdb_observation):
    model = PixelVLA(cruise_speed=6.0, red_threshold=0.002, obstacle_threshold=0.004, coupling=1.0)
    go = model.decode_action(vdb_observation, model.splice_cot(vdb_observation, "Maintain speed.", None),
                             np.random.default_rng(1))
    stop = model.splice_cot(vdb_observation, "Stop for the pedestrian in the lane because it is blocking the lane.", None)
    assert model.decode_action(vdb_observation, stop, np.random.default_rng(1)).forward_displacement(2.0) < \
        go.forward_displacement(2.0)
