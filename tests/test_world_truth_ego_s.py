"""TruthTracker.ego_s answers a repeated question within a step from memory: the same as computing it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._scenarios.spec import parse_scenario
from vladrivebench.records import EgoState
from vladrivebench.world._roads import build_road
from vladrivebench.world._truth import TruthTracker

SCENARIO = parse_scenario({"id": "T.1", "title": "t", "family": "intervention", "group": "g", "layout": "four_way",
                           "command": "left", "max_time_s": 20.0, "road": {"approach_length": 60.0}}, "t.toml")
ROAD = build_road(SCENARIO)

steps = st.lists(st.tuples(st.floats(-5.0, 120.0), st.floats(-30.0, 30.0), st.floats(-3.1, 3.1),
                           st.floats(0.0, 10.0), st.booleans()), min_size=1, max_size=8)


@given(steps)
@settings(max_examples=60, deadline=None)
def test_ego_s_asked_twice_is_ego_s_computed_afresh(sequence):
    tracker = TruthTracker(SCENARIO, ROAD)
    for step, (x, y, yaw, speed, twice) in enumerate(sequence):
        ego = EgoState(x, y, yaw, speed)
        fresh = TruthTracker(SCENARIO, ROAD)
        fresh._s_centre = tracker._s_centre
        expected = fresh.ego_s(ego)
        assert tracker.ego_s(ego) == expected
        if twice:
            assert tracker.ego_s(ego) == expected
        tracker.observe(step, ego, ())
        assert tracker._s_centre == expected
