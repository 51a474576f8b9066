"""`vdb run`: flags and config files, one-line errors with exit status 2, summary/JSON output, progress,
failures, refusal of a different configuration, resume (SIGKILL tests: test_cli_run_kill.py)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import runner_fakes as fakes
from vladrivebench._cli import main as cli
from vladrivebench._engine import registry as plugins
from vladrivebench._scenarios import spec as scenarios

BASE = ["run", "--model", "echo", "--sim", "line", "--controller", "speed"]


@pytest.fixture(autouse=True)
def fake_world(monkeypatch):
    previous = plugins.set_registry(fakes.fake_registry())
    monkeypatch.setattr(scenarios, "resolve_scenarios", fakes.fake_resolve_scenarios)
    yield
    plugins.set_registry(previous)


def vdb(capsys, *args):
    code = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("vdb: error: "), err
    assert "Traceback" not in err
    return lines[0]


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_run_prints_a_table_and_writes_the_logs(tmp_path, capsys):
    code, out, err = vdb(capsys, *BASE, "--scenarios", "road,car", "--seeds", 2, "--out", tmp_path, "--quiet")
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0].split() == ["scenario", "episodes", "failed", "collisions", "violations", "route", "compl.",
                                "mean", "speed"]
    assert lines[1].split()[:6] == ["road", "2", "0", "0", "0", "1.00"]
    assert lines[2].split()[:3] == ["car", "2", "0"]
    assert "4 episodes: 4 complete (4 run now, 0 already there), 0 failed" in lines[3]
    assert len(list((tmp_path / "episodes").glob("*.mcap"))) == 4


def test_json_summary(tmp_path, capsys):
    code, out, _ = vdb(capsys, *BASE, "--scenarios", "road", "--seeds", 3, "--seed-offset", 5, "--out", tmp_path,
                       "--quiet", "--json")
    summary = json.loads(out)
    assert code == 0 and summary["episodes"] == 3 and summary["complete"] == 3 and summary["failed"] == 0
    assert summary["scenarios"][0]["scenario"] == "road" and summary["scenarios"][0]["route_completion"] == 1.0
    assert sorted(p.name for p in (tmp_path / "episodes").iterdir()) == [f"echo__road__s{s}.mcap" for s in (5, 6, 7)]


def test_progress_goes_to_stderr_unless_quiet(tmp_path, capsys):
    code, out, err = vdb(capsys, *BASE, "--scenarios", "road", "--seeds", 2, "--out", tmp_path)
    assert code == 0
    assert re.fullmatch(r"vdb run: 2/2 episodes, done in \d+s", err.strip().splitlines()[-1])
    assert "vdb:" not in out


def test_failed_episodes_exit_2_with_one_line(tmp_path, capsys):
    code, out, err = vdb(capsys, *BASE, "--model-opt", "fail_at=[0, 2]", "--scenarios", "road,car", "--seeds", 2,
                         "--out", tmp_path, "--quiet")
    assert code == 2
    line = one_line_error(err)
    assert line.startswith("vdb: error: 2 of 4 episodes failed; first, echo__car__s0: model 'echo'")
    assert line.endswith(f"(details: {tmp_path / 'failures.json'})")
    assert "2 complete" in out and "2 failed" in out
    failures = json.loads((tmp_path / "failures.json").read_text())["failures"]
    assert [f["episode_id"] for f in failures] == ["echo__car__s0", "echo__road__s0"]


def test_retry_failed_flag(tmp_path, capsys):
    flag = tmp_path / "flag"
    args = [*BASE, "--model-opt", f"fail_once_file={flag}", "--scenarios", "road", "--seeds", 1,
            "--out", tmp_path / "out", "--quiet"]
    assert vdb(capsys, *args)[0] == 2
    assert vdb(capsys, *args)[0] == 2  # still failed: not retried by default
    code, out, err = vdb(capsys, *args, "--retry-failed")
    assert code == 0 and "1 complete (1 run now" in out


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--seeds", 0], "--seeds must be a whole number from 1 to 100,000 (seeds 0 … N−1), got 0"),
        (["--seeds", 10**12], "--seeds must be a whole number from 1 to 100,000"),
        (["--seeds", -3], "--seeds must be a whole number from 1"),
        (["--seeds", "two"], "'two' is not a valid integer"),
        (["--seeds", 2, "--seed-offset", -1], "--seed-offset must be a whole number from 0"),
        (["--seeds", 2, "--model-opt", "cruise"], "--model-opt 'cruise': expected key=value"),
        (["--seeds", 2, "--model-opt", "temperature=1"], "model 'echo' does not take option 'temperature'"),
        (["--seeds", 2, "--executor", "rayy"], "unknown executor 'rayy'"),
        (["--seeds", 2, "--address", "10.0.0.1:6379"], "executor 'sequential' does not take option 'address'"),
        (["--seeds", 2, "--workers", 0], "--workers must be a whole number from 1 to 512, got 0"),
            (["--seeds", 2, "--executor", "sequential", "--workers", 2], "--executor sequential runs one episode"),
        (["--seeds", 2, "--model-opt", "cruise=-1"], "model 'echo': cruise must be ≥ 0, got -1"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, expected):
    code, out, err = vdb(capsys, *BASE, "--scenarios", "road", "--out", tmp_path / "out", *args)
    assert code == 2 and expected in one_line_error(err)


def test_unknown_scenario_and_model(tmp_path, capsys):
    code, _, err = vdb(capsys, *BASE, "--scenarios", "raod", "--seeds", 1, "--out", tmp_path)
    assert code == 2 and "unknown scenario 'raod': did you mean 'road'?" in one_line_error(err)
    code, _, err = vdb(capsys, "run", "--model", "ech", "--sim", "line", "--controller", "speed",
                       "--scenarios", "road", "--seeds", 1, "--out", tmp_path / "x")
    assert code == 2 and "unknown model 'ech': did you mean 'echo'?" in one_line_error(err)
    assert not (tmp_path / "x").exists()


def test_missing_required_settings(tmp_path, capsys):
    code, _, err = vdb(capsys, "run", "--scenarios", "road", "--out", tmp_path)
    assert code == 2 and one_line_error(err) == ("vdb: error: vdb run: missing --model, --seeds (give them on "
                                                 "the command line or in --config)")


def test_config_file_with_command_line_overrides(tmp_path, capsys):
    config = tmp_path / "run.toml"
    config.write_text(f'model = "echo"\nsim = "line"\ncontroller = "speed"\nscenarios = ["road", "car"]\n'
                      f'seeds = 1\nout = "{tmp_path / "out"}"\n[model_options]\ncruise = 4.0\nnoise = 0.1\n')
    code, out, err = vdb(capsys, "run", "--config", config, "--seeds", 2, "--model-opt", "noise=0.0", "--quiet",
                         "--json")
    assert code == 0 and json.loads(out)["episodes"] == 4
    manifest = json.loads((tmp_path / "out" / "run.json").read_text())
    assert manifest["config"]["model"]["options"] == {"cruise": 4.0, "noise": 0.0}
    assert manifest["config"]["scenarios"] == ["road", "car"] and manifest["config"]["seeds"] == [0, 1]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('model = "echo"\nseed = 3\n', "unknown key 'seed' (expected one of:"),
        ('seeds = "two"\n', "key 'seeds' must be a whole number, got 'two'"),
        ("scenarios = []\n", "key 'scenarios' must be a string"),
        ("model_options = 3\n", "key 'model_options' must be a table of options"),
        ("model = \n", "not valid TOML"),
    ],
)
def test_bad_config_files(tmp_path, capsys, text, expected):
    config = tmp_path / "run.toml"
    config.write_text(text)
    code, _, err = vdb(capsys, "run", "--config", config)
    line = one_line_error(err)
    assert code == 2 and expected in line and str(config) in line


def test_missing_config_file(tmp_path, capsys):
    code, _, err = vdb(capsys, "run", "--config", tmp_path / "nope.toml")
    assert code == 2 and "no such file" in one_line_error(err)


def test_other_configuration_in_out_is_refused_untouched(tmp_path, capsys):
    assert vdb(capsys, *BASE, "--scenarios", "road", "--seeds", 2, "--out", tmp_path, "--quiet")[0] == 0
    before = snapshot(tmp_path)
    code, _, err = vdb(capsys, *BASE, "--scenarios", "road", "--seeds", 2, "--out", tmp_path, "--quiet",
                       "--model-opt", "cruise=3")
    assert code == 2 and "holds a run with a different configuration (config.model.options.cruise: 3 now, " \
                         "absent before)" in one_line_error(err)
    assert snapshot(tmp_path) == before


def test_same_command_resumes(tmp_path, capsys):
    args = [*BASE, "--scenarios", "road,car", "--seeds", 2, "--out", tmp_path, "--quiet"]
    assert vdb(capsys, *args)[0] == 0
    code, out, _ = vdb(capsys, *args, "--workers", 2)  # executor settings may change between resumes
    assert code == 0 and "(0 run now, 4 already there)" in out


def test_workers_use_the_process_pool_with_identical_results(tmp_path, capsys):
    common = [*BASE, "--scenarios", "road,car,long", "--seeds", 2, "--quiet"]
    assert vdb(capsys, *common, "--out", tmp_path / "seq")[0] == 0
    assert vdb(capsys, *common, "--out", tmp_path / "pool", "--workers", 2)[0] == 0
    assert json.loads((tmp_path / "pool" / "run.json").read_text())["executor"] == {"name": "process", "workers": 2}
    assert snapshot(tmp_path / "seq" / "episodes") == snapshot(tmp_path / "pool" / "episodes")


def test_log_images_flag(tmp_path, capsys):
    from vladrivebench._logs.episodes import read_episode

    assert vdb(capsys, *BASE, "--scenarios", "road", "--seeds", 1, "--out", tmp_path, "--quiet", "--log-images")[0] == 0
    episode = read_episode(tmp_path / "episodes" / "echo__road__s0.mcap")
    assert all(s.image_png is not None for s in episode.steps) and episode.meta["config"]["log_images"] is True


def test_the_pipelined_executor_gives_the_bytes_of_a_sequential_batched_run(tmp_path, capsys):
    common = [*BASE, "--scenarios", "road,car,long", "--seeds", 3, "--batch", 2, "--quiet"]
    assert vdb(capsys, *common, "--out", tmp_path / "seq")[0] == 0
    assert vdb(capsys, *common, "--out", tmp_path / "pipe", "--executor", "pipelined")[0] == 0
    manifest = json.loads((tmp_path / "pipe" / "run.json").read_text())
    assert manifest["executor"] == {"name": "pipelined", "workers": 2}
    assert snapshot(tmp_path / "seq" / "episodes") == snapshot(tmp_path / "pipe" / "episodes")
    code, _, err = vdb(capsys, *common, "--out", tmp_path / "bad", "--executor", "pipelined", "--workers", 0)
    assert code == 2 and "--workers must be a whole number from 1 to" in one_line_error(err)
    assert not (tmp_path / "bad").exists()
