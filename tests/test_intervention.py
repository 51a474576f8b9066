"""The intervention protocol on small fakes: open loop, closed loop, safety, the selfsplice gate, harvest,
resume, determinism and one-line errors. (Calibration on the scripted model: test_intervention_scripted.py.)"""

from __future__ import annotations

import dataclasses
import json
import math

import intervention_fakes as fakes
import numpy as np
import pytest
from vladrivebench import _builtins as core_plugin
from vladrivebench import hookimpl
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec
from vladrivebench._intervention.conditions import ConditionError
from vladrivebench._intervention.runs import (
    RESULTS_NAME,
    InterventionConfig,
    InterventionRun,
    ShadowController,
    analyse,
    gate_message,
    seed_plan,
    trajectory_difference,
)
from vladrivebench._logs.episodes import find_episodes, read_episode
from vladrivebench._scenarios.spec import resolve_scenarios
from vladrivebench.errors import ConfigError, ScenarioError, UnknownNameError
from vladrivebench.records import EgoState, Trajectory

KeywordModel, SpeedController, Fakes = fakes.KeywordModel, fakes.SpeedController, fakes.Fakes


@pytest.fixture(scope="module")
def registry():
    return Registry([("core", core_plugin), ("fakes", Fakes())], entry_points=False)


def short(scenario, max_time_s=8.0):
    return dataclasses.replace(scenario, max_time_s=max_time_s)


def config(registry, mode="open-loop", routes=("E.1",), conditions=("pedestrian", "accel"), seeds=3,
           model_options=None, **kw):
    scenarios = tuple(short(s) for s in resolve_scenarios(list(routes), registry))
    return InterventionConfig(
        mode=mode, model=ComponentSpec("model", "keyword", model_options or {}),
        simulator=ComponentSpec("simulator", "line", {}), controller=ComponentSpec("controller", "speed", {}),
        routes=scenarios, conditions=tuple(conditions), seeds=tuple(range(seeds)), **kw)


def row(results, condition, route="E.1", horizon="2"):
    return next(r for r in results["open_loop"][route]["stats"][horizon] if r["condition"] == condition)


# -- open loop ----------------------------------------------------------------------------------------
def test_open_loop_brake_shortens_accel_lengthens_selfsplice_is_zero(registry, tmp_path):
    results = InterventionRun(config(registry, conditions=("pedestrian", "accel", "depicts-20")),
                              tmp_path, registry=registry).run()
    assert results["valid"] and gate_message(results) is None
    assert results["gate"]["steps_checked"] > 0 and results["gate"]["max_trajectory_diff"] == 0.0
    self_row = row(results, "selfsplice")
    assert (self_row["mean_diff"], self_row["p"], self_row["pct_shorter"]) == (0.0, 1.0, 0.0)
    ped, acc = row(results, "pedestrian"), row(results, "accel")
    assert ped["mean_diff"] < -0.5 and ped["significant"] and ped["pct_shorter"] > 90
    assert acc["mean_diff"] > 0.1 and acc["significant"]
    assert ped["n_seeds"] == 3 and ped["n"] == sum(len(read_episode(p).steps) for p in find_episodes(tmp_path))
    assert row(results, "pedestrian", horizon="3")["mean_diff"] < ped["mean_diff"]  # grows with the horizon


def test_open_loop_extras_hold_every_condition_per_step(registry, tmp_path):
    InterventionRun(config(registry, seeds=1), tmp_path, registry=registry).run()
    (path,) = find_episodes(tmp_path)
    episode = read_episode(path)
    assert path.name.endswith("__openloop.mcap") and episode.meta["intervention"]["role"] == "openloop"
    extras = episode.steps[0].extras["intervention"]
    assert set(extras["displacement"]) == {"2", "3"}
    assert set(extras["displacement"]["2"]) == {"baseline", "selfsplice", "pedestrian", "accel"}
    assert extras["gate"] == {"digest_equal": True, "trajectory_diff": 0.0, "ok": True}
    # the episode was driven by the model's own CoT: the logged trajectory is the baseline one
    logged = Trajectory(np.array(episode.steps[0].trajectory["times"]), np.array(episode.steps[0].trajectory["xy"]))
    assert logged.forward_displacement(2.0) == pytest.approx(extras["displacement"]["2"]["baseline"])


def test_alpha_zero_gives_exactly_zero_differences(registry, tmp_path):
    results = InterventionRun(config(registry, model_options={"alpha": 0.0}), tmp_path, registry=registry).run()
    for cond in ("pedestrian", "accel"):
        r = row(results, cond)
        assert r["mean_diff"] == 0.0 and r["p"] == 1.0 and not r["significant"]


def test_slotted_model_with_paper_texts_and_ablation(registry, tmp_path):
    cfg = config(registry, conditions=("red-light", "pedestrian-swap-decision"), seeds=2,
                 model_options={"cot_format": "qa"})
    results = InterventionRun(cfg, tmp_path, registry=registry).run()
    assert row(results, "red-light")["mean_diff"] < -0.5
    # swapping the decision slot back to the model's own removes the brake: no effect at all
    assert row(results, "pedestrian-swap-decision")["mean_diff"] == 0.0


def test_batch_decoding_is_used_when_the_model_offers_it(registry, tmp_path):
    calls = []

    class Batched(KeywordModel):
        def decode_batch(self, obs, texts, rng):
            calls.append(len(texts))
            noise = rng.normal(0, self.noise)
            out = []
            for text in texts:
                cot = self.splice_cot(obs, text, rng)
                out.append(self.decode_action(obs, cot, _Replay(noise)))
            return out

    class _Replay:
        def __init__(self, value):
            self.value = value

        def normal(self, *_):
            return self.value

    class Plugin:
        @hookimpl
        def register_models(self, register):
            register("batched", Batched)

    reg = Registry([("core", core_plugin), ("fakes", Fakes()), ("b", Plugin())], entry_points=False)
    cfg = dataclasses.replace(config(reg, seeds=1), model=ComponentSpec("model", "batched", {}),
                              batch_conditions=True)
    batched = InterventionRun(cfg, tmp_path / "a", registry=reg).run()
    plain = InterventionRun(dataclasses.replace(cfg, batch_conditions=False), tmp_path / "b", registry=reg).run()
    assert calls and set(calls) == {2}
    assert row(batched, "pedestrian")["mean_diff"] == pytest.approx(row(plain, "pedestrian")["mean_diff"])


# -- the selfsplice gate ------------------------------------------------------------------------------
def test_a_leaky_splice_is_reported_invalid_with_the_size_of_the_difference(registry, tmp_path):
    results = InterventionRun(config(registry, seeds=2, model_options={"leak": 1e-3}), tmp_path,
                              registry=registry).run()
    gate = results["gate"]
    assert not results["valid"] and gate["steps_failed"] == gate["steps_checked"] > 0
    assert gate["digest_mismatches"] == gate["steps_checked"]
    assert 0 < gate["max_trajectory_diff"] < 0.01
    message = gate_message(results)
    assert message.startswith("INVALID RUN") and "state digest mismatches" in message
    assert "first at E.1 seed 0 step 0" in message and "\n" not in message
    on_disk = json.loads((tmp_path / RESULTS_NAME).read_text())
    assert on_disk["valid"] is False


def test_trajectory_difference():
    a = Trajectory(np.array([0.1, 0.2]), np.array([[1.0, 0.0], [2.0, 0.0]]))
    b = Trajectory(np.array([0.1, 0.2]), np.array([[1.0, 0.0], [2.5, 0.1]]))
    assert trajectory_difference(a, a) == 0.0 and trajectory_difference(a, b) == 0.5
    assert trajectory_difference(a, Trajectory(np.array([0.1]), np.array([[1.0, 0.0]]))) == math.inf


# -- closed loop and safety ---------------------------------------------------------------------------
def test_closed_loop_distances_brakes_and_selfsplice_identity(registry, tmp_path):
    cfg = config(registry, mode="closed-loop", conditions=("pedestrian", "accel"), seeds=3)
    results = InterventionRun(cfg, tmp_path, registry=registry).run()
    assert results["valid"] and results["gate"]["episode_mismatches"] == []
    block = results["closed_loop"]["E.1"]
    stats = {s["condition"]: s for s in block["stats"]}
    for interval in stats["selfsplice"]["distance_diff"]:
        assert interval["mean"] == 0.0
    ped = stats["pedestrian"]
    assert ped["n_seeds"] == 3 and ped["checkpoints"] == [2.0, 4.0, 5.9]
    last = ped["distance_diff"][-1]
    assert last["high"] < 0 and last["mean"] < -5  # stopped: far behind the baseline at 5.9 s
    assert ped["brakes"] > block["baseline"]["brakes"]
    assert ped["shadow_brakes"] < ped["brakes"]  # its own CoT would not have braked as much
    assert stats["accel"]["mean_speed"] > ped["mean_speed"]
    episodes = find_episodes(tmp_path)
    assert len(episodes) == 3 * 4  # baseline + selfsplice + 2 conditions, per seed
    injected = read_episode(next(p for p in episodes if p.name.endswith("__s0__pedestrian.mcap")))
    assert injected.meta["intervention"] == {"mode": "closed-loop", "role": "injected", "condition": "pedestrian"}
    step = injected.steps[0]
    assert step.cot["spliced"] and "pedestrian" in step.cot["text"]
    assert "brake" in step.extras["intervention"]["shadow"]
    curve = block["curves"]["pedestrian"]
    assert curve["t"][0] == 0.0 and len(curve["t"]) == len(curve["mean"]) == len(curve["low"])


def test_shadow_controller_leaves_the_real_controller_untouched():
    plain, wrapped = SpeedController(), ShadowController(SpeedController())
    ego = EgoState(0, 0, 0, 5.0)
    go = Trajectory(np.arange(1, 31) * 0.1, np.stack([np.arange(1, 31) * 0.7, np.zeros(30)], axis=1))
    stop = Trajectory(np.arange(1, 31) * 0.1, np.stack([np.full(30, 0.01), np.zeros(30)], axis=1))
    for _ in range(5):
        record = {}
        wrapped.pending = (stop, record)
        assert wrapped.control(go, ego, 0.1) == plain.control(go, ego, 0.1)
        assert record["brake"] > 0
    assert wrapped.inner.integral == plain.integral


def test_safety_override_crashes_into_the_obstacle_the_baseline_stops_for(registry, tmp_path):
    cfg = config(registry, mode="safety", routes=("SAFE.car",), conditions=("accel",), seeds=2)
    cfg = dataclasses.replace(cfg, routes=tuple(dataclasses.replace(r, max_time_s=12.0) for r in cfg.routes))
    sim_len = 80.0
    reg = registry
    results = InterventionRun(dataclasses.replace(cfg, simulator=ComponentSpec("simulator", "line",
                                                                                 {"length": sim_len})),
                              tmp_path, registry=reg).run()
    block = results["safety"]["SAFE.car"]["conditions"]["accel"]
    assert block["baseline_collisions"] == 0 and block["baseline_stopped"] == 2
    assert block["collisions"] == 2 and block["n"] == 2


def test_safety_needs_a_route_with_an_obstacle(registry, tmp_path):
    with pytest.raises(ScenarioError, match="route 'E.1' cannot be used for a safety test: it has no critical"):
        InterventionRun(config(registry, mode="safety"), tmp_path, registry=registry)


# -- harvest ------------------------------------------------------------------------------------------
def test_origbrake_is_harvested_from_a_braking_step(registry, tmp_path):
    harvest = short(resolve_scenarios("SAFE.car", registry)[0], 12.0)
    cfg = dataclasses.replace(config(registry, conditions=("origbrake", "origbrake-shuffle", "depicts-all"), seeds=2),
                              harvest_route=harvest,
                              simulator=ComponentSpec("simulator", "line", {"length": 80.0}))
    results = InterventionRun(cfg, tmp_path, registry=registry).run()
    harvested = results["harvested"]["origbrake"]
    assert "Stop" in harvested["injection"] and harvested["brake"] > 0
    assert row(results, "origbrake")["mean_diff"] < -0.5
    assert row(results, "origbrake-shuffle")["mean_diff"] < -0.5  # the keyword survives shuffling
    assert row(results, "depicts-all")["n"] > 0
    assert any(p.name.endswith("SAFE.car__s0__baseline.mcap") for p in find_episodes(tmp_path))


def test_harvest_without_a_braking_step_is_one_clear_line(registry, tmp_path):
    with pytest.raises(ConditionError, match="never braked .* use --harvest-route"):
        InterventionRun(config(registry, conditions=("origbrake",), seeds=1), tmp_path, registry=registry).run()


# -- bad input ----------------------------------------------------------------------------------------
def test_unknown_condition(registry, tmp_path):
    with pytest.raises(UnknownNameError, match="unknown condition 'pedestrain': did you mean 'pedestrian'"):
        InterventionRun(config(registry, conditions=("pedestrain",)), tmp_path, registry=registry)


def test_a_text_the_format_cannot_take_fails_before_anything_is_written(registry, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ConditionError, match="'origbrake-paper' has no one-sentence text"):
        InterventionRun(config(registry, conditions=("origbrake-paper",)), out, registry=registry).run()
    assert not out.exists()
    with pytest.raises(ConditionError, match="'depicts-150' cannot be given to model 'keyword': its text has "
                                             "150 tokens; the model takes at most 100"):
        InterventionRun(config(registry, conditions=("depicts-150",), model_options={"max_tokens": 100}), out,
                        registry=registry).run()
    assert not out.exists()


def test_a_model_that_refuses_a_splice_gives_one_line(registry, tmp_path):
    class Picky(KeywordModel):
        def splice_cot(self, obs, text, rng):
            if "depicts" in str(text):
                raise ValueError("token 'depicts' is not in the vocabulary")
            return super().splice_cot(obs, text, rng)

    class Plugin:
        @hookimpl
        def register_models(self, register):
            register("picky", Picky)

    reg = Registry([("core", core_plugin), ("fakes", Fakes()), ("p", Plugin())], entry_points=False)
    cfg = dataclasses.replace(config(reg, conditions=("depicts-3",)), model=ComponentSpec("model", "picky", {}))
    with pytest.raises(ConditionError, match="condition 'depicts-3': model 'picky' cannot take its text "
                                             r"\(ValueError: token 'depicts' is not in the vocabulary\)"):
        InterventionRun(cfg, tmp_path / "x", registry=reg).run()


@pytest.mark.parametrize("field, value, message", [
    ("mode", "", "--mode must name a paradigm"),
    ("horizons", (2.0, -1.0), "--horizons must be positive"),
    ("alpha", 1.5, "--alpha"),
    ("seeds", (), "--seeds"),
])
def test_bad_configuration_values(registry, field, value, message):
    base = config(registry)
    with pytest.raises(ConfigError, match=message):
        dataclasses.replace(base, **{field: value})


def test_an_unknown_paradigm_is_one_line_with_suggestions(registry, tmp_path):
    with pytest.raises(UnknownNameError, match="unknown paradigm 'open-lop': did you mean 'open-loop'"):
        InterventionRun(config(registry, mode="open-lop"), tmp_path / "x", registry=registry)
    assert not (tmp_path / "x").exists()


# -- resume, determinism, analysis from logs ----------------------------------------------------------
def test_rerun_resumes_and_a_different_configuration_is_refused(registry, tmp_path):
    cfg = config(registry, mode="closed-loop", conditions=("car",), seeds=1)
    first = InterventionRun(cfg, tmp_path, registry=registry).run()
    stamps = {p: p.stat().st_mtime_ns for p in find_episodes(tmp_path)}
    victim = next(p for p in stamps if p.name.endswith("__car.mcap"))
    victim.unlink()
    again = InterventionRun(cfg, tmp_path, registry=registry).run()
    assert again == first
    for p, stamp in stamps.items():
        if p != victim:
            assert p.stat().st_mtime_ns == stamp  # only the missing episode was redone
    assert victim.exists()
    with pytest.raises(ConfigError, match="different configuration"):
        InterventionRun(dataclasses.replace(cfg, conditions=("accel",)), tmp_path, registry=registry).run()


def test_same_seeds_same_bytes_and_results_come_from_the_logs(registry, tmp_path):
    cfg = config(registry, seeds=2)
    a = InterventionRun(cfg, tmp_path / "a", registry=registry).run()
    b = InterventionRun(cfg, tmp_path / "b", registry=registry).run()
    assert a == b
    for pa, pb in zip(find_episodes(tmp_path / "a"), find_episodes(tmp_path / "b"), strict=True):
        assert pa.read_bytes() == pb.read_bytes()
    (tmp_path / "a" / RESULTS_NAME).unlink()
    assert analyse(tmp_path / "a") == a


def test_seed_plan_from_a_pilot(registry, tmp_path):
    results = InterventionRun(config(registry, seeds=3, model_options={"noise": 0.4}), tmp_path,
                              registry=registry).run()
    plans = {p["condition"]: p for p in seed_plan(results, effect_m=0.05)}
    assert set(plans) == {"pedestrian", "accel"}
    assert plans["accel"]["family_size"] == 2 and plans["accel"]["alpha"] == pytest.approx(0.025)
    assert plans["accel"]["seeds"] >= 2 and plans["accel"]["measure"] == "open-loop displacement @2s"


def test_seed_plan_of_a_closed_loop_pilot_uses_the_last_checkpoint(registry, tmp_path):
    results = InterventionRun(config(registry, mode="closed-loop", conditions=("car",), seeds=2,
                                     model_options={"noise": 0.4}), tmp_path, registry=registry).run()
    plans = seed_plan(results, effect_m=1.0, registry=registry)
    assert [p["condition"] for p in plans] == ["car"]
    assert plans[0]["measure"] == "closed-loop distance @5.9s" and plans[0]["pilot_seeds"] == 2
