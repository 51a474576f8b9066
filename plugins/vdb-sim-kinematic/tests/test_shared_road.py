"""The process-wide road cache: simulators share one road per scenario, equal to a freshly built one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from vdb_sim_kinematic import simulator as module
from vdb_sim_kinematic.simulator import KinematicSimulator, shared_road
from vladrivebench.testing import Registry, core_plugin
from vladrivebench.world import build_road, load_suite


@pytest.fixture(scope="module")
def suite():
    return load_suite(Registry(plugins=[core_plugin()], entry_points=False))


def _same_road(a, b) -> bool:
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if field.name == "route":
            if not all(np.array_equal(getattr(x, f), getattr(y, f)) for f in ("points", "s", "headings")):
                return False
            if x.length != y.length:
                return False
        elif x != y:
            return False
    return True


@pytest.mark.parametrize("sid", ["P.1", "S.3", "C.1", "TL.1-red", "E.1"])
def test_the_shared_road_is_the_road_built_afresh(suite, sid):
    assert _same_road(shared_road(suite[sid]), build_road(suite[sid]))


def test_simulators_share_one_road_per_scenario(suite):
    a, b = KinematicSimulator(render=False), KinematicSimulator(render=False)
    a.reset(suite["P.1"], 0)
    b.reset(suite["P.1"], 1)
    assert a.road is b.road
    b.reset(suite["S.3"], 0)
    assert b.road is not a.road


def test_the_cache_keeps_the_most_recently_used_roads(suite, monkeypatch):
    monkeypatch.setattr(module, "SHARED_ROADS", 1)
    first = shared_road(suite["P.1"])
    shared_road(suite["S.3"])
    assert len(module._shared_roads) == 1
    assert shared_road(suite["P.1"]) is not first
