"""The fidelity half of the intervention gate: a model with the ``FidelityCheck`` capability compares the
spliced state with its own native computation at every gated step; the gate fails a step above the model's
tolerance even when selfsplice passes, and reports the largest differences beside the selfsplice columns."""

from __future__ import annotations

import dataclasses

import intervention_fakes as fakes
import pytest
from vladrivebench import FidelityCheck, hookimpl
from vladrivebench._engine.sweep import ComponentSpec
from vladrivebench._intervention.metric import gate_table
from vladrivebench._intervention.runs import GateTally, InterventionConfig, InterventionRun, gate_message
from vladrivebench._scenarios.spec import resolve_scenarios


class FaithfulModel(fakes.KeywordModel):
    """The keyword fake with a fidelity check: ``drift`` is how far its splices are from its native
    computation (a dropped rope delta in a real VLA); generation and splice still agree with each other."""

    fidelity_tolerance = 1e-4

    def __init__(self, drift: float = 0.0, **kw):
        super().__init__(**kw)
        self.drift, self.checked = drift, 0

    def fidelity_check(self, obs, cot, rng):
        self.checked += 1
        return self.drift, 10 * self.drift


class FidelityFakes:
    @hookimpl
    def register_models(self, register):
        register("faithful", FaithfulModel)


def run(tmp_path, drift, mode="open-loop"):
    registry = fakes.fake_registry(("fidelity", FidelityFakes()))
    routes = tuple(dataclasses.replace(s, max_time_s=3.0) for s in resolve_scenarios(["E.1"], registry))
    cfg = InterventionConfig(mode=mode, model=ComponentSpec("model", "faithful", {"drift": drift}),
                             simulator=ComponentSpec("simulator", "line", {}),
                             controller=ComponentSpec("controller", "speed", {}), routes=routes,
                             conditions=("accel",), seeds=(0, 1))
    return InterventionRun(cfg, tmp_path, registry=registry).run()


def test_the_capability_is_recognised():
    assert isinstance(FaithfulModel(), FidelityCheck)
    assert not isinstance(fakes.KeywordModel(), FidelityCheck)


@pytest.mark.parametrize("mode", ["open-loop", "closed-loop"])
def test_a_faithful_splice_passes_and_the_numbers_are_reported(tmp_path, mode):
    results = run(tmp_path, 0.0, mode)
    gate = results["gate"]
    assert results["valid"] and gate["fidelity_steps_checked"] == gate["steps_checked"] > 0
    assert gate["fidelity_steps_failed"] == 0 and gate["max_fidelity_cache_diff"] == 0.0
    table = gate_table(results)
    assert "Max fidelity cache diff" in table.columns and "Max trajectory diff (m)" in table.columns


def test_a_drifting_splice_fails_the_gate_while_selfsplice_alone_passes(tmp_path):
    results = run(tmp_path, 0.5)
    gate = results["gate"]
    assert gate["digest_mismatches"] == 0 and gate["max_trajectory_diff"] == 0.0  # selfsplice holds …
    assert not results["valid"] and gate["fidelity_steps_failed"] == gate["steps_checked"] > 0  # … fidelity not
    assert gate["max_fidelity_cache_diff"] == 0.5 and gate["max_fidelity_trajectory_diff"] == 5.0
    message = gate_message(results)
    assert message.startswith("INVALID RUN: selfsplice holds but the gate failed at")
    assert "native forward pass" in message and "0.5" in message and "\n" not in message


def test_models_without_the_capability_keep_the_old_gate_record():
    tally = GateTally()
    tally.add({"digest_equal": True, "trajectory_diff": 0.0, "ok": True}, {})
    assert "fidelity_steps_checked" not in tally.to_json() and tally.valid
