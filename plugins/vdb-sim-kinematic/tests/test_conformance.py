"""The kinematic simulator passes the conformance kit (vladrivebench.testing) on every scenario family."""

from __future__ import annotations

import pytest
from vdb_sim_kinematic import plugin
from vladrivebench import Control
from vladrivebench.testing import Registry, check_bad_options, check_simulator, core_plugin
from vladrivebench.world import load_suite

SUITE = load_suite(Registry([core_plugin()], entry_points=False))
FAMILIES = sorted({scenario_id.split(".")[0] for scenario_id in SUITE})


def first_of(family: str) -> str:
    return next(scenario_id for scenario_id in SUITE if scenario_id.split(".")[0] == family)


@pytest.mark.parametrize("scenario_id", [first_of(family) for family in FAMILIES])
def test_the_kinematic_simulator_conforms(vdb_registry, scenario_id):
    registry = vdb_registry(("kinematic", plugin))
    check_simulator(lambda: registry.create("simulator", "kinematic", {"width": 96, "height": 48}),
                    SUITE[scenario_id], seed=3, name="kinematic")


def test_the_kinematic_camera_is_large_enough_for_a_vision_encoder(vdb_registry):
    registry = vdb_registry(("kinematic", plugin))
    check_simulator(lambda: registry.create("simulator", "kinematic", {"width": 448, "height": 224}),
                    SUITE[first_of(FAMILIES[0])], name="kinematic", min_image_side=224,
                    controls=[Control(0.5, 0.0, 0.0, 6.0)] * 5)


def test_bad_kinematic_options_are_one_line_errors(vdb_registry):
    registry = vdb_registry(("kinematic", plugin))
    check_bad_options(lambda options: registry.create("simulator", "kinematic", options),
                      [{"width": 4}, {"height": "tall"}, {"render": "yes"}, {"hfov_deg": 200},
                       {"position_jitter": -1}], name="kinematic")
