"""The shipped ``kv`` and ``qa`` models pass the conformance kit (vladrivebench.testing) on 448 × 224 frames."""

from __future__ import annotations

import pytest
from vdb_model_neural import plugin
from vladrivebench.testing import check_bad_options, check_model


@pytest.mark.parametrize("name", ["kv", "qa"])
def test_the_neural_models_conform(vdb_registry, vdb_observations, name):
    registry = vdb_registry(("neural", plugin))
    check_model(registry.create("model", name, {}), vdb_observations(2), name=name)


@pytest.mark.parametrize("name", ["kv", "qa"])
def test_bad_neural_options_are_one_line_errors(vdb_registry, tmp_path, name):
    registry = vdb_registry(("neural", plugin))
    check_bad_options(lambda options: registry.create("model", name, options),
                      [{"splice_mode": "sideways"}, {"threads": 0}, {"threads": "many"}, {"threads": True},
                       {"weights_dir": str(tmp_path / "none")}], name=name)
