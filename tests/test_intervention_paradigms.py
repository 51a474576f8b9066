"""Paradigms are components: the register_paradigms hook, `--mode` from the registry, one-line errors, and a
tiny paradigm registered in an isolated registry running end to end (plan → policy → logs → analyse →
tables → report), without touching the core."""

from __future__ import annotations

import ast
import importlib
import json
import sys
from pathlib import Path

import intervention_fakes as fakes
import pytest
from intervention_fakes import one_line_error, vdb
from vladrivebench import hookimpl
from vladrivebench._engine import registry as plugins
from vladrivebench._intervention.metric import InterventionMetric
from vladrivebench.intervention import (
    SELFSPLICE,
    GateTally,
    PlannedEpisode,
    RunContext,
    gate_record,
    own_step,
)
from vladrivebench.metrics import AnalysisDataset, Cell, Row, Table
from vladrivebench.protocols import Paradigm

BASE = ["intervene", "--model", "keyword", "--sim", "line", "--controller", "speed", "--quiet", "--route", "E.1",
        "--seeds", "2"]


# -- a tiny third-party paradigm, from the public API only ---------------------------------------------
class Echo:
    """The own CoT drives; at each step the model's own text is spliced back (the gate) and the step's
    CoT length is logged. Results: steps and mean CoT words per seed, scaled by ``weight``."""

    name = "echo"
    default_conditions = ("selfsplice",)

    def __init__(self, weight: float = 1.0, reserved: bool = False):
        self.weight, self.reserved = float(weight), reserved

    def check(self, config):
        if config.tested != ("selfsplice",):
            raise fakes_error(f"paradigm 'echo' takes no conditions, got {', '.join(config.conditions)}")

    def plan(self, config):
        return [PlannedEpisode(route, seed, "echo") for route in config.routes for seed in config.seeds]

    def policy(self, episode, context: RunContext):
        splicer = context.splicer

        def step(model, obs, seed):
            own, trajectory = own_step(model, obs, seed)
            spliced = splicer.splice(obs, SELFSPLICE, splicer.check(SELFSPLICE, own.text), seed)
            gate = gate_record(model, own, trajectory, spliced, splicer.decode(obs, spliced, seed))
            return own, trajectory, {"intervention": {"gate": gate, "words": len(own.text.split())}}

        return step

    def analyse(self, config, episodes, gate: GateTally):
        out = {}
        for route in config["routes"]:
            for seed in config["seeds"]:
                episode = episodes.require(route, seed, "echo")
                gate.add_episode(episode, route, seed, "echo")
                words = [s.extras["intervention"]["words"] for s in episode.steps]
                out[f"{route}/{seed}"] = {"steps": len(words), "words": self.weight * sum(words) / len(words)}
        return {"gate" if self.reserved else "echo": out}

    def tables(self, results):
        rows = tuple(Row((key,), (Cell(str(v["steps"]), v["steps"], float(v["steps"])),
                                  Cell(f"{v['words']:.2f}", v["steps"], v["words"])))
                     for key, v in results["echo"].items())
        return [Table("intervention.echo", "Echo: words per step", ("Route/seed",), ("Steps", "Words"), rows)]


def fakes_error(message):
    from vladrivebench import ConfigError

    return ConfigError(message)


class EchoPlugin:
    @hookimpl
    def register_paradigms(self, register):
        register("echo", Echo, description="a test paradigm")


class NotAParadigm:
    @hookimpl
    def register_paradigms(self, register):
        register("hollow", lambda: object())


@pytest.fixture
def echo_registry():
    registry = fakes.fake_registry(("echo", EchoPlugin()), ("hollow", NotAParadigm()))
    previous = plugins.set_registry(registry)
    yield registry
    plugins.set_registry(previous)


# -- registration -------------------------------------------------------------------------------------
def test_the_core_registers_its_three_paradigms_through_the_hook():
    registry = fakes.fake_registry()
    assert registry.names("paradigm") == ["closed-loop", "open-loop", "safety"]
    assert {c.plugin for c in registry.components("paradigm")} == {"core"}
    for name in registry.names("paradigm"):
        paradigm = registry.create("paradigm", name)
        assert isinstance(paradigm, Paradigm) and paradigm.name == name
    assert "paradigm" in next(p for p in registry.plugins if p.name == "core").registered


def test_a_plugin_paradigm_is_registered_and_a_taken_name_is_refused(echo_registry):
    assert "echo" in echo_registry.names("paradigm")

    class Clash:
        @hookimpl
        def register_paradigms(self, register):
            register("open-loop", Echo)

    info = echo_registry.add_plugin("clash", Clash())
    assert info.status == "error" and "paradigm 'open-loop' is already registered by plugin 'core'" in info.error
    assert echo_registry.get("paradigm", "open-loop").plugin == "core"


def test_registration_of_the_builtin_paradigms_imports_none_of_them():
    code = ("import sys; from vladrivebench._engine.registry import Registry; from vladrivebench import _builtins; "
            "r = Registry([('core', _builtins)], entry_points=False); assert r.names('paradigm'); "
            "print(sorted(m for m in sys.modules if m.startswith('vladrivebench._builtins.paradigms.') "
            "or m in ('numpy', 'scipy')))")
    import subprocess

    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_builtin_paradigm_modules_import_only_public_names():
    import vladrivebench

    allowed = {"vladrivebench": set(vladrivebench.__all__)}
    for module in vladrivebench.PUBLIC_SUBPACKAGES:
        allowed[module] = set(importlib.import_module(module).__all__)
    folder = Path(vladrivebench.__file__).parent / "_builtins" / "paradigms"
    modules = sorted(folder.glob("*.py"))
    assert {p.stem for p in modules} >= {"open_loop", "closed_loop", "safety"}
    for path in modules:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module.startswith("vladrivebench"):
                assert node.module in allowed, f"{path.name}: {node.module}"
                assert all(a.name in allowed[node.module] for a in node.names), f"{path.name}: {node.module}"
            elif isinstance(node, ast.Import):
                assert not any(a.name.startswith("vladrivebench") for a in node.names), path.name


# -- --mode from the registry ---------------------------------------------------------------------------
def test_mode_choices_come_from_the_registry(capsys, echo_registry):
    code, out, err = vdb(capsys, "intervene", "--help")
    assert code == 0, err
    assert "[closed-loop|echo|hollow|open-loop|safety]" in " ".join(out.split())


def test_an_unknown_mode_is_one_line_with_suggestions_and_writes_nothing(capsys, echo_registry, tmp_path):
    code, _, err = vdb(capsys, *BASE, "--mode", "ecoh", "--out", tmp_path / "x")
    one_line_error(code, err, "unknown paradigm 'ecoh'", "did you mean 'echo'", "open-loop")
    assert not (tmp_path / "x").exists()


def test_a_registered_object_that_is_not_a_paradigm_is_one_line(capsys, echo_registry, tmp_path):
    code, _, err = vdb(capsys, *BASE, "--mode", "hollow", "--out", tmp_path / "x")
    one_line_error(code, err, "paradigm 'hollow'", "is not a Paradigm", "lacks name, default_conditions")
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize("args, fragments", [
    (["--paradigm-opt", "colour=red"], ["paradigm 'echo' does not take option 'colour'", "weight"]),
    (["--paradigm-opt", "weight"], ["--paradigm-opt 'weight': expected key=value"]),
    (["--conditions", "car"], ["paradigm 'echo' takes no conditions, got car"]),
])
def test_bad_paradigm_input_is_one_line_and_writes_nothing(capsys, echo_registry, tmp_path, args, fragments):
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", tmp_path / "x", *args)
    one_line_error(code, err, *fragments)
    assert not (tmp_path / "x").exists()


# -- a fake paradigm end to end ---------------------------------------------------------------------------
def test_a_plugin_paradigm_runs_end_to_end(capsys, echo_registry, tmp_path):
    out = tmp_path / "echo"
    code, stdout, err = vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "weight=2", "--out", out)
    assert code == 0, err
    assert "Selfsplice gate — keyword, echo" in stdout and "Echo: words per step" in stdout
    results = json.loads((out / "intervention.json").read_text())
    assert results["mode"] == "echo" and results["paradigm_options"] == {"weight": 2}
    assert results["valid"] and results["gate"]["steps_checked"] > 0
    names = sorted(p.name for p in (out / "episodes").glob("*.mcap"))
    assert names == ["keyword__E.1__s0__echo.mcap", "keyword__E.1__s1__echo.mcap"]
    from vladrivebench._logs.episodes import read_episode

    episode = read_episode(out / "episodes" / names[0])
    assert episode.meta["intervention"] == {"mode": "echo", "role": "echo", "condition": None}
    steps = results["echo"]["E.1/0"]["steps"]
    assert steps == len(episode.steps)
    words = sum(len(s.cot["text"].split()) for s in episode.steps) / steps
    assert results["echo"]["E.1/0"]["words"] == pytest.approx(2 * words)
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["config"]["paradigm_options"] == {"weight": 2}

    # the report metric asks the paradigm for its tables, under its own ids and the metric's name
    tables = InterventionMetric().compute(AnalysisDataset(out, []))
    assert [t.id for t in tables] == ["intervention.gate", "intervention.echo"]
    assert {t.metric for t in tables} == {"intervention"}
    echo = tables[1]
    assert echo.cell("E.1/1", 0).count == results["echo"]["E.1/1"]["steps"]

    # resuming: the same command again reruns nothing and gives the same results
    stamps = {p: p.stat().st_mtime_ns for p in (out / "episodes").glob("*.mcap")}
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "weight=2", "--out", out, "--json")
    assert code == 0, err
    assert all(p.stat().st_mtime_ns == t for p, t in stamps.items())
    assert json.loads((out / "intervention.json").read_text()) == results

    # another option is another run
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "weight=3", "--out", out)
    one_line_error(code, err, "different configuration", "paradigm_options.weight")

    # --plan needs a paradigm that names its effects
    code, _, err = vdb(capsys, "intervene", "--plan", "--out", out)
    one_line_error(code, err, "--plan: paradigm 'echo' does not say which effect")


def test_a_paradigm_may_not_overwrite_the_cores_result_keys(capsys, echo_registry, tmp_path):
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "reserved=true", "--out", tmp_path / "r")
    one_line_error(code, err, "paradigm 'echo' returned the result key 'gate', which the core writes itself")


def test_a_report_without_the_paradigm_installed_shows_the_gate_and_says_why(capsys, echo_registry, tmp_path):
    out = tmp_path / "echo"
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", out)
    assert code == 0, err
    previous = plugins.set_registry(fakes.fake_registry())  # the echo plugin is gone
    try:
        tables = InterventionMetric().compute(AnalysisDataset(out, []))
    finally:
        plugins.set_registry(previous)
    assert [t.id for t in tables] == ["intervention.gate"]
    assert any("paradigm 'echo' is not installed" in note for note in tables[0].notes)


def test_an_invalid_run_marks_every_paradigm_table(capsys, echo_registry, tmp_path):
    out = tmp_path / "leaky"
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--model-opt", "leak=0.5", "--out", out)
    assert code == 3 and "INVALID RUN" in err
    tables = InterventionMetric().compute(AnalysisDataset(out, []))
    assert all(t.title.startswith("INVALID (selfsplice gate failed) — ") for t in tables)


def test_planned_episodes_name_their_logs():
    route = type("Route", (), {"id": "E.1"})()
    assert PlannedEpisode(route, 3, "injected", "car").key == ("E.1", 3, "car")
    assert PlannedEpisode(route, 3, "baseline").name == "baseline"


# -- the paradigm's effective settings in run.json (resume under another default is refused) ------------------
def snapshot(out):
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


class StatedEcho(Echo):
    """Echo stating its settings itself (the EffectiveOptions capability), in its own normalised form."""

    def __init__(self, weight: float = 1.0, reserved: bool = False, broken: bool = False):
        super().__init__(weight, reserved)
        self.broken = broken

    def effective_options(self):
        return ["weight"] if self.broken else {"weight": self.weight, "scale": "linear"}


class StatedEchoPlugin:
    @hookimpl
    def register_paradigms(self, register):
        register("stated-echo", StatedEcho)


@pytest.fixture
def stated_registry():
    registry = fakes.fake_registry(("echo", EchoPlugin()), ("stated", StatedEchoPlugin()))
    previous = plugins.set_registry(registry)
    yield registry
    plugins.set_registry(previous)


def test_a_changed_default_is_refused_on_resume_and_the_same_defaults_resume(capsys, echo_registry, tmp_path,
                                                                              monkeypatch):
    out = tmp_path / "echo"
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", out)
    assert code == 0, err
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["config"]["paradigm_settings"] == {"reserved": False, "weight": 1.0}  # the signature's defaults
    assert "paradigm_options" not in manifest["config"]
    before = snapshot(out)

    monkeypatch.setattr(Echo.__init__, "__defaults__", (1.5, False))  # a new version of the plugin
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", out)
    one_line_error(code, err, "different configuration", "paradigm 'echo' setting weight: 1.5 now, 1.0 before",
                   "a default of the paradigm changed", "use another --out")
    assert snapshot(out) == before

    monkeypatch.undo()
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", out)
    assert code == 0, err
    assert snapshot(out) == before  # resumed: nothing rerun, the same results


def test_other_options_given_are_named_as_the_options(capsys, echo_registry, tmp_path):
    out = tmp_path / "echo"
    assert vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "weight=2", "--out", out)[0] == 0
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--paradigm-opt", "weight=3", "--out", out)
    one_line_error(code, err, "different configuration", "config.paradigm_options.weight: 3 now, 2 before")


def test_a_directory_written_before_the_settings_were_recorded_still_resumes(capsys, echo_registry, tmp_path):
    out = tmp_path / "echo"
    assert vdb(capsys, *BASE, "--mode", "echo", "--out", out)[0] == 0
    manifest = json.loads((out / "run.json").read_text())
    del manifest["config"]["paradigm_settings"]  # as written before the settings were recorded
    (out / "run.json").write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    before = snapshot(out)
    code, _, err = vdb(capsys, *BASE, "--mode", "echo", "--out", out)
    assert code == 0, err
    assert snapshot(out) == before  # accepted as unknown; the manifest is left as it was


def test_a_paradigm_may_state_its_settings_and_one_without_options_records_none(capsys, stated_registry, tmp_path):
    code, _, err = vdb(capsys, *BASE, "--mode", "stated-echo", "--paradigm-opt", "weight=2", "--out", tmp_path / "s")
    assert code == 0, err
    config = json.loads((tmp_path / "s" / "run.json").read_text())["config"]
    assert config["paradigm_settings"] == {"weight": 2.0, "scale": "linear"}

    code, _, err = vdb(capsys, *BASE, "--mode", "stated-echo", "--paradigm-opt", "broken=true", "--out", tmp_path / "b")
    one_line_error(code, err, "paradigm 'stated-echo'", "effective_options() returned list, expected a mapping")
    assert not (tmp_path / "b").exists()

    code, _, err = vdb(capsys, *BASE, "--mode", "closed-loop", "--conditions", "selfsplice", "--checkpoints", "1",
                       "--out", tmp_path / "c")
    assert code == 0, err
    assert "paradigm_settings" not in json.loads((tmp_path / "c" / "run.json").read_text())["config"]


def test_without_the_method_the_settings_are_the_options_given_over_the_plain_json_defaults():
    from vladrivebench._engine.sweep import ComponentSpec
    from vladrivebench._intervention.runs import paradigm_settings
    from vladrivebench.intervention import EffectiveOptions

    unset = object()

    class Defaults(Echo):
        def __init__(self, weight: float = 1.0, reserved: bool = False, levels=(0, 50), marker=unset, *, unit="words"):
            super().__init__(weight, reserved)

    class DefaultsPlugin:
        @hookimpl
        def register_paradigms(self, register):
            register("defaults", Defaults)

    registry = fakes.fake_registry(("defaults", DefaultsPlugin()))
    spec = ComponentSpec("paradigm", "defaults", {"weight": 2})
    paradigm = registry.create("paradigm", "defaults", {"weight": 2})
    assert not isinstance(paradigm, EffectiveOptions)
    assert paradigm_settings(paradigm, registry, spec) == {"weight": 2, "reserved": False, "levels": [0, 50],
                                                           "unit": "words"}  # the sentinel is left out
