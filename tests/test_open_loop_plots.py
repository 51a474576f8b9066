"""The open-loop paradigm's plots: displacement per condition against the horizon, and the per-step CDF."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from vladrivebench._builtins.paradigms.open_loop import displacement_plot, step_distribution_plot


def results(steps: dict[str, dict[str, list[float]]]) -> dict:
    """A minimal intervention.json of one route, two horizons, per-seed step differences by condition."""
    from statistics import mean

    stats = {}
    for h in ("2", "3"):
        scale = float(h) / 2
        stats[h] = [{"condition": c, "horizon_s": float(h), "n": sum(len(v) for v in by_seed.values()),
                     "mean_diff": mean(x * scale for v in by_seed.values() for x in v),
                     "seed_means": [mean(x * scale for x in v) for v in by_seed.values()]}
                    for c, by_seed in steps.items()]
    return {"conditions": list(steps), "open_loop": {"E.1": {"stats": stats, "steps": {
        h: {c: {s: [x * float(h) / 2 for x in v] for s, v in by_seed.items()} for c, by_seed in steps.items()}
        for h in ("2", "3")}}}}


STEPS = {"selfsplice": {"0": [0.0, 0.0], "1": [0.0, 0.0, 0.0]},
         "car": {"0": [-1.0, -2.0], "1": [-3.0, -1.5, -2.5]}}


def test_displacement_plot_has_a_series_per_condition_with_counts():
    plot = displacement_plot(results(STEPS))
    (title, series), = plot.panels
    assert title == "route E.1" and [s.label for s in series] == ["selfsplice", "car"]
    car = series[1]
    assert car.x == (2.0, 3.0) and car.counts == (5, 5)
    assert car.y[0] == pytest.approx(-2.0) and car.y[1] == pytest.approx(-3.0)
    assert car.low[0] < car.y[0] < car.high[0]  # the seed-level interval brackets the mean


def test_step_distribution_is_the_empirical_cdf_of_every_step_at_the_first_horizon():
    plot = step_distribution_plot(results(STEPS))
    (title, series), = plot.panels
    assert title == "route E.1, @2 s"
    car = series[1]
    assert car.x == (-3.0, -2.5, -2.0, -1.5, -1.0)
    assert car.y == (0.2, 0.4, 0.6, 0.8, 1.0) and car.counts == (5,) * 5
    assert series[0].x == (0.0,) * 5


def test_a_real_open_loop_run_reports_both_plots(tmp_path):
    """Built from a logged run's own intervention.json when one is at hand (the scripted model, 2 seeds)."""
    pytest.importorskip("vdb_sim_kinematic")
    pytest.importorskip("vdb_model_scripted")
    from vladrivebench.testing import run_cli

    out = tmp_path / "ol"
    assert run_cli(["intervene", "--model", "scripted", "--model-opt", "alpha=1", "--route", "E.1", "--mode",
                    "open-loop", "--conditions", "selfsplice,car", "--seeds", "2", "--out", str(out),
                    "--quiet"]) == 0
    data = json.loads(Path(out / "intervention.json").read_text())
    ids = [displacement_plot(data).id, step_distribution_plot(data).id]
    assert ids == ["intervention.open_loop_displacement", "intervention.open_loop_steps"]
    assert run_cli(["report", str(out), "--format", "md", "--out", str(tmp_path / "r.md")]) == 0
    assert "displacement difference per condition" in (tmp_path / "r.md").read_text()
