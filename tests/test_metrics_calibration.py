"""Calibration: on the scripted model, whose error rates and CoT–action coupling α are known exactly, the
labeler + metrics pipeline recovers the rates within their confidence intervals. The labels equal the
model's recorded draws exactly; the configured rates lie within the Wilson intervals of the measured ones
(99.9 % for the test's five checks together; the tables print 95 %).

The scripted model (plugin ``vdb-model-scripted``) is driven open-loop along a fixed approach to one
critical feature (constant 5.5 m/s, 60 m → 0 m), so that the test takes seconds: each step's CoT and
trajectory come from the model with the pinned RNG streams, ``v_des`` from the PID controller, and the
model's own record of what it wrote (``cot_truth``) is the ground truth of every error draw.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from vdb_labeler_lexicon import plugin as lexicon_plugin
from vdb_model_scripted.model import cot_truth
from vdb_model_scripted.plugin import make_scripted
from vladrivebench import _builtins as builtins
from vladrivebench._analysis.tables import wilson_interval
from vladrivebench._builtins.controllers import PIDController
from vladrivebench._builtins.metrics import (
    AlignmentByDistance,
    ContradictionRate,
    HallucinationRate,
    LightAccuracy,
    MentionRate,
)
from vladrivebench._cli.main import main
from vladrivebench._engine.rng import step_rng
from vladrivebench._logs.episodes import EpisodeWriter
from vladrivebench.records import Actor, EgoState, GroundTruth, Observation
from vladrivebench.testing import isolated_registry

SPEED, START, STEPS, SEEDS = 5.5, 60.0, 110, 3
RATES = {"miss_rate": 0.3, "hallucination_rate": 0.2, "contradiction_rate": 0.1, "light_error_rate": 0.25}
FEATURES = {  # kind → (group, actor lateral offset, light state)
    "pedestrian": ("Pedestrian (in-lane)", 0.0, None),
    "traffic_light": ("Traffic light (red)", -5.0, "red"),
}


def observation(step: int, kind: str) -> Observation:
    group, lateral, light = FEATURES[kind]
    x = step * SPEED * 0.1
    target = Actor("target", kind, START, lateral, state=light)
    truth = GroundTruth(step=step, time=step * 0.1, actors=(target,), critical_id="target", critical_kind=kind,
                        distance_to_critical=START - x, blocking=kind == "pedestrian", light_state=light,
                        lead_gap=START - x if kind == "pedestrian" else None,
                        lead_speed=0.0 if kind == "pedestrian" else None,
                        route_ahead=tuple((float(i), 0.0) for i in range(51)))
    return Observation(step, step * 0.1, np.zeros((1, 1, 3), np.uint8), EgoState(x, 0.0, 0.0, SPEED),
                       "follow_lane", truth, kind)


def drive(directory: Path, options: dict, kind: str, seed: int) -> list[dict]:
    """Log one open-loop approach; return the model's truth of every step."""
    model = make_scripted(**options)
    controller = PIDController()
    model.reset(seed)
    controller.reset()
    group = FEATURES[kind][0]
    meta = {"episode_id": f"{kind}-{seed}", "seed": seed,
            "model": {"name": "scripted", "options": options, "cot_format": {"kind": options["cot_format"]}},
            "scenario": {"id": kind, "group": group, "family": kind}}
    truths = []
    with EpisodeWriter(directory / f"{options['cot_format']}-{kind}-{seed}.mcap", meta) as writer:
        for step in range(STEPS):
            obs = observation(step, kind)
            cot = model.generate_cot(obs, step_rng(seed, step, "cot"))
            trajectory = model.decode_action(obs, cot, step_rng(seed, step, "action"))
            writer.write_step(obs, cot, trajectory, controller.control(trajectory, obs.ego, 0.1))
            truths.append(cot_truth(cot))
        writer.finish({"terminal": "timeout", "steps": STEPS})
    return truths


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    directory = tmp_path_factory.mktemp("calibration")
    truths = []
    for first_seed, cot_format in ((0, "sentence"), (SEEDS, "qa")):  # distinct seeds: independent draws
        for kind in FEATURES:
            for seed in range(first_seed, first_seed + SEEDS):
                truths += drive(directory, {"alpha": 0.5, "cot_format": cot_format, **RATES}, kind, seed)
    with isolated_registry(("core", builtins), ("lexicon", lexicon_plugin)):
        assert main(["label", str(directory), "--quiet"]) == 0
    from vladrivebench._analysis.dataset import load_dataset

    return load_dataset(directory), truths


def pooled(table, rows=None):
    """Successes and observations over every cell of a zone table (value × count summed)."""
    k = n = 0
    for row in table.rows:
        if rows is None or row.labels[0] in rows:
            for cell in row.cells:
                if cell.value is not None:
                    k += round(cell.value * cell.count)
                    n += cell.count
    return k, n


Z_FAMILY = 3.2905  # two-sided 99.9 %: five rate checks, family-wise false alarm ≤ 0.5 % (95 % each: ~23 %)


def assert_recovered(k: int, n: int, rate: float, what: str) -> None:
    low, high = wilson_interval(k, n, z=Z_FAMILY)
    assert low <= rate <= high, f"{what}: {k}/{n} = {k / n:.3f}, 99.9 % CI [{low:.3f}, {high:.3f}] misses {rate}"


def test_mention_rate_recovers_one_minus_the_miss_rate(calibrated):
    dataset, truths = calibrated
    table = MentionRate().compute(dataset)[0]
    k, n = pooled(table)
    in_table = [t for t in truths if t["mentioned"] is not None]
    assert n == len(in_table) and k == sum(t["mentioned"] for t in in_table)  # the labels are the draws
    assert_recovered(k, n, 1 - RATES["miss_rate"], "mention rate")


def test_hallucination_rate_recovers_the_configured_rate(calibrated):
    dataset, truths = calibrated
    k, n = pooled(HallucinationRate().compute(dataset)[0])
    assert k == sum(t["hallucinated"] for t in truths)
    assert_recovered(k, n, RATES["hallucination_rate"], "hallucination rate")


def test_contradiction_rate_recovers_the_configured_rate_per_format(calibrated):
    dataset, truths = calibrated
    (table,) = ContradictionRate().compute(dataset)
    assert {row.labels[1] for row in table.rows} == {"sentence", "qa"}
    for row in table.rows:
        cell = row.cells[1]
        assert_recovered(round(cell.value * cell.count), cell.count, RATES["contradiction_rate"], str(row.labels))
        assert cell.low < cell.value < cell.high  # the table's own 95 % interval
    assert sum(round(r.cells[1].value * r.cells[1].count) for r in table.rows) == sum(t["contradiction"] for t in truths)


def test_light_accuracy_recovers_one_minus_the_light_error_rate(calibrated):
    dataset, _ = calibrated
    table = LightAccuracy().compute(dataset)[0]
    k, n = pooled(table)
    assert n > 200
    assert_recovered(k, n, 1 - RATES["light_error_rate"], "light colour accuracy")


def test_alignment_rises_with_alpha_where_the_cot_misses_the_obstacle(tmp_path):
    """With a CoT that misses the pedestrian half the time, near the pedestrian the action head follows the
    CoT at α = 1 (aligned) and perception at α = 0 (it stops while the CoT says drive on: misaligned)."""
    from vladrivebench._analysis.dataset import load_dataset

    rates = {}
    for alpha in (0.0, 1.0):
        directory = tmp_path / f"a{alpha}"
        directory.mkdir()
        for seed in range(2):
            drive(directory, {"alpha": alpha, "cot_format": "sentence", "miss_rate": 0.5, "noise": 0.0},
                  "pedestrian", seed)
        with isolated_registry(("core", builtins), ("lexicon", lexicon_plugin)):
            assert main(["label", str(directory), "--quiet"]) == 0
        table = next(t for t in AlignmentByDistance().compute(load_dataset(directory)) if t.id == "alignment_distance")
        rates[alpha] = [table.rows[0].cells[i].value for i in range(3)]
    far0, med0, near0 = rates[0.0]
    far1, med1, near1 = rates[1.0]
    assert min(med1, near1) >= 0.9
    assert max(med0, near0) <= 0.75 and med1 - med0 >= 0.25

