"""`vdb intervene` / `vdb conditions` and the intervention metric's tables and plots (on fakes)."""

from __future__ import annotations

import json

import intervention_fakes as fakes
import pytest
from intervention_fakes import one_line_error, vdb
from vladrivebench._analysis.tables import AnalysisDataset, Plot, Table
from vladrivebench._cli import main as cli
from vladrivebench._engine import registry as plugins
from vladrivebench._intervention.metric import InterventionMetric, interval_text, p_text, table_text

BASE = ["intervene", "--model", "keyword", "--sim", "line", "--controller", "speed", "--quiet"]


@pytest.fixture(autouse=True)
def fake_world():
    previous = plugins.set_registry(fakes.fake_registry())
    yield
    plugins.set_registry(previous)


@pytest.fixture(scope="module")
def open_loop_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("ol")
    previous = plugins.set_registry(fakes.fake_registry())
    try:
        code = cli.main(BASE + ["--route", "E.1", "--seeds", "3", "--out", str(out), "--conditions",
                                "pedestrian,accel,depicts-3,depicts-30"])
    finally:
        plugins.set_registry(previous)
    assert code == 0
    return out


def test_open_loop_run_prints_the_paper_table(capsys, tmp_path):
    code, out, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 2, "--out", tmp_path / "r")
    assert code == 0, err
    assert "Open-loop: predicted forward displacement at 2 s, route E.1" in out
    assert "Cohen's d (steps)" in out and "p (Holm)" in out
    for condition in ("selfsplice", "accel", "pedestrian", "car"):
        assert f"\n{condition} " in out
    assert (tmp_path / "r" / "intervention.json").exists() and (tmp_path / "r" / "run.json").exists()
    assert len(list((tmp_path / "r" / "episodes").glob("*__openloop.mcap"))) == 2


def test_json_output(capsys, tmp_path):
    code, out, _ = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 2, "--out", tmp_path, "--json",
                       "--mode", "closed-loop", "--conditions", "selfsplice,car", "--checkpoints", "1,2")
    assert code == 0
    results = json.loads(out)
    assert results["mode"] == "closed-loop" and results["valid"] is True
    assert [s["condition"] for s in results["closed_loop"]["E.1"]["stats"]] == ["selfsplice", "car"]
    assert results["closed_loop"]["E.1"]["stats"][1]["checkpoints"] == [1.0, 2.0]


def test_invalid_gate_is_loud_and_exits_3(capsys, tmp_path):
    code, out, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 2, "--out", tmp_path, "--model-opt", "leak=0.001")
    assert code == 3
    assert "INVALID (selfsplice gate failed)" in out
    assert err.startswith("vdb: error: INVALID RUN: selfsplice differs from the model's own CoT at")
    assert "largest trajectory difference: 0.003 m" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("args, fragments", [
    (["--conditions", "pedestrain"], ["unknown condition 'pedestrain'", "did you mean 'pedestrian'"]),
    (["--conditions", "origbrake-paper"], ["'origbrake-paper' has no one-sentence text"]),
    (["--conditions", "depicts-150", "--model-opt", "max_tokens=50"], ["has 150 tokens; the model takes at most 50"]),
    (["--mode", "safety"], ["route 'E.1' cannot be used for a safety test", "SAFE.kerb-ped"]),
    (["--horizons", "two"], ["--horizons 'two': expected seconds"]),
    (["--horizons", "0"], ["--horizons must be positive"]),
    (["--model", "nope"], ["unknown model 'nope'"]),
    (["--route", "E.9"], ["E.9"]),
    (["--model-opt", "colour=red"], ["does not take option 'colour'"]),
    (["--workers", "0"], ["--workers must be a whole number from 1"]),
    (["--executor", "sequential", "--workers", "2"], ["--executor sequential runs one episode at a time"]),
    (["--executor", "nope"], ["unknown executor 'nope'"]),
    (["--executor-opt", "speed=3"], ["does not take option 'speed'"]),
])
def test_bad_input_is_one_line_and_writes_nothing(capsys, tmp_path, args, fragments):
    out_dir = tmp_path / "out"
    code, _, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 2, "--out", out_dir, *args)
    one_line_error(code, err, *fragments)
    assert not out_dir.exists()


def test_missing_required_options(capsys, tmp_path):
    code, _, err = vdb(capsys, "intervene", "--route", "E.1", "--seeds", 1, "--out", tmp_path / "x")
    one_line_error(code, err, "--model is required")
    code, _, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 0, "--out", tmp_path / "x")
    one_line_error(code, err, "--seeds must be a whole number")


def test_a_bad_condition_file_is_one_line(capsys, tmp_path):
    bad = tmp_path / "c.toml"
    bad.write_text('[conditions.go]\nkind = "repeat"\ntoken = "go"\ncount = 0\n')
    code, _, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 1, "--out", tmp_path / "x",
                       "--condition-file", bad, "--conditions", "go")
    one_line_error(code, err, str(bad), "condition 'go': field 'count' must be an integer between 1 and")


def test_a_condition_file_adds_conditions(capsys, tmp_path):
    good = tmp_path / "c.toml"
    good.write_text('[conditions.cyclist]\nintent = "brake"\nsentence = "Stop for the cyclist in the lane."\n')
    code, out, _ = vdb(capsys, "conditions", "--condition-file", good)
    assert code == 0 and "cyclist" in out and f"file {good}" in out
    code, out, err = vdb(capsys, *BASE, "--route", "E.1", "--seeds", 2, "--out", tmp_path / "r",
                         "--condition-file", good, "--conditions", "cyclist", "--json")
    assert code == 0, err
    row = json.loads(out)["open_loop"]["E.1"]["stats"]["2"][1]
    assert row["condition"] == "cyclist" and row["mean_diff"] < 0


def test_conditions_listing(capsys):
    code, out, _ = vdb(capsys, "conditions", "--json")
    names = {c["name"] for c in json.loads(out)}
    assert code == 0 and {"selfsplice", "accel", "pedestrian", "car", "animal", "red-light", "origbrake"} <= names


def test_plan_from_a_pilot(capsys, open_loop_dir):
    code, out, err = vdb(capsys, "intervene", "--plan", "--out", open_loop_dir, "--effect", 0.05)
    assert code == 0, err
    assert "Seeds needed" in out and "pedestrian" in out
    plan = json.loads((open_loop_dir / "plan.json").read_text())["plan"]
    assert {p["condition"] for p in plan} == {"pedestrian", "accel", "depicts-3", "depicts-30"}
    assert all(p["family_size"] == 4 for p in plan)


def test_plan_without_a_pilot_is_one_line(capsys, tmp_path):
    code, _, err = vdb(capsys, "intervene", "--plan", "--out", tmp_path)
    one_line_error(code, err, "holds no intervention results")


# -- the metric -----------------------------------------------------------------------------------------
def test_metric_tables_have_the_paper_shapes(open_loop_dir):
    items = InterventionMetric().compute(AnalysisDataset(open_loop_dir, []))
    tables = {t.id: t for t in items if isinstance(t, Table)}
    plots = {p.id: p for p in items if isinstance(p, Plot)}
    assert set(tables) == {"intervention.gate", "intervention.open_loop.E.1.2s", "intervention.open_loop.E.1.3s"}
    table = tables["intervention.open_loop.E.1.2s"]
    assert table.columns == ("n", "Mean diff (m)", "% shorter", "% longer", "Cohen's d (steps)", "d (seeds)",
                             "p (seed)", "p (Holm)")
    assert [r.labels[0] for r in table.rows] == ["selfsplice", "pedestrian", "accel", "depicts-3", "depicts-30"]
    selfsplice = table.rows[0].cells
    assert selfsplice[1].display == "+0.000" and selfsplice[6].display == "1.00" and selfsplice[7].display == "(control)"
    assert table.cell("pedestrian", 6).count == 3 and table.cell("pedestrian", 1).count == table.cell("pedestrian", 0).count
    assert any("one-sample t-test of the per-seed mean" in n for n in table.notes)
    dose = plots["intervention.dose_response"]
    assert [s.x for s in dose.panels[0][1]] == [(3.0, 30.0), (3.0, 30.0)]
    assert dose.to_png().startswith(b"\x89PNG")


def test_metric_is_empty_without_intervention_runs(tmp_path):
    assert InterventionMetric().compute(AnalysisDataset(tmp_path, [])) == []


def test_metric_finds_several_runs_and_computes_missing_results_from_logs(capsys, tmp_path):
    for mode in ("closed-loop", "safety"):
        route = "E.1" if mode == "closed-loop" else "SAFE.car"
        code, _, err = vdb(capsys, *BASE, "--route", route, "--seeds", 2, "--out", tmp_path / mode, "--mode", mode,
                           "--conditions", "selfsplice,accel" if mode == "closed-loop" else "accel",
                           "--sim-opt", "length=80")
        assert code in (0,), err
    (tmp_path / "closed-loop" / "intervention.json").unlink()
    items = InterventionMetric().compute(AnalysisDataset(tmp_path, []))
    ids = {i.id for i in items}
    assert {"intervention.closed_loop.E.1.closed-loop", "intervention.closed_loop_curve.closed-loop",
            "intervention.safety.safety", "intervention.gate.safety"} <= ids
    assert not (tmp_path / "closed-loop" / "intervention.json").exists()  # reports never write results
    safety = next(i for i in items if i.id == "intervention.safety.safety")
    assert [r.labels for r in safety.rows] == [("SAFE.car", "selfsplice"), ("SAFE.car", "accel")]
    assert "Injected collisions" in table_text(safety)


def test_formatting_helpers():
    assert p_text(1.0) == "1.00" and p_text(0.037) == "0.037" and p_text(1.3e-9) == "1.3e-09"
    assert p_text(None) == "—"
    assert interval_text({"mean": -1.6, "low": -2.2, "high": -1.1}) == "-1.6 [-2.2, -1.1]*"
    assert interval_text({"mean": -0.1, "low": -0.5, "high": 0.2}) == "-0.1 [-0.5, +0.2]"


def test_the_seeds_default_matches_the_protocols():
    from vladrivebench._cli.intervene import intervene_command
    from vladrivebench._intervention.runs import DEFAULT_SEEDS

    option = next(p for p in intervene_command.params if p.name == "seeds")
    assert option.default == DEFAULT_SEEDS
