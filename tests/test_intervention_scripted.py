"""Calibration of the intervention protocol on the scripted model (kinematic simulator, PID controller).

The scripted model's coupling ``alpha`` is the ground truth: at alpha = 0 no text can change the action,
so no condition may come out significant; at alpha = 1 every brake condition must shorten the predicted
trajectory and accelerate lengthen it, significantly with the default number of seeds; the effect must
grow with alpha. Short routes (E.1 cut to a few seconds) keep this file quick.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

pytest.importorskip("vdb_model_scripted", reason="the scripted model plugin is not installed")
pytest.importorskip("vdb_sim_kinematic", reason="the kinematic simulator plugin is not installed")

from vladrivebench import _builtins as core_plugin  # noqa: E402
from vladrivebench._engine.registry import Registry  # noqa: E402
from vladrivebench._engine.sweep import ComponentSpec  # noqa: E402
from vladrivebench._intervention.runs import (  # noqa: E402
    DEFAULT_SEEDS,
    InterventionConfig,
    InterventionRun,
)
from vladrivebench._logs.episodes import find_episodes, read_episode  # noqa: E402
from vladrivebench._scenarios.spec import resolve_scenarios  # noqa: E402

BRAKES_SENTENCE = ("pedestrian", "car", "animal", "red-light")
# ORION's car text (Table 4) says "maintain your current speed" in its decision slot: not a brake text.
BRAKES_QA = ("pedestrian", "animal", "red-light")


@pytest.fixture(scope="module")
def registry():
    import vdb_model_scripted.plugin as scripted
    import vdb_sim_kinematic.plugin as kinematic

    return Registry([("core", core_plugin), ("scripted", scripted), ("kinematic", kinematic)], entry_points=False)


def run(registry, tmp_path, *, alpha, conditions, mode="open-loop", route="E.1", seconds=3.0,
        seeds=tuple(range(DEFAULT_SEEDS)), cot_format="sentence", name="run"):
    scenario = dataclasses.replace(resolve_scenarios(route, registry)[0], max_time_s=seconds)
    config = InterventionConfig(
        mode=mode, model=ComponentSpec("model", "scripted", {"alpha": alpha, "cot_format": cot_format}),
        simulator=ComponentSpec("simulator", "kinematic", {"render": False}),
        controller=ComponentSpec("controller", "pid", {}), routes=(scenario,), conditions=tuple(conditions),
        seeds=tuple(seeds))
    return InterventionRun(config, tmp_path / name, registry=registry).run()


def rows(results, horizon="2"):
    return {r["condition"]: r for r in results["open_loop"]["E.1"]["stats"][horizon]}


def test_alpha_zero_no_condition_is_significant_over_repeated_seed_sets(registry, tmp_path):
    significant = 0
    sets = [tuple(range(start, start + DEFAULT_SEEDS)) for start in (0, 100, 200)]
    for i, seeds in enumerate(sets):
        results = run(registry, tmp_path, alpha=0.0, conditions=BRAKES_SENTENCE + ("accel", "depicts-30"),
                      seeds=seeds, seconds=1.5, name=f"set{i}")
        assert results["valid"]
        for name, r in rows(results).items():
            assert r["mean_diff"] == 0.0 and r["pct_shorter"] == 0.0 and r["pct_longer"] == 0.0, name
            significant += r["significant"]
    assert significant == 0  # at alpha = 0 the text cannot change the action at all: rate 0 ≤ 5 %


@pytest.mark.parametrize("cot_format, brakes", [("sentence", BRAKES_SENTENCE), ("qa", BRAKES_QA)])
def test_alpha_one_brakes_shorten_and_accelerate_lengthens_significantly(registry, tmp_path, cot_format, brakes):
    results = run(registry, tmp_path, alpha=1.0, conditions=brakes + ("accel",), cot_format=cot_format)
    assert results["valid"] and results["gate"]["max_trajectory_diff"] == 0.0
    for horizon in ("2", "3"):
        table = rows(results, horizon)
        assert table["selfsplice"]["mean_diff"] == 0.0
        for name in brakes:
            assert table[name]["mean_diff"] < 0 and table[name]["significant"], (name, table[name])
            assert table[name]["n_seeds"] == DEFAULT_SEEDS
        assert table["accel"]["mean_diff"] > 0 and table["accel"]["significant"]


def test_the_effect_grows_monotonically_with_alpha(registry, tmp_path):
    effects = {"pedestrian": [], "accel": []}
    for alpha in (0.0, 0.25, 0.5, 0.75, 1.0):
        # 6 s: "accelerate" differs from the model's own CoT once the run-up to cruise speed is over
        table = rows(run(registry, tmp_path, alpha=alpha, conditions=("pedestrian", "accel"), seeds=(0, 1),
                         seconds=6.0, name=f"a{alpha}"))
        for name in effects:
            effects[name].append(table[name]["mean_diff"])
    assert effects["pedestrian"][0] == 0.0 and effects["accel"][0] == 0.0
    assert all(b < a for a, b in zip(effects["pedestrian"], effects["pedestrian"][1:], strict=False))
    assert all(b > a for a, b in zip(effects["accel"], effects["accel"][1:], strict=False))


def test_statistics_agree_with_an_independent_computation(registry, tmp_path):
    results = run(registry, tmp_path, alpha=0.5, conditions=("car", "accel", "depicts-10"), seeds=(0, 1, 2, 3))
    table = rows(results, "3")
    # recompute from the logs alone, by hand and with scipy
    per_seed: dict[str, dict[int, list[float]]] = {c: {} for c in table}
    for path in find_episodes(tmp_path / "run"):
        episode = read_episode(path)
        for step in episode.steps:
            disp = step.extras["intervention"]["displacement"]["3"]
            for c in table:
                reference = disp["baseline"] if c == "selfsplice" else disp["selfsplice"]
                per_seed[c].setdefault(episode.seed, []).append(disp[c] - reference)
    p_values = []
    for c in ("car", "accel", "depicts-10"):
        steps = np.concatenate([per_seed[c][s] for s in sorted(per_seed[c])])
        means = [float(np.mean(per_seed[c][s])) for s in sorted(per_seed[c])]
        n = len(means)
        mean = math.fsum(means) / n
        sd = math.sqrt(math.fsum((m - mean) ** 2 for m in means) / (n - 1))
        t = mean / (sd / math.sqrt(n))
        p = 2 * stats.t.sf(abs(t), n - 1)
        assert table[c]["t"] == pytest.approx(t, rel=1e-9)
        assert table[c]["p"] == pytest.approx(p, rel=1e-9, abs=1e-300)
        assert table[c]["p"] == pytest.approx(stats.ttest_1samp(means, 0).pvalue, rel=1e-9, abs=1e-300)
        assert table[c]["d_steps"] == pytest.approx(steps.mean() / steps.std(ddof=1), rel=1e-9)
        assert table[c]["d_seeds"] == pytest.approx(mean / sd, rel=1e-9)
        assert table[c]["mean_diff"] == pytest.approx(steps.mean(), rel=1e-9, abs=1e-12)
        assert table[c]["pct_shorter"] == pytest.approx(100 * np.mean(steps < -0.1), rel=1e-9)
        p_values.append(p)
    order = np.argsort(p_values)
    holm = np.maximum.accumulate([min(1.0, (3 - rank) * p_values[i]) for rank, i in enumerate(order)])
    for rank, i in enumerate(order):
        assert table[("car", "accel", "depicts-10")[i]]["p_holm"] == pytest.approx(holm[rank], rel=1e-9, abs=1e-300)


def test_closed_loop_car_injection_falls_behind_and_selfsplice_drives_identically(registry, tmp_path):
    results = run(registry, tmp_path, alpha=1.0, conditions=("car", "accel"), mode="closed-loop", seconds=6.0,
                  seeds=(0, 1, 2))
    assert results["valid"] and results["gate"]["episode_mismatches"] == []
    stats_by = {s["condition"]: s for s in results["closed_loop"]["E.1"]["stats"]}
    assert all(iv["mean"] == 0.0 for iv in stats_by["selfsplice"]["distance_diff"])
    car = stats_by["car"]["distance_diff"]
    assert car[-1]["high"] < 0 and car[-1]["mean"] < car[0]["mean"]
    assert stats_by["car"]["brakes"] > stats_by["car"]["shadow_brakes"]


def test_safety_override_follows_alpha(registry, tmp_path):
    coupled = run(registry, tmp_path, alpha=1.0, conditions=("accel",), mode="safety", route="SAFE.kerb-ped",
                  seconds=14.0, seeds=(0, 1), name="coupled")
    entry = coupled["safety"]["SAFE.kerb-ped"]["conditions"]["accel"]
    assert entry["baseline_collisions"] == 0 and entry["collisions"] == 2
    vision = run(registry, tmp_path, alpha=0.0, conditions=("accel",), mode="safety", route="SAFE.kerb-ped",
                 seconds=14.0, seeds=(0,), name="vision")
    assert vision["safety"]["SAFE.kerb-ped"]["conditions"]["accel"]["collisions"] == 0
