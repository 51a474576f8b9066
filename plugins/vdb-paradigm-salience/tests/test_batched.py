"""`vdb intervene --mode salience --batch B` on a batched model (kv): the same cells, the gate bit for bit."""

from __future__ import annotations

import json

import numpy as np
import pytest
from vladrivebench.testing import find_episodes, read_episode, run_cli

pytest.importorskip("vdb_model_neural", reason="the neural model plugin is not installed")

GRID = ["--paradigm-opt", "kinds=pedestrian,car", "--paradigm-opt", "offsets=0", "--paradigm-opt",
        "distances=66", "--paradigm-opt", "sizes=1", "--paradigm-opt", "max_time=6"]
RUN = ["intervene", "--model", "kv", "--controller", "mpc", "--route", "SAFE.centre-ped", "--mode", "salience",
       "--seeds", "2", "--quiet", *GRID]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("salience-batch")
    out = {}
    for batch in (1, 4):
        out[batch] = root / f"b{batch}"
        assert run_cli([*RUN, "--batch", str(batch), "--out", str(out[batch])]) == 0
    return out


def episodes(run_dir):
    return {(e.scenario_id, e.seed, e.meta["intervention"]["role"]): e for e in map(read_episode, find_episodes(run_dir))}


def test_batched_sweep_holds_the_gate_and_plans_the_same_episodes(runs):
    one, four = (json.loads((runs[b] / "intervention.json").read_text()) for b in (1, 4))
    assert four["valid"] and four["gate"]["steps_checked"] == one["gate"]["steps_checked"] == 2 * 2
    assert [c["key"] for c in four["salience"]["cells"]] == [c["key"] for c in one["salience"]["cells"]]
    assert set(episodes(runs[4])) == set(episodes(runs[1]))


def test_batched_baseline_and_injected_drive_alike_until_onset(runs):
    logged = episodes(runs[4])
    for (route, seed, role), base in logged.items():
        if role != "baseline":
            continue
        injected = logged[(route, seed, "injected")]
        onset = next(s.step for s in base.steps if "onset" in s.extras["intervention"])
        assert [s.ego for s in base.steps[:onset + 1]] == [s.ego for s in injected.steps[:onset + 1]]
        assert base.steps[onset].extras["intervention"]["gate"]["ok"]
        assert all(s.extras["intervention"].get("condition") == "accel" for s in injected.steps[onset:])


def test_batched_trajectories_match_unbatched_up_to_rounding(runs):
    one, four = episodes(runs[1]), episodes(runs[4])
    assert set(one) == set(four)
    for key, episode in one.items():
        first, other = episode.steps[0].trajectory, four[key].steps[0].trajectory
        assert abs(np.asarray(first.xy) - np.asarray(other.xy)).max() < 1e-3
