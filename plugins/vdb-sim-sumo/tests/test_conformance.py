"""The SUMO simulator passes the conformance kit (vladrivebench.testing) on every scenario family."""

from __future__ import annotations

import pytest
from vdb_sim_sumo import plugin
from vladrivebench.testing import Registry, check_bad_options, check_options, check_simulator, core_plugin
from vladrivebench.world import load_suite

SUITE = load_suite(Registry([core_plugin()], entry_points=False))
FAMILIES = sorted({scenario_id.split(".")[0] for scenario_id in SUITE})


def first_of(family: str) -> str:
    return next(scenario_id for scenario_id in SUITE if scenario_id.split(".")[0] == family)


@pytest.mark.parametrize("scenario_id", [first_of(family) for family in FAMILIES])
def test_the_sumo_simulator_conforms(sumo_sim, scenario_id):
    check_simulator(lambda: sumo_sim(render=True, width=64, height=32), SUITE[scenario_id], seed=2, name="sumo")


def test_bad_sumo_options_are_one_line_errors(sumo_sim):
    def create(options):
        check_options("simulator", "sumo", plugin.make_simulator, options)  # as the registry does
        return sumo_sim(**options)

    check_bad_options(create,
                      [{"width": 4}, {"render": "yes"}, {"pedestrians": "ghosts"},
                       {"background_vehicles_per_hour": -5}], name="sumo")
