"""Bad input answers with one line (what, where, what is expected), never a traceback: SUMO missing or failing
to start, a scenario feature SUMO cannot represent, bad options, a second simulation in one process."""

from __future__ import annotations

import sys

import pytest
import vdb_model_scripted.plugin
import vdb_sim_sumo.plugin
from sumo_episodes import suite_scenario
from vdb_sim_sumo import session
from vdb_sim_sumo.session import SumoBusyError, SumoSession, SumoUnavailableError
from vladrivebench import ConfigError, ScenarioError, VdbError
from vladrivebench.testing import core_plugin, isolated_registry, run_cli
from vladrivebench.world import parse_scenario


def one_line(exc: BaseException) -> str:
    text = str(exc)
    assert "\n" not in text and "Traceback" not in text
    return text


def test_libsumo_missing_names_the_packages_to_install(monkeypatch, sumo_sim):
    monkeypatch.setitem(sys.modules, "libsumo", None)
    with pytest.raises(SumoUnavailableError) as caught:
        sumo_sim()
    assert "pip install eclipse-sumo libsumo" in one_line(caught.value)
    monkeypatch.undo()
    sumo_sim().close()  # the failed attempt did not keep the process's SUMO slot


def test_netconvert_missing_names_the_package_to_install(monkeypatch, tmp_path, sumo_sim):
    monkeypatch.setenv("SUMO_HOME", str(tmp_path))
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(session, "eclipse_sumo_home", lambda: None)
    with pytest.raises(SumoUnavailableError) as caught:
        sumo_sim()
    message = one_line(caught.value)
    assert "netconvert" in message and "pip install eclipse-sumo" in message


class FailingLibsumo:
    """Stands in for libsumo: SUMO writes why it failed on standard error and raises 'Process Error'."""

    def start(self, args):
        import os

        os.write(2, b"Error: Cannot load network 'broken.net.xml': premature end of file.\n")
        raise RuntimeError("Process Error")

    class simulation:
        @staticmethod
        def getTime():
            raise RuntimeError("not started")


def test_sumo_failing_to_start_is_one_line_with_sumos_own_reason(monkeypatch):
    monkeypatch.setattr(session, "import_libsumo", FailingLibsumo)
    owner = object.__new__(type("Owner", (), {}))
    started = SumoSession(owner)
    with pytest.raises(SumoUnavailableError) as caught:
        started.begin(["-n", "broken.net.xml"], "scenario broken.toml")
    message = one_line(caught.value)
    assert "scenario broken.toml" in message and "premature end of file" in message
    assert "pip install eclipse-sumo libsumo" in message
    started.close()


def test_an_unreadable_network_file_is_one_line(tmp_path, sumo_sim):
    net = tmp_path / "broken.net.xml"
    net.write_text("<net><edge id='a'", encoding="utf-8")
    with pytest.raises(ConfigError) as caught:
        sumo_sim(net_file=str(net), route="a")
    assert str(net) in one_line(caught.value)


def test_a_feature_sumo_cannot_represent_names_the_feature_and_the_file(sumo_sim):
    sim = sumo_sim(pedestrians="sumo")
    scenario = suite_scenario("P.6")  # a pedestrian walking along the ego's lane
    with pytest.raises(ScenarioError) as caught:
        sim.reset(scenario, 0)
    message = one_line(caught.value)
    assert str(scenario.source) in message and "motion:along" in message and "pedestrians=scripted" in message
    data = dict(scenario.to_json(), requires=["weather:rain"])
    with pytest.raises(ScenarioError) as caught:
        sim.reset(parse_scenario(data, "rain.toml"), 0)
    assert "rain.toml" in one_line(caught.value) and "'weather:rain'" in caught.value.args[0]


@pytest.mark.parametrize("options, expected", [
    ({"width": 0}, "option width must be a whole number between 8 and 4096"),
    ({"pedestrians": "crowd"}, "option pedestrians must be 'scripted' or 'sumo'"),
    ({"background_vehicles_per_hour": -5}, "option background_vehicles_per_hour must be a number between 0"),
    ({"net_file": "x.net.xml"}, "option net_file needs option route too"),
    ({"net_file": "/nonexistent/x.net.xml", "route": "a"}, "no such file /nonexistent/x.net.xml"),
])
def test_bad_options_are_one_line(options, expected, sumo_sim):
    with pytest.raises(ConfigError) as caught:
        sumo_sim(**options)
    assert expected in one_line(caught.value)


def test_a_second_simulation_in_one_process_is_refused_until_the_first_is_closed(sumo_sim):
    first = sumo_sim()
    first.reset(suite_scenario("BASE"), 0)
    with pytest.raises(SumoBusyError) as caught:
        sumo_sim()
    assert "--executor process" in one_line(caught.value)
    first.close()
    second = sumo_sim()
    assert second.reset(suite_scenario("BASE"), 0).step == 0


def test_vdb_run_reports_a_bad_sumo_option_on_one_line_with_status_2(tmp_path, capsys):
    plugins = (core_plugin(), ("sumo", vdb_sim_sumo.plugin),
               ("scripted", vdb_model_scripted.plugin))
    with isolated_registry(*plugins):
        code = run_cli(["run", "--model", "scripted", "--sim", "sumo", "--sim-opt", "pedestrians=crowd",
                         "--scenarios", "P.1", "--seeds", "1", "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("vdb: error: ") and "option pedestrians" in err[0]


@pytest.mark.parametrize("command", [["run", "--scenarios", "P.1", "--seeds", "2"],
                                     ["intervene", "--route", "E.1", "--mode", "closed-loop", "--seeds", "2"]])
def test_a_batch_needing_two_simulations_in_one_process_is_one_line_before_anything_is_written(tmp_path, capsys,
                                                                                             command, sumo_sim):
    plugins = (core_plugin(), ("sumo", vdb_sim_sumo.plugin), ("scripted", vdb_model_scripted.plugin))
    with isolated_registry(*plugins):
        code = run_cli([*command, "--model", "scripted", "--sim", "sumo", "--batch", "2",
                        "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and not (tmp_path / "run").exists()
    assert len(err) == 1 and err[0].startswith("vdb: error: --batch 2 runs each episode of a batch with its own "
                                               "simulator in one process, and a second simulator 'sumo' cannot")
    assert err[0].endswith("expected --batch 1 (and --executor process --workers N to run episodes in parallel)")
    sumo_sim().close()  # the refused command holds no simulation


def test_every_error_of_this_plugin_is_a_user_error():
    assert issubclass(SumoBusyError, VdbError) and issubclass(SumoUnavailableError, VdbError)
