"""The grid: option parsing and validation, and the derived routes (rule-based: property tests)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_paradigm_salience.grid import (
    KINDS,
    GridCell,
    along_extent,
    base_obstacle,
    cell_route,
    check_grid,
    cruise_distance,
    from_start,
    grid_options,
    near_edge,
    parse_kinds,
    parse_numbers,
    start_distance,
)
from vladrivebench import ConfigError
from vladrivebench.world import EGO_WIDTH, load_suite

SUITE = load_suite()
BASES = [SUITE[r] for r in ("SAFE.kerb-ped", "SAFE.centre-ped", "SAFE.car")]

offsets = st.lists(st.floats(-5, 5, allow_nan=False).map(lambda v: round(v, 2)), min_size=1, max_size=6)


@given(offsets)
def test_numbers_parse_the_same_from_text_lists_and_one_number(values):
    expected = tuple(sorted(set(values)))
    assert parse_numbers("offsets", ",".join(repr(v) for v in values), -5, 5) == expected
    assert parse_numbers("offsets", values, -5, 5) == expected
    assert parse_numbers("offsets", values[0], -5, 5) == (values[0],)


@given(st.one_of(st.floats(5.0001, 1e6), st.floats(-1e6, -5.0001), st.just(math.nan), st.just(math.inf),
                 st.sampled_from(["a", "", True, None, "1,,2", [], "1;2"])))
def test_a_bad_number_is_one_line_naming_the_option(value):
    with pytest.raises(ConfigError) as info:
        parse_numbers("offsets", value, -5, 5)
    message = str(info.value)
    assert message.startswith("--paradigm-opt offsets:") and "\n" not in message


def test_sizes_exclude_zero_and_kinds_are_known():
    with pytest.raises(ConfigError, match="sizes: '0' is not a size factor"):
        grid_options(sizes="0,1")
    assert parse_kinds("car,pedestrian,car") == ("car", "pedestrian")
    for bad in ("bus", "car,", 3, ["car", "tree"]):
        with pytest.raises(ConfigError, match="--paradigm-opt kinds"):
            parse_kinds(bad)
    for bad in ("abc", 0, 500, True):
        with pytest.raises(ConfigError, match="--paradigm-opt max_time"):
            grid_options(max_time=bad)
    with pytest.raises(ConfigError, match="the grid has 1000 cells"):
        grid_options(kinds="pedestrian", offsets=list(range(-4, 6)), distances=list(range(10, 20)),
                     sizes=[0.1 * k for k in range(1, 11)])


@given(st.lists(st.sampled_from(KINDS), min_size=1, max_size=3, unique=True), offsets,
       st.lists(st.floats(5, 50).map(lambda v: round(v, 1)), min_size=1, max_size=3),
       st.lists(st.floats(0.1, 3).map(lambda v: round(v, 2)), min_size=1, max_size=3))
def test_the_grid_is_every_combination_once(kinds, offs, distances, sizes):
    options = grid_options(kinds, offs, distances, sizes)
    cells = options.cells()
    assert len(cells) == len(kinds) * len(set(offs)) * len(set(distances)) * len(set(sizes))
    assert len({c.key for c in cells}) == len(cells)
    assert {c.kind for c in cells} == set(kinds) and {c.size for c in cells} == set(sizes)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from(BASES), st.sampled_from(KINDS), st.floats(-0.9, 0.9).map(lambda v: round(v, 2)),
       st.floats(0.2, 3).map(lambda v: round(v, 2)), st.floats(5, 50).map(lambda v: round(v, 1)))
def test_a_cell_route_changes_only_the_obstacle_and_keeps_its_near_edge(base, kind, offset, size, distance):
    cell = GridCell(kind, offset, distance, size)
    route = cell_route(base, cell, 16.0)
    old, new = base_obstacle(base), route.actor(base.critical)
    assert route.id == cell.route_id(base.id) and route.max_time_s == 16.0
    assert new.kind == kind and new.offset == offset and route.critical_kind == kind
    assert near_edge(new) == pytest.approx(near_edge(old), abs=1e-6)
    default = cell_route(base, GridCell(kind, offset, distance, 1.0), 16.0).actor(base.critical)
    assert (new.length, new.width, new.height) == pytest.approx((default.length * size, default.width * size,
                                                                 default.height * size))
    assert (route.road, route.ego, route.light, route.layout) == (base.road, base.ego, base.light, base.layout)
    assert [a for a in route.actors if a.id != base.critical] == [a for a in base.actors if a.id != base.critical]


def test_the_grid_must_fit_the_base_route():
    base = SUITE["SAFE.kerb-ped"]
    farthest = start_distance(base)
    assert 45 < cruise_distance(base) < 52 < 65 < farthest < 75  # ~50 m ahead at cruising, ~70 m at the start
    assert from_start(base, farthest) and not from_start(base, cruise_distance(base))
    assert len(check_grid(grid_options(), [base])) == len(grid_options().cells()) >= 4
    cases = [
        (grid_options(), [base, SUITE["SAFE.car"]], "sweeps one base route"),
        (grid_options(), [SUITE["E.1"]], "needs a safety route with one static obstacle"),
        (grid_options(), [SUITE["P.2"]], "needs a safety route with one static obstacle"),
        (grid_options(distances=farthest + 5), [base], "--paradigm-opt distances:"),
        (grid_options(max_time=60), [base], "--paradigm-opt max_time: 60 s is longer"),
        (grid_options(kinds="pedestrian", offsets=2.0, sizes=1), [base], "outside the ego's path"),
    ]
    for options, routes, fragment in cases:
        with pytest.raises(ConfigError, match=fragment):
            check_grid(options, routes)


@given(st.floats(0.1, 5), st.floats(0.1, 5), st.floats(-360, 360))
def test_extents_are_the_box_projected_on_the_route_axes(length, width, heading):
    along = along_extent(length, width, heading)
    assert min(length, width) - 1e-9 <= along <= math.hypot(length, width) + 1e-9
    assert along_extent(length, width, 0.0) == pytest.approx(length)
    assert along_extent(length, width, 90.0) == pytest.approx(width)


def test_the_suite_obstacles_block_the_ego_path():
    for base in BASES:
        obstacle = base_obstacle(base)
        assert abs(obstacle.offset) < EGO_WIDTH / 2 + 0.5
