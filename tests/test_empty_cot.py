"""An empty own CoT is a valid CoT: its selfsplice is the empty splice, and it never aborts a run."""

from __future__ import annotations

import dataclasses

import intervention_fakes as fakes
import pytest
from vladrivebench import hookimpl
from vladrivebench._engine.sweep import ComponentSpec
from vladrivebench._intervention.conditions import injection_problem
from vladrivebench._intervention.runs import InterventionConfig, InterventionRun
from vladrivebench._scenarios.spec import resolve_scenarios
from vladrivebench.records import CoT, CoTFormat


class SometimesSilent(fakes.KeywordModel):
    """Writes an empty CoT at every other step (as a random-weight VLM does now and then)."""

    def generate_cot(self, obs, rng):
        cot = super().generate_cot(obs, rng)
        return CoT("", state=self._state("", self.leak)) if obs.step % 2 == 0 else cot


class SilentFakes:
    @hookimpl
    def register_models(self, register):
        register("silent", SometimesSilent)


@pytest.mark.parametrize("mode", ["open-loop", "closed-loop"])
def test_a_run_with_empty_own_cots_completes_and_its_gate_holds(tmp_path, mode):
    registry = fakes.fake_registry(("silent", SilentFakes()))
    routes = tuple(dataclasses.replace(s, max_time_s=2.0) for s in resolve_scenarios(["E.1"], registry))
    cfg = InterventionConfig(mode=mode, model=ComponentSpec("model", "silent", {}),
                             simulator=ComponentSpec("simulator", "line", {}),
                             controller=ComponentSpec("controller", "speed", {}), routes=routes,
                             conditions=("accel",), seeds=(0,))
    results = InterventionRun(cfg, tmp_path, registry=registry).run()
    assert results["valid"] and results["gate"]["steps_checked"] > 0


def test_empty_texts_are_refused_only_where_they_cannot_come_from_the_model():
    sentence = CoTFormat("sentence", (), None)
    assert injection_problem("", sentence, len) == "is empty"
    assert injection_problem("", sentence, len, allow_empty=True) is None
    assert injection_problem("  ", sentence, len, allow_empty=True) is None
    assert injection_problem(3, sentence, len, allow_empty=True).startswith("must be one sentence")
