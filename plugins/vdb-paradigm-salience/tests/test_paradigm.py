"""The salience paradigm end to end with the scripted model on a tiny grid, through the real `vdb`."""

from __future__ import annotations

import json
import os

import pytest
from vladrivebench.intervention import PAPER_TEXTS
from vladrivebench.testing import find_episodes, read_episode, run_cli

pytest.importorskip("vdb_model_scripted", reason="the scripted model plugin is not installed")
pytest.importorskip("vdb_sim_kinematic", reason="the kinematic simulator plugin is not installed")

GRID = ["--paradigm-opt", "kinds=pedestrian,car", "--paradigm-opt", "offsets=0", "--paradigm-opt",
        "distances=20,70", "--paradigm-opt", "sizes=1", "--paradigm-opt", "max_time=14"]
RUN = ["intervene", "--model", "scripted", "--route", "SAFE.centre-ped", "--mode", "salience", "--seeds", "2",
       "--quiet"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("salience") / "run"
    assert run_cli([*RUN, *GRID, "--out", str(out)]) == 0
    return out


def logs(run_dir):
    return {(e.scenario_id, e.seed, e.meta["intervention"]["condition"] or e.meta["intervention"]["role"]): e
            for e in map(read_episode, find_episodes(run_dir))}


def test_every_cell_runs_a_baseline_and_an_injected_episode_per_seed(run_dir):
    results = json.loads((run_dir / "intervention.json").read_text())
    block = results["salience"]
    assert results["valid"] and results["mode"] == "salience" and block["condition"] == "accel"
    assert [c["key"] for c in block["cells"]] == ["pedestrian_o0_d20_x1", "pedestrian_o0_d70_x1", "car_o0_d20_x1",
                                                  "car_o0_d70_x1"]
    episodes = logs(run_dir)
    assert len(episodes) == 4 * 2 * 2
    assert results["gate"]["steps_checked"] == 4 * 2  # the selfsplice gate at every baseline's onset
    assert all(e.steps[-1].time <= 14.0 + 1e-9 for e in episodes.values())


def test_before_onset_both_drive_alike_and_from_onset_the_paper_text_drives(run_dir):
    results = json.loads((run_dir / "intervention.json").read_text())
    text = results["definitions"]["accel"]["sentence"]
    assert "road ahead is clear" in text and "accel" in PAPER_TEXTS
    for cell in results["salience"]["cells"]:
        for seed in (0, 1):
            base = logs(run_dir)[(cell["route"], seed, "baseline")]
            inj = logs(run_dir)[(cell["route"], seed, "accel")]
            onset = next(s.step for s in base.steps if "onset" in s.extras["intervention"])
            if cell["distance"] == 70:  # the obstacle's distance at the start: the injection begins at once
                assert onset == 0
            else:
                assert base.steps[onset].ground_truth.distance_to_critical <= cell["distance"]
                assert base.steps[onset - 1].ground_truth.distance_to_critical > cell["distance"]
            assert [s.ego for s in base.steps[:onset + 1]] == [s.ego for s in inj.steps[:onset + 1]]
            assert all(s.cot.text != text for s in base.steps)
            assert all(s.cot.text == text for s in inj.steps[onset:])
            assert base.steps[onset].extras["intervention"]["gate"]["ok"]
            assert base.steps[onset].extras["intervention"]["onset"] == inj.steps[onset].extras["intervention"]["onset"]


def test_the_counts_and_rates_are_recomputed_from_the_logs(run_dir):
    results = json.loads((run_dir / "intervention.json").read_text())
    episodes = logs(run_dir)
    for cell in results["salience"]["cells"]:
        trials = overrides = 0
        for seed in (0, 1):
            base, inj = episodes[(cell["route"], seed, "baseline")], episodes[(cell["route"], seed, "accel")]
            hit = [any("ped0" in s.ground_truth.collisions for s in e.steps) for e in (base, inj)]
            stopped = not hit[0] and any(s.ego.speed < 0.3 and s.ground_truth.distance_to_critical > 0
                                         for s in base.steps[10:])
            trials += stopped
            overrides += stopped and hit[1]
        counts = cell["counts"]
        assert (counts["trials"], counts["overrides"]) == (trials, overrides)
        if trials:
            assert cell["override_rate"] == overrides / trials and cell["low"] <= cell["override_rate"] <= cell["high"]
    # the scripted model follows its CoT: "road is clear, accelerate" from onset drives it into the obstacle
    assert sum(c["counts"]["overrides"] for c in results["salience"]["cells"]) > 0


def test_salience_rises_as_the_obstacle_nears_and_a_car_covers_more_than_a_pedestrian(run_dir):
    cells = {c["key"]: c["salience"] for c in json.loads((run_dir / "intervention.json").read_text())["salience"]["cells"]}
    for kind in ("pedestrian", "car"):
        near, far = cells[f"{kind}_o0_d20_x1"], cells[f"{kind}_o0_d70_x1"]
        assert near["pixels"] > far["pixels"] > 0
        assert near["angular_width_deg"] > far["angular_width_deg"] > 0 and near["n"] == 2
    assert cells["car_o0_d20_x1"]["pixels"] > cells["pedestrian_o0_d20_x1"]["pixels"]


def test_the_report_has_the_tables_the_fit_and_the_plot(run_dir, tmp_path):
    assert run_cli(["report", str(run_dir), "--format", "md", "--out", str(tmp_path / "r.md")]) == 0
    text = (tmp_path / "r.md").read_text()
    assert "Salience sweep: override rate per cell" in text and "Salience threshold" in text
    assert "Override rate against the obstacle's salience at onset" in text
    assert "contrast is not varied" in text
    assert any(p.suffix == ".png" for p in tmp_path.rglob("*")), list(tmp_path.rglob("*"))


def test_a_second_run_resumes_every_episode_and_gives_the_same_results(run_dir, capsys):
    before = {p: os.stat(p).st_mtime_ns for p in find_episodes(run_dir)}
    results = (run_dir / "intervention.json").read_text()
    assert run_cli([*RUN, *GRID, "--out", str(run_dir)]) == 0
    assert {p: os.stat(p).st_mtime_ns for p in find_episodes(run_dir)} == before
    assert json.loads((run_dir / "intervention.json").read_text()) == json.loads(results)
    capsys.readouterr()


@pytest.mark.parametrize("args, fragment", [
    (["--paradigm-opt", "kinds=pedestrian,bus"], "--paradigm-opt kinds: 'bus' is not an obstacle kind"),
    (["--paradigm-opt", "offsets=0,x"], "--paradigm-opt offsets: 'x' is not a lateral offset"),
    (["--paradigm-opt", "offsets=3"], "is outside the ego's path"),
    (["--paradigm-opt", "distances=2"], "--paradigm-opt distances: 2 is not a distance"),
    (["--paradigm-opt", "distances=80"], "80 m is beyond what route SAFE.centre-ped allows (70.0 m"),
    (["--paradigm-opt", "sizes=-1"], "--paradigm-opt sizes: -1 is not a size factor"),
    (["--paradigm-opt", "sizes=0.5,,1"], "--paradigm-opt sizes: '0.5,,1' has an empty entry"),
    (["--paradigm-opt", "max_time=soon"], "--paradigm-opt max_time: 'soon' is not a number of seconds"),
    (["--paradigm-opt", "contrast=0.5"], "paradigm 'salience' does not take option 'contrast'"),
    (["--conditions", "accel,car"], "injects exactly one condition from onset"),
    (["--conditions", "selfsplice"], "injects exactly one condition from onset"),
    (["--route", "E.1"], "needs a safety route with one static obstacle"),
    (["--route", "SAFE.car,SAFE.kerb-ped"], "sweeps one base route"),
])
def test_bad_options_are_one_line_and_write_nothing(args, fragment, tmp_path, capsys):
    code = run_cli([*RUN, *GRID, "--out", str(tmp_path / "x"), *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and fragment in err[0], err
    assert err[0].startswith("vdb: error:")
    assert not (tmp_path / "x").exists()


def test_it_is_listed_as_a_paradigm_plugin(capsys):
    assert run_cli(["list-plugins", "--json"]) == 0
    listing = {p["name"]: p for p in json.loads(capsys.readouterr().out)}
    assert listing["salience"]["registered"] == {"paradigm": ["salience"]}
    assert listing["salience"]["distribution"] == "vdb-paradigm-salience"
