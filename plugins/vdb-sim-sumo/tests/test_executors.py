"""Parallel safety: libsumo runs one simulation per process. The ``process`` executor gives every worker its
own process and simulator; the ``sequential`` executor reuses one simulator for all episodes (SUMO is started
once and reloaded for each episode). Both write byte-identical episode logs."""

from __future__ import annotations

import libsumo
import vdb_model_scripted.plugin
import vdb_sim_sumo.plugin
from sumo_episodes import suite_scenario
from vdb_sim_sumo import simulator as simulator_module
from vladrivebench.executors import SequentialExecutor
from vladrivebench.testing import ComponentSpec, Registry, RunConfig, build, core_plugin, run_sweep
from vladrivebench.world import parse_scenario

SCENARIOS = ("P.4", "TL.1-red")


def short(scenario_id: str, seconds: float = 6.0):
    scenario = suite_scenario(scenario_id)
    return parse_scenario(dict(scenario.to_json(), max_time_s=seconds), scenario.source)


def config(cache: str) -> RunConfig:
    options = {"render": False, "cache_dir": cache, "background_vehicles_per_hour": 1200.0,
               "background_warmup_s": 10.0}
    return RunConfig(ComponentSpec("model", "scripted", {}), ComponentSpec("simulator", "sumo", options),
                     ComponentSpec("controller", "pid", {}), tuple(short(s) for s in SCENARIOS), (0, 1))


def registry() -> Registry:
    return Registry([core_plugin(), ("sumo", vdb_sim_sumo.plugin),
                     ("scripted", vdb_model_scripted.plugin)], entry_points=False)


def logs(summary) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((summary.out / "episodes").glob("*.mcap"))}


def test_process_and_sequential_executors_give_the_same_episodes(tmp_path, net_cache, monkeypatch):
    built, calls = [], {"start": 0, "load": 0}
    original_init = simulator_module.SumoSimulator.__init__

    def counting_init(self, *args, **kwargs):
        built.append(self)
        original_init(self, *args, **kwargs)

    for name in calls:
        real = getattr(libsumo, name)

        def counted(*args, _name=name, _real=real, **kwargs):
            calls[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(libsumo, name, counted)
    monkeypatch.setattr(simulator_module.SumoSimulator, "__init__", counting_init)
    sequential = run_sweep(config(net_cache), tmp_path / "sequential", executor=SequentialExecutor(),
                           registry=registry())
    assert sequential.failures == {} and len(sequential.results) == 4
    assert len(built) == 1  # one simulator for the four episodes ...
    assert calls == {"start": 1, "load": 3}  # ... SUMO started once, reloaded for each further episode
    monkeypatch.undo()
    parallel = run_sweep(config(net_cache), tmp_path / "process", executor=build("executor", "process", workers=2),
                         registry=registry())
    assert parallel.failures == {} and len(parallel.results) == 4
    assert logs(parallel) == logs(sequential)
    assert any(r["collisions"] == 0 for r in sequential.results.values())


def test_the_sequential_sweep_leaves_the_process_free_for_another_simulation(tmp_path, net_cache, sumo_sim):
    run_sweep(config(net_cache), tmp_path / "run", executor=SequentialExecutor(), registry=registry())
    assert sumo_sim().reset(suite_scenario("BASE"), 0).step == 0  # the sweep closed its simulator
