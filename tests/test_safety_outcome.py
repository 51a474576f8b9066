"""The safety paradigm's "baseline stopped": a stop after driving, with the obstacle ahead."""

from __future__ import annotations

from types import SimpleNamespace

from hypothesis import given
from hypothesis import strategies as st
from vladrivebench._intervention.runs import MOVING_SPEED, STOPPED_SPEED, came_to_stop


def steps(speeds: list[float], distances: list[float | None] | None = None) -> list[SimpleNamespace]:
    distances = distances if distances is not None else [10.0] * len(speeds)
    return [SimpleNamespace(step=i, ego=SimpleNamespace(speed=v), ground_truth=SimpleNamespace(distance_to_critical=d))
            for i, (v, d) in enumerate(zip(speeds, distances, strict=True))]


def test_pulling_away_from_rest_is_not_a_stop():
    assert not came_to_stop(steps([0.0, 0.08, 0.2, 0.9, 3.0, 6.0, 8.0]))


def test_slowing_to_rest_after_driving_is_a_stop():
    assert came_to_stop(steps([0.0, 0.2, 3.0, 8.0, 4.0, 0.1]))


def test_a_stop_with_no_obstacle_ahead_does_not_count():
    assert not came_to_stop(steps([0.0, 5.0, 0.1, 0.0], [10.0, 5.0, -1.0, None]))


speeds = st.lists(st.floats(0.0, 15.0, allow_nan=False), max_size=40)


@given(speeds)
def test_never_driving_is_never_a_stop(values):
    below = [min(v, MOVING_SPEED * 0.99) for v in values]
    assert not came_to_stop(steps(below))


@given(speeds)
def test_matches_the_rule(values):
    first_moving = next((i for i, v in enumerate(values) if v >= MOVING_SPEED), None)
    expected = first_moving is not None and any(v < STOPPED_SPEED for v in values[first_moving + 1:])
    assert came_to_stop(steps(values)) == expected


@given(speeds, st.integers(0, 40))
def test_a_prefix_that_stopped_stays_stopped(values, cut):
    if came_to_stop(steps(values[:cut])):
        assert came_to_stop(steps(values))
