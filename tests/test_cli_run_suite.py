"""End to end with the real components: scripted model, kinematic simulator, PID/MPC, the scenario suite."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from vladrivebench._cli import main as cli
from vladrivebench._engine.registry import Registry, set_registry
from vladrivebench._logs.episodes import find_episodes, load_episodes, read_episode

SHORT = ["--model", "scripted", "--sim-opt", "render=false", "--quiet"]


@pytest.fixture(autouse=True)
def installed_plugins():
    """The registry of the installed plugins (scripted, kinematic, the core), fresh for each test."""
    previous = set_registry(Registry())
    yield
    set_registry(previous)


def vdb(capsys, *args):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def files(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in find_episodes(directory)}


def test_demo_runs_end_to_end_and_logs_everything(tmp_path, capsys):
    code, out, err = vdb(capsys, "demo", "--model", "scripted", "--out", tmp_path, "--quiet", "--json")
    summary = json.loads(out)
    assert code == 0 and err == "" and summary["complete"] == 8 and summary["failed"] == 0
    assert [r["scenario"] for r in summary["scenarios"]] == ["P.1", "C.1", "TL.1-red", "E.1"]
    episodes = {e.episode_id: e for e in load_episodes(tmp_path)}
    assert sorted(episodes) == sorted(f"scripted__{s}__s{seed}" for s in ("P.1", "C.1", "TL.1-red", "E.1")
                                      for seed in (0, 1))
    p1 = episodes["scripted__P.1__s0"]
    assert p1.complete and p1.meta["scenario"]["family"] == "pedestrian" and p1.meta["scenario"]["group"]
    assert {"vdb-model-scripted", "vdb-sim-kinematic", "vladrivebench", "numpy", "mcap", "python"} <= set(
        p1.meta["versions"])
    assert p1.meta["model"]["cot_format"]["kind"] == "sentence" and p1.meta["simulator"]["dt"] == pytest.approx(0.1)
    assert p1.meta["controller"]["name"] == "pid"
    assert any(s.ground_truth["critical_kind"] == "pedestrian" for s in p1.steps)
    assert any("pedestrian" in s.cot["text"].lower() for s in p1.steps)
    assert p1.result["steps"] == len(p1.steps) and p1.result["collisions"] == 0
    e1 = episodes["scripted__E.1__s1"]
    assert e1.result["terminal"] == "route_complete" and e1.result["route_completion"] == 1.0
    assert e1.steps[-1].ground_truth["terminal"] == "route_complete"


def test_demo_labels_summarises_and_reports(tmp_path, capsys):
    code, out, _ = vdb(capsys, "demo", "--model", "scripted", "--out", tmp_path, "--quiet")
    assert code == 0
    assert (tmp_path / "labels" / "lexicon.jsonl").exists() and (tmp_path / "report.html").exists()
    (line,) = [ln for ln in out.splitlines() if ln.strip().startswith("scripted: target mentioned")]
    # the demo's model writes contradictions with a known rate of 5 %: the labels must recover it
    low, high = (float(x) for x in line.split("contradiction ")[1].split("[")[1].split("]")[0].split("–"))
    assert low <= 5.0 <= high


def test_same_command_twice_gives_identical_bytes(tmp_path, capsys):
    args = ["run", *SHORT, "--scenarios", "TL.1-red", "--seeds", 1]
    assert vdb(capsys, *args, "--out", tmp_path / "a")[0] == 0
    assert vdb(capsys, *args, "--out", tmp_path / "b")[0] == 0
    assert files(tmp_path / "a") == files(tmp_path / "b")


def test_process_pool_matches_sequential_on_the_real_components(tmp_path, capsys):
    args = ["run", *SHORT, "--scenarios", "P.1", "--seeds", 2]
    assert vdb(capsys, *args, "--out", tmp_path / "seq")[0] == 0
    assert vdb(capsys, *args, "--out", tmp_path / "pool", "--workers", 2)[0] == 0
    assert files(tmp_path / "seq") == files(tmp_path / "pool")


def test_mpc_controller_and_model_options(tmp_path, capsys):
    code, out, _ = vdb(capsys, "run", *SHORT, "--controller", "mpc", "--model-opt", "cot_format=qa",
                       "--model-opt", "alpha=1", "--scenarios", "E.1", "--seeds", 1, "--out", tmp_path, "--json")
    assert code == 0 and json.loads(out)["complete"] == 1
    episode = read_episode(tmp_path / "episodes" / "scripted__E.1__s0.mcap")
    assert episode.meta["model"]["options"] == {"cot_format": "qa", "alpha": 1}
    assert set(episode.steps[0].cot["slots"]) == {"scene", "objects", "decision"}
    assert all(s.control["next_state"] is not None for s in episode.steps)  # MPC places the ego
    assert episode.result["terminal"] == "route_complete"


def test_bad_option_of_a_real_model_is_one_line(tmp_path, capsys):
    code, _, err = vdb(capsys, "run", *SHORT, "--model-opt", "alpha=2", "--scenarios", "E.1", "--seeds", 1,
                       "--out", tmp_path)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "alpha" in err and "Traceback" not in err


def test_demo_refuses_a_model_it_has_no_setup_for(tmp_path, capsys):
    code, _, err = vdb(capsys, "demo", "--model", "pixel", "--out", tmp_path)
    assert code == 2 and err.strip().count("\n") == 0 and "declares a demo (kv, scripted), got 'pixel'" in err
