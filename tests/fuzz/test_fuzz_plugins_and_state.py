"""Failure isolation of plugins, name conflicts, broken scenario packs, read-only file systems, warnings and
resume trust: what a single refused input cannot show."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cases import fake_distribution, scenario_json  # noqa: E402
from harness import Case, classify, explain, run_in_process, snapshot  # noqa: E402
from test_fuzz_cli import complete_run  # noqa: E402


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-state")


def plugins_listed(sys_path, *extra):
    ended = run_in_process(Case("list", ["list-plugins", "--json", *extra], sys_path=tuple(sys_path), status=0))
    assert ended.status == 0 and ended.escaped is None, ended.stderr
    return {p["name"]: p for p in json.loads(ended.stdout)}


@pytest.mark.parametrize("body", ["import sys\nsys.exit(3)\n", "raise SystemExit('bye')\n",
                                  "class Stop(BaseException):\n    pass\nraise Stop('x')\n",
                                  "raise RuntimeError('boom')\n"])
def test_a_plugin_failing_at_import_is_reported_and_the_rest_works(tmp_path, body):
    site = fake_distribution(tmp_path, "vdb-broken", "broken", body)
    listed = plugins_listed([site])
    assert listed["broken"]["status"] == "error" and listed["broken"]["distribution"] == "vdb-broken"
    assert listed["scripted"]["status"] == "ok"
    ended = run_in_process(Case("scenarios", ["scenarios", "P.1"], sys_path=(site,), status=0))
    assert ended.status == 0 and "P.1" in ended.stdout


def test_a_plugin_exiting_in_register_commands_is_reported(tmp_path):
    source = ("import sys\nimport vladrivebench\n\n@vladrivebench.hookimpl\n"
              "def register_commands(cli):\n    sys.exit(4)\n")
    site = fake_distribution(tmp_path, "vdb-cmd", "cmdexit", source)
    ended = run_in_process(Case("help", ["--help"], sys_path=(site,), status=0))
    assert ended.status == 0 and ended.escaped is None, ended.stderr
    listed = plugins_listed([site])
    assert listed["cmdexit"]["status"] == "error" and "register_commands" in listed["cmdexit"]["error"]


def _claims(name: str) -> str:
    return ("import vladrivebench\n\n@vladrivebench.hookimpl\ndef register_models(register):\n"
            f"    register('dupe', 'vdb_model_scripted.plugin:make_scripted', description='{name}')\n")


@pytest.mark.parametrize("order", ["a-first", "b-first"])
def test_a_contested_name_stays_with_the_first_distribution_whatever_the_path_order(tmp_path, order):
    site_a = fake_distribution(tmp_path / "a", "vdb-dup-a", "dupa", _claims("a"))
    site_b = fake_distribution(tmp_path / "b", "vdb-dup-b", "dupb", _claims("b"))
    listed = plugins_listed([site_a, site_b] if order == "a-first" else [site_b, site_a])
    assert listed["dupa"]["status"] == "ok" and listed["dupa"]["registered"] == {"model": ["dupe"]}
    assert listed["dupb"]["status"] == "error"
    assert "dupa" in listed["dupb"]["error"] and "dupb" in listed["dupb"]["error"]


def test_one_broken_file_in_a_scenario_pack(tmp_path):
    pack = tmp_path / "pack"
    pack.mkdir()
    (pack / "good.json").write_text(json.dumps(scenario_json("P.1", id="X.good")))
    (pack / "bad.toml").write_bytes(b"id = [\n")
    source = (f"import vladrivebench\n\n@vladrivebench.hookimpl\ndef register_scenarios(register):\n"
              f"    register({str(pack)!r})\n")
    site = fake_distribution(tmp_path, "vdb-pack", "pack", source)
    listed = plugins_listed([site])
    assert listed["pack"]["status"] == "error" and "bad.toml" in listed["pack"]["error"]
    for spec in ("X.good", "P.1"):
        ended = run_in_process(Case("scenarios", ["scenarios", spec], sys_path=(site,), status=0))
        assert ended.status == 0 and spec in ended.stdout, ended.stderr


def test_a_broken_pack_is_one_line_with_strict_plugins(tmp_path):
    pack = tmp_path / "pack"
    pack.mkdir()
    (pack / "bad.toml").write_bytes(b"id = [\n")
    source = (f"import vladrivebench\n\n@vladrivebench.hookimpl\ndef register_scenarios(register):\n"
              f"    register({str(pack)!r})\n")
    site = fake_distribution(tmp_path, "vdb-pack", "pack", source)
    case = Case("strict", ["--strict-plugins", "scenarios", "P.1"], sys_path=(site,), mentions=("bad.toml",))
    before = snapshot(tmp_path)
    ended = run_in_process(case)
    assert classify(case, ended, before, snapshot(tmp_path)) == "one line", explain(case, ended, before, before)


def test_third_party_warnings_are_not_printed_before_the_error(tmp_path):
    source = ("import warnings\nimport vladrivebench\n\n@vladrivebench.hookimpl\ndef register_models(register):\n"
              "    warnings.warn('a noisy third-party warning', FutureWarning)\n")
    site = fake_distribution(tmp_path, "vdb-noisy", "noisy", source)
    case = Case("warn", ["run", "--model", "nosuch", "--scenarios", "P.1", "--seeds", "1", "--out",
                         str(tmp_path / "o")], sys_path=(site,), mentions=("nosuch",))
    before = snapshot(tmp_path)
    ended = run_in_process(case)
    assert classify(case, ended, before, snapshot(tmp_path)) == "one line", explain(case, ended, before, before)


def _copy_run(base: Path, tmp: Path) -> Path:
    run = tmp / "run"
    shutil.copytree(complete_run(base), run)
    return run


RUN = ["run", "--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--quiet", "--sim-opt", "render=false"]


def test_a_resumed_sweep_does_not_trust_an_edited_result(tmp_path, base):
    run = _copy_run(base, tmp_path)
    log = sorted((run / "episodes").glob("*.mcap"))[0]
    original = log.read_bytes()
    found = re.search(rb'route_completion\\?"\s*:\s*([0-9])', original)
    assert found, "the result record holds route_completion"
    edited = bytearray(original)
    edited[found.start(1)] = ord("7") if found.group(1) != b"7" else ord("3")
    log.write_bytes(bytes(edited))
    ended = run_in_process(Case("resume", [*RUN, "--json", "--out", str(run)], status=0))
    assert ended.status == 0, ended.stderr
    summary = json.loads(ended.stdout)
    assert summary["ran"] == 1 and summary["skipped"] == 0
    assert log.read_bytes() == original


def test_a_rejected_option_leaves_no_run_directory(tmp_path):
    out = tmp_path / "D"
    for opt in (["--model-opt", "alpha=2"], ["--controller-opt", "max_speed=-1"],
                ["--controller-opt", "speed_window=abc"], ["--executor-opt", "nosuch=1"]):
        ended = run_in_process(Case("opt", [*RUN, *opt, "--out", str(out)]))
        assert ended.status == 2 and len(ended.error_lines) == 1, ended.stderr
        assert not out.exists()
    ended = run_in_process(Case("fixed", [*RUN, "--model-opt", "alpha=0.9", "--out", str(out)], status=0))
    assert ended.status == 0, ended.stderr


def _read_only_run(command: list[str], directory: Path) -> subprocess.CompletedProcess:
    """``vdb COMMAND`` in a private mount namespace where ``directory`` is a read-only bind mount."""
    script = (f"mount --bind {directory} {directory} && mount -o remount,bind,ro {directory} && "
              f"exec {sys.executable} -m vladrivebench " + " ".join(f"'{c}'" for c in command))
    return subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True, timeout=120,
                          stdin=subprocess.DEVNULL)


def _can_mount_read_only(tmp_path: Path) -> bool:
    probe = tmp_path / "probe"
    probe.mkdir()
    if shutil.which("unshare") is None:
        return False
    done = subprocess.run(["unshare", "-m", "sh", "-c", f"mount --bind {probe} {probe} && "
                           f"mount -o remount,bind,ro {probe} && ! touch {probe}/x 2>/dev/null"],
                          capture_output=True, timeout=30)
    probe.rmdir()
    return done.returncode == 0


@pytest.mark.parametrize("which", ["complete run", "new run", "report"])
def test_read_only_file_system(tmp_path, base, which):
    """A real read-only mount (root ignores permission bits, a read-only mount it does not)."""
    if not _can_mount_read_only(tmp_path):
        pytest.skip("no private mount namespace here (unshare -m / mount --bind)")
    run = _copy_run(base, tmp_path)
    command = {"complete run": [*RUN, "--out", str(run)],
               "new run": [*RUN, "--out", str(tmp_path / "new")],
               "report": ["report", str(run), "--format", "md", "--out", str(tmp_path / "r.md")]}[which]
    before = snapshot(tmp_path)
    done = _read_only_run(command, tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("vdb: error: "), done.stderr
    assert "read-only" in lines[0].lower() and "Traceback" not in done.stderr
    assert snapshot(tmp_path) == before
