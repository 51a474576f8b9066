"""The truncation paradigm end to end with the scripted model, the way a third party uses it.

In process (the example registered on top of the installed plugins) for the numbers and the errors, and
installed with pip into a temporary directory and driven through the real `vdb` for the entry point.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from vdb_paradigm_truncation import plugin
from vdb_paradigm_truncation.paradigm import Truncation, parse_levels
from vladrivebench import ConfigError
from vladrivebench.testing import find_episodes, read_episode, registered, run_cli

pytest.importorskip("vdb_model_scripted", reason="the scripted model plugin is not installed")
pytest.importorskip("vdb_sim_kinematic", reason="the kinematic simulator plugin is not installed")

EXAMPLE = Path(__file__).resolve().parents[1]
RUN = ["intervene", "--model", "scripted", "--model-opt", "alpha=1", "--route", "P.1", "--mode", "truncation",
       "--seeds", "2", "--quiet"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("truncation") / "run"
    with registered("truncation", plugin):
        assert run_cli([*RUN, "--paradigm-opt", "levels=0,50,100", "--out", str(out)]) == 0
    return out


def test_results_come_from_the_logs_and_the_whole_cot_changes_nothing(run_dir):
    results = json.loads((run_dir / "intervention.json").read_text())
    assert results["valid"] and results["mode"] == "truncation"
    assert results["paradigm_options"] == {"levels": "0,50,100"}
    block = results["truncation"]
    assert block["levels"] == [0.0, 50.0, 100.0] and block["unit"] == "words"
    episodes = {read_episode(p).seed: read_episode(p) for p in find_episodes(run_dir)}
    assert sorted(episodes) == [0, 1]
    rows = {r["level"]: r for r in block["routes"]["P.1"]["2"]}
    steps = sum(len(e.steps) for e in episodes.values())
    assert all(r["n"] == steps and r["n_seeds"] == 2 for r in rows.values())
    # recompute k = 0 independently from the logged displacements
    deltas = {seed: [s.extras["intervention"]["displacement"]["2"]["0"] - s.extras["intervention"]["displacement"]["2"]["own"]
                     for s in e.steps] for seed, e in episodes.items()}
    every = np.abs(np.concatenate([deltas[0], deltas[1]]))
    assert rows[0.0]["mean_abs"] == pytest.approx(float(np.mean(every)))
    assert rows[0.0]["pct_changed"] == pytest.approx(100 * float(np.mean(every > results["threshold"])))
    assert rows[0.0]["abs_seed_means"] == pytest.approx([float(np.mean(np.abs(deltas[s]))) for s in (0, 1)])
    assert rows[0.0]["kept"] == 0.0 and rows[100.0]["kept"] == 1.0 and 0.3 < rows[50.0]["kept"] <= 0.5
    # the scripted model reads its decision from the CoT: without it the action changes, spliced whole never
    assert rows[0.0]["pct_changed"] > 5 and rows[0.0]["mean_abs"] > 0.1
    assert rows[100.0]["mean_abs"] == 0.0 and rows[100.0]["pct_changed"] == 0.0
    assert rows[100.0]["p_holm"] is None and not rows[100.0]["significant"]


def test_the_report_shows_one_table_per_horizon_with_counts(run_dir, tmp_path):
    with registered("truncation", plugin):
        assert run_cli(["report", str(run_dir), "--format", "md", "--out", str(tmp_path / "r.md")]) == 0
    text = (tmp_path / "r.md").read_text()
    assert "CoT truncation: action change at 2 s, route P.1" in text and "at 3 s, route P.1" in text
    assert "| 100 % |" in text and "(control)" in text


@pytest.mark.parametrize("args, fragment", [
    (["--paradigm-opt", "levels=0,150"], "--paradigm-opt levels: '150' is not a percentage from 0 to 100"),
    (["--paradigm-opt", "unit=chars"], "--paradigm-opt unit: 'chars' is not known"),
    (["--paradigm-opt", "depth=2"], "paradigm 'truncation' does not take option 'depth'"),
    (["--conditions", "car"], "paradigm 'truncation' takes no conditions"),
])
def test_bad_options_are_one_line_and_write_nothing(args, fragment, tmp_path, capsys):
    with registered("truncation", plugin):
        code = run_cli([*RUN, "--out", str(tmp_path / "x"), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and fragment in err[0], err
    assert not (tmp_path / "x").exists()


def test_levels_parse_from_text_lists_and_numbers():
    assert parse_levels("100, 0,50") == (0.0, 50.0, 100.0)
    assert parse_levels([25, 25.0, 75]) == (25.0, 75.0) and parse_levels(50) == (50.0,)
    for bad in ("", "a,b", [True], "-1"):
        with pytest.raises(ConfigError):
            parse_levels(bad)
    assert Truncation(unit="tokens").levels == (0.0, 25.0, 50.0, 75.0, 100.0)


def test_installed_it_is_a_paradigm_of_vdb_intervene(tmp_path):
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--disable-pip-version-check", "--target", str(target), str(EXAMPLE)],
                   check=True, capture_output=True)
    env = dict(os.environ, PYTHONPATH=str(target))

    def vdb(*args):
        return subprocess.run([sys.executable, "-m", "vladrivebench", *args], capture_output=True, text=True,
                              env=env, timeout=600)

    listing = {p["name"]: p for p in json.loads(vdb("list-plugins", "--json").stdout)}
    assert listing["truncation"]["registered"] == {"paradigm": ["truncation"]}
    assert listing["truncation"]["distribution"] == "vdb-paradigm-truncation"
    assert "truncation" in vdb("intervene", "--help").stdout
    out = tmp_path / "run"
    result = vdb("intervene", "--model", "scripted", "--route", "E.1", "--mode", "truncation", "--seeds", "2",
                 "--paradigm-opt", "levels=0,100", "--paradigm-opt", "unit=tokens", "--quiet", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "CoT truncation: action change at 2 s, route E.1" in result.stdout
    assert json.loads((out / "intervention.json").read_text())["truncation"]["unit"] == "tokens"
    report = vdb("report", str(out), "--format", "md", "--out", str(tmp_path / "r.md"))
    assert report.returncode == 0, report.stderr
    assert "CoT truncation" in (tmp_path / "r.md").read_text()
