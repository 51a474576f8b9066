"""The scripted model passes the conformance kit (vladrivebench.testing) in both CoT formats."""

from __future__ import annotations

import pytest
from vdb_model_scripted import plugin
from vladrivebench.testing import check_bad_options, check_model


@pytest.mark.parametrize("options", [
    {},
    {"cot_format": "qa"},
    {"alpha": 1.0, "miss_rate": 0.3, "hallucination_rate": 0.3, "contradiction_rate": 0.3, "light_error_rate": 0.3},
    {"alpha": 0.0, "cot_format": "qa", "noise": 0.5},
])
def test_the_scripted_model_conforms(vdb_registry, vdb_observations, options):
    registry = vdb_registry(("scripted", plugin))
    model = registry.create("model", "scripted", options)
    check_model(model, vdb_observations(6), name="scripted")
    check_model(model, vdb_observations(3, seed=7), name="scripted", seed=11)


def test_bad_scripted_options_are_one_line_errors(vdb_registry):
    registry = vdb_registry(("scripted", plugin))
    check_bad_options(lambda options: registry.create("model", "scripted", options),
                      [{"alpha": 2}, {"miss_rate": -0.1}, {"cot_format": "haiku"}, {"noise": "loud"},
                       {"cruise_speed": float("nan")}], name="scripted")
