"""Property tests of the plugin's rule-based computations: the scenario scripts of road users, and the
scanline rasteriser of user networks' ground."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from matplotlib.path import Path as PolygonPath
from vdb_sim_sumo.scripted import ScriptedUser
from vdb_sim_sumo.usernet import _Raster
from vladrivebench.records import EgoState
from vladrivebench.scenarios import ActorSpec
from vladrivebench.world.boxes import Box, overlap
from vladrivebench.world.roads import RouteBuilder

ROUTE = RouteBuilder(0.0, -1.75, 0.0).straight(300.0).build(200.0)
DT = 0.1


@st.composite
def movers(draw):
    motion = draw(st.sampled_from(["along", "cross"]))
    offset = draw(st.floats(-6.0, 6.0))
    extra = {}
    if motion == "along":
        extra["direction"] = draw(st.sampled_from(["same", "opposite"]))
    else:
        end = draw(st.floats(-6.0, 6.0).filter(lambda e: abs(e - offset) > 0.1))
        extra["end_offset"] = end
    return ActorSpec(id="p", kind="pedestrian", s=draw(st.floats(20.0, 120.0)), offset=offset, motion=motion,
                     speed=draw(st.floats(0.5, 3.0)), trigger_distance=draw(st.one_of(st.none(), st.floats(0, 60))),
                     length=0.5, width=0.6, **extra)


@settings(max_examples=80, deadline=None)
@given(movers(), st.floats(-10.0, 150.0), st.floats(-3.0, 3.0))
def test_a_scripted_road_user_keeps_its_script(spec, ego_s, ego_offset):
    user = ScriptedUser.at_start(spec)
    ego_x, ego_y = (float(v) for v in ROUTE.to_world(ego_s, ego_offset))
    ego = EgoState(ego_x, ego_y, 0.0, 5.0)
    front = ego_s + ego.length / 2
    started_now = user.check_trigger(front)
    expected = spec.trigger_distance is None or spec.s - front <= spec.trigger_distance
    assert user.started == expected and started_now == (expected and spec.trigger_distance is not None)
    for _ in range(60):
        before = (user.s, user.offset)
        was_overlapping = overlap(Box.of_ego(ego), Box.of_actor(user.actor(ROUTE)))
        user.advance(ROUTE, ego, DT)
        moved = math.hypot(user.s - before[0], user.offset - before[1])
        assert moved <= spec.speed * DT + 1e-9  # never faster than its speed
        if not user.started:
            assert moved == 0.0
        if spec.motion == "cross":
            assert user.s == spec.s  # crosses at its line ...
            low, high = sorted((spec.offset, spec.end_offset))
            assert low - 1e-9 <= user.offset <= high + 1e-9  # ... and stops at its end
        else:
            assert user.offset == spec.offset
        if not was_overlapping:  # it never steps into the ego
            assert not overlap(Box.of_ego(ego), Box.of_actor(user.actor(ROUTE)))


@st.composite
def convex_polygons(draw):
    cx, cy = draw(st.floats(5.0, 15.0)), draw(st.floats(5.0, 15.0))
    angles = sorted(draw(st.lists(st.floats(0.0, 2 * math.pi, exclude_max=True), min_size=3, max_size=8,
                                  unique=True)))
    radius = draw(st.floats(0.5, 4.0))
    return [(cx + radius * math.cos(a), cy + radius * math.sin(a)) for a in angles]


@settings(max_examples=80, deadline=None)
@given(convex_polygons())
def test_the_rasteriser_fills_exactly_the_cells_whose_centres_are_inside(polygon):
    grid = np.zeros((100, 100), dtype=np.uint8)
    _Raster(grid, (0.0, 0.0), 0.2).fill(polygon, 7)
    centres = (np.stack(np.meshgrid(np.arange(100), np.arange(100)), -1).reshape(-1, 2) + 0.5) * 0.2
    inside = PolygonPath(polygon).contains_points(centres).reshape(100, 100)
    filled = grid == 7
    # cells whose centre lies within 1e-9 of an edge may go either way
    assert np.count_nonzero(filled != inside) <= 2
    assert np.count_nonzero(filled) >= np.count_nonzero(inside) - 2
