"""The example adapter works the way CONTRIBUTING.md says a third-party plugin does.

It is installed with pip into a temporary directory during the test and driven through the real CLI.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

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


def test_selfsplice_is_exact_and_the_cot_drives_the_action():
    sys.path.insert(0, str(EXAMPLE))
    try:
        from vdb_model_pixelvla.model import PixelVLA
    finally:
        sys.path.remove(str(EXAMPLE))
    from vladrivebench import EgoState, GroundTruth, Observation

    model = PixelVLA(cruise_speed=6.0, red_threshold=0.002, obstacle_threshold=0.004, coupling=1.0)
    image = np.full((80, 160, 3), 72, np.uint8)
    obs = Observation(step=0, time=0.0, image=image, ego=EgoState(0, 0, 0, 5.0), command="follow_lane",
                      ground_truth=GroundTruth(step=0, time=0.0))
    own = model.generate_cot(obs, np.random.default_rng(0))
    spliced = model.splice_cot(obs, own.text, np.random.default_rng(0))
    assert model.state_digest(own) == model.state_digest(spliced)
    go = model.decode_action(obs, own, np.random.default_rng(1))
    assert np.array_equal(go.xy, model.decode_action(obs, spliced, np.random.default_rng(1)).xy)
    stop = model.splice_cot(obs, "Stop for the pedestrian in the lane because it is blocking the lane.", None)
    assert model.decode_action(obs, stop, np.random.default_rng(1)).forward_displacement(2.0) < \
        go.forward_displacement(2.0)
