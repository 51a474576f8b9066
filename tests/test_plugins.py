"""The plugin registry: isolation, duplicates, unknown names, option checking, strict loading."""

from __future__ import annotations

import types

import pytest
import vladrivebench
import vladrivebench.testing
from vladrivebench._engine.registry import Registry
from vladrivebench.errors import ConfigError, PluginLoadError, UnknownNameError
from vladrivebench.testing import isolated_registry


def make_plugin(**hooks) -> types.SimpleNamespace:
    """A plugin object whose attributes are hook implementations."""
    return types.SimpleNamespace(**{name: vladrivebench.hookimpl(fn) for name, fn in hooks.items()})


def toy_model(alpha: float = 0.5, *, label: str = "x"):
    return ("toy", alpha, label)


def models_plugin(*names):
    def register_models(register):
        for name in names:
            register(name, toy_model, description=f"model {name}")

    return make_plugin(register_models=register_models)


def test_components_are_collected_with_their_plugin():
    registry = Registry([("alpha", models_plugin("kv", "qa"))], entry_points=False)
    assert registry.names("model") == ["kv", "qa"]
    comp = registry.get("model", "kv")
    assert (comp.plugin, comp.description) == ("alpha", "model kv")
    assert registry.plugins[0].registered == {"model": ["kv", "qa"]}
    assert registry.create("model", "kv", {"alpha": 0.25}) == ("toy", 0.25, "x")


def test_unknown_name_suggests_close_matches_and_lists_available():
    registry = Registry([("alpha", models_plugin("kv", "qa", "scripted"))], entry_points=False)
    with pytest.raises(UnknownNameError) as info:
        registry.get("model", "scriptd")
    message = str(info.value)
    assert "did you mean 'scripted'?" in message
    assert "available: kv, qa, scripted" in message
    assert "\n" not in message


def test_duplicate_name_rejects_the_second_plugin_whole():
    registry = Registry(
        [("first", models_plugin("kv")), ("second", models_plugin("fresh", "kv"))], entry_points=False
    )
    second = next(p for p in registry.plugins if p.name == "second")
    assert second.status == "error"
    assert "'kv' is already registered by plugin 'first'" in second.error
    # nothing the failing plugin registered before the clash survives
    assert registry.names("model") == ["kv"]
    assert registry.get("model", "kv").plugin == "first"


def test_misspelt_hook_is_reported_and_others_keep_working():
    bad = make_plugin(register_model=lambda register: None)
    registry = Registry([("typo", bad), ("good", models_plugin("kv"))], entry_points=False)
    typo = next(p for p in registry.plugins if p.name == "typo")
    assert typo.status == "error" and "register_model" in typo.error
    assert registry.names("model") == ["kv"]


def test_plugin_raising_while_registering_is_isolated():
    def register_models(register):
        register("half", toy_model)
        raise RuntimeError("boom")

    registry = Registry([("raiser", make_plugin(register_models=register_models)),
                         ("good", models_plugin("kv"))], entry_points=False)
    raiser = next(p for p in registry.plugins if p.name == "raiser")
    assert raiser.status == "error" and "RuntimeError: boom" in raiser.error
    assert registry.names("model") == ["kv"]


def test_strict_loading_makes_a_failure_fatal():
    bad = make_plugin(register_model=lambda register: None)
    with pytest.raises(PluginLoadError, match="typo"):
        Registry([("typo", bad)], entry_points=False, strict=True)


def test_unknown_option_is_one_line_naming_the_accepted_ones():
    registry = Registry([("alpha", models_plugin("kv"))], entry_points=False)
    with pytest.raises(ConfigError) as info:
        registry.create("model", "kv", {"alpah": 1})
    assert str(info.value) == "model 'kv' does not take option 'alpah' (it takes: alpha, label)"


def test_factory_needing_a_missing_package_names_the_pip_command():
    def needs_torch():
        import vdb_package_that_does_not_exist  # noqa: F401

    def register_models(register):
        register("heavy", needs_torch)

    registry = Registry([("heavy", make_plugin(register_models=register_models))], entry_points=False)
    with pytest.raises(vladrivebench.errors.VdbError, match="pip install vdb_package_that_does_not_exist"):
        registry.create("model", "heavy")


def test_scenario_registration_records_paths(tmp_path):
    def register_scenarios(register):
        register(tmp_path, description="pack")

    registry = Registry([("pack", make_plugin(register_scenarios=register_scenarios))], entry_points=False)
    (comp,) = registry.components("scenario")
    assert comp.path == tmp_path


def test_isolated_registry_restores_the_previous_one():
    from vladrivebench._engine.registry import get_registry

    with isolated_registry(("alpha", models_plugin("kv"))):
        assert get_registry().names("model") == ["kv"]
    with isolated_registry():
        assert get_registry().names("model") == []


def test_factory_given_as_import_path_is_imported_on_first_use():
    def register_models(register):
        register("lazy", "fractions:Fraction", description="imported when built")

    registry = Registry([("lazy", make_plugin(register_models=register_models))], entry_points=False)
    assert registry.plugins[0].status == "ok"
    from fractions import Fraction

    assert registry.create("model", "lazy", {"numerator": 3, "denominator": 4}) == Fraction(3, 4)
    with pytest.raises(ConfigError, match="does not take option 'alpha'"):
        registry.create("model", "lazy", {"alpha": 1})


def test_malformed_import_path_fails_the_plugin():
    def register_models(register):
        register("bad", "no-colon-here")

    registry = Registry([("bad", make_plugin(register_models=register_models))], entry_points=False)
    assert registry.plugins[0].status == "error" and "package.module:attribute" in registry.plugins[0].error


class InlineExecutor:
    """Runs every job in the calling process, in reverse order (any order is allowed)."""

    in_process = True

    def __init__(self, workers: int = 1):
        self.workers = workers

    def run(self, worker, jobs):
        for job in reversed(list(jobs)):
            yield worker(job)


class ExecutorAndCommandPlugin:
    """A third-party plugin adding an executor and a ``vdb`` command."""

    @vladrivebench.hookimpl
    def register_executors(self, register):
        register("inline-reversed", InlineExecutor, description="in process, last job first")

    @vladrivebench.hookimpl
    def register_commands(self, cli):
        import click

        @cli.command("hello-plugin")
        @click.argument("name")
        def hello(name):
            """Greet NAME (a command a plugin added)."""
            if name == "nobody":
                raise vladrivebench.ConfigError("vdb hello-plugin: NAME must name somebody, got 'nobody'")
            click.echo(f"hello {name}")


def test_a_plugin_executor_runs_a_sweep_through_the_cli(tmp_path, capsys, runner_fakes, monkeypatch):
    from vladrivebench._scenarios import spec

    monkeypatch.setattr(spec, "resolve_scenarios", runner_fakes.fake_resolve_scenarios)
    with isolated_registry(("fakes", runner_fakes), ("mine", ExecutorAndCommandPlugin()), core=True) as registry:
        assert "inline-reversed" in registry.names("executor")
        code = vladrivebench.testing.run_cli(
            ["run", "--model", "echo", "--sim", "line", "--controller", "speed", "--scenarios", "road",
             "--seeds", "3", "--out", str(tmp_path), "--executor", "inline-reversed", "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert len(list((tmp_path / "episodes").glob("*.mcap"))) == 3


def test_a_plugin_command_is_added_to_vdb_and_its_errors_are_one_line(capsys):
    with isolated_registry(("mine", ExecutorAndCommandPlugin()), core=True):
        assert vladrivebench.testing.run_cli(["hello-plugin", "world"]) == 0
        assert capsys.readouterr().out == "hello world\n"
        assert vladrivebench.testing.run_cli(["hello-plugin", "nobody"]) == 2
    assert capsys.readouterr().err == "vdb: error: vdb hello-plugin: NAME must name somebody, got 'nobody'\n"
