"""The scenario's road-user scripts and the episode setup every suite simulator shares."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._engine.rng import episode_rng
from vladrivebench._scenarios.spec import ActorSpec, parse_scenario
from vladrivebench.errors import ConfigError, ScenarioError
from vladrivebench.records import EgoState
from vladrivebench.world import _bicycle as bicycle
from vladrivebench.world._boxes import Box, overlap
from vladrivebench.world._motion import (
    JITTERED_KINDS,
    WORLD_FEATURES,
    ScriptedUser,
    blank_image,
    check_supported,
    check_view_options,
    ego_at_start,
    scripted_users,
)
from vladrivebench.world._roads import RouteBuilder, build_road

ROUTE = RouteBuilder(0.0, -1.75, 0.0).straight(300.0).build(200.0)
DT = 0.1
FAR_AWAY = EgoState(-500.0, 300.0, 0.0, 0.0)
"""An ego nowhere near any road user: nothing waits for it."""


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


def scenario(actors=(), **extra):
    data = {"id": "M.1", "title": "t", "family": "intervention", "group": "g", "layout": "straight",
            "command": "follow_lane", "max_time_s": 20.0, "road": {"approach_length": 100.0},
            "actors": list(actors), **extra}
    return parse_scenario(data, "motion.toml")


# -- the scripts --------------------------------------------------------------------------------------


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


@settings(max_examples=60, deadline=None)
@given(movers(), st.floats(-0.2, 0.2))
def test_without_the_ego_in_the_way_a_mover_follows_its_script_exactly(spec, shift):
    user = ScriptedUser.at_start(spec, shift)
    user.started = True
    steps = 300
    for _ in range(steps):
        user.advance(ROUTE, FAR_AWAY, DT)
    if spec.motion == "along":
        sign = 1.0 if spec.direction == "same" else -1.0
        assert user.s == pytest.approx(spec.s + shift + sign * spec.speed * DT * steps, abs=1e-6)
        assert user.speed == spec.speed
    else:  # 300 steps at 0.5 m/s or more (15 m) cover the at most 12 m across: it stands at its end (summed steps
        # land within rounding of it, and that counts as arrived)
        assert (user.s, user.speed) == (spec.s + shift, 0.0)
        assert user.offset == pytest.approx(spec.end_offset, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(movers(), st.floats(-50.0, 200.0))
def test_the_trigger_fires_once_when_the_front_bumper_comes_within_the_trigger_distance(spec, front):
    user = ScriptedUser.at_start(spec)
    if spec.trigger_distance is None:
        assert user.started and not user.check_trigger(front)
        return
    assert not user.started
    fired = user.check_trigger(front)
    assert fired == user.started == (spec.s - front <= spec.trigger_distance)
    if fired:  # it never fires again, and never stops, however far back the ego is
        assert not user.check_trigger(front - spec.trigger_distance - 100.0) and user.started
    else:  # with the front at its position, every trigger distance is reached
        assert user.check_trigger(spec.s) and user.started


@settings(max_examples=60, deadline=None)
@given(st.floats(-180.0, 180.0), st.floats(0.0, 60.0), st.floats(-50.0, 200.0))
def test_a_static_road_user_never_moves_and_faces_its_heading(heading_deg, trigger, front):
    spec = ActorSpec(id="car0", kind="car", s=40.0, offset=1.0, heading_deg=heading_deg, trigger_distance=trigger,
                     length=4.5, width=1.8)
    user = ScriptedUser.at_start(spec)
    assert not user.check_trigger(front) and not user.started
    user.advance(ROUTE, FAR_AWAY, DT)
    assert (user.s, user.offset, user.speed) == (40.0, 1.0, 0.0)
    actor = user.actor(ROUTE)
    assert actor.yaw == pytest.approx(math.remainder(math.radians(heading_deg), 2 * math.pi), abs=1e-12)
    assert (actor.x, actor.y, actor.length, actor.width) == pytest.approx((40.0, -0.75, 4.5, 1.8))


@settings(max_examples=60, deadline=None)
@given(movers())
def test_a_mover_faces_where_it_walks(spec):
    actor = ScriptedUser.at_start(spec).actor(ROUTE)  # the route heads east (yaw 0)
    if spec.motion == "along":
        expected = 0.0 if spec.direction == "same" else math.pi
    else:
        expected = math.pi / 2 if spec.end_offset > spec.offset else -math.pi / 2
    assert abs(math.remainder(actor.yaw - expected, 2 * math.pi)) < 1e-12


def test_a_road_user_the_ego_drove_into_may_walk_out_of_it():
    spec = ActorSpec(id="p", kind="pedestrian", s=30.0, offset=0.0, motion="cross", end_offset=5.0, speed=1.0)
    user = ScriptedUser.at_start(spec)
    ego = EgoState(30.0, -1.75, 0.0, 0.0)  # the ego's box covers the pedestrian
    assert overlap(Box.of_ego(ego), Box.of_actor(user.actor(ROUTE)))
    user.advance(ROUTE, ego, DT)
    assert user.offset == pytest.approx(0.1) and user.speed == pytest.approx(1.0)


def test_a_road_user_waits_rather_than_step_into_the_ego():
    spec = ActorSpec(id="p", kind="pedestrian", s=30.0, offset=-3.8, motion="cross", end_offset=5.0, speed=1.0)
    user = ScriptedUser.at_start(spec)
    ego = EgoState(30.0, -1.75, 0.0, 0.0)  # stands on the crossing line; its box reaches offset -0.95
    for _ in range(30):
        user.advance(ROUTE, ego, DT)
    assert not overlap(Box.of_ego(ego), Box.of_actor(user.actor(ROUTE)))
    assert user.speed == 0.0 and -3.8 < user.offset < -0.95 - 0.25 + 1e-9


# -- the episode's start ------------------------------------------------------------------------------

ACTORS = [
    {"id": "ped0", "kind": "pedestrian", "s": 40.0, "offset": 3.0, "motion": "cross", "end_offset": -3.0,
     "speed": 1.2},
    {"id": "car0", "kind": "car", "s": 60.0, "offset": 3.5, "length": 4.5, "width": 1.8},
    {"id": "dog0", "kind": "animal", "s": 70.0, "offset": 2.0},
    {"id": "ped1", "kind": "pedestrian", "s": 80.0, "motion": "along", "direction": "same", "speed": 1.0,
     "trigger_distance": 20.0},
]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32), st.floats(0.0, 2.0))
def test_seeds_shift_pedestrians_and_animals_from_the_simulator_stream_in_scenario_order(seed, jitter):
    posed = scenario(ACTORS)
    users = scripted_users(posed, seed, jitter)
    assert [u.spec for u in users] == list(posed.actors)
    draws = episode_rng(seed, "simulator")
    for user, spec in zip(users, posed.actors, strict=True):
        expected = spec.s
        if spec.kind in JITTERED_KINDS and jitter > 0:
            expected += float(draws.uniform(-jitter, jitter))
        assert user.s == expected and abs(user.s - spec.s) <= jitter
        assert (user.offset, user.speed) == (spec.offset, 0.0)
        assert user.started == (spec.motion != "static" and spec.trigger_distance is None)
    assert [(u.s, u.offset) for u in scripted_users(posed, seed, jitter)] == [(u.s, u.offset) for u in users]


def test_jitter_zero_poses_every_seed_the_same_and_cars_never_move():
    posed = scenario(ACTORS)
    assert {tuple(u.s for u in scripted_users(posed, seed, 0.0)) for seed in range(5)} == {(40.0, 60.0, 70.0, 80.0)}
    assert len({tuple(u.s for u in scripted_users(posed, seed, 0.2)) for seed in range(5)}) == 5
    assert {scripted_users(posed, seed, 0.2)[1].s for seed in range(5)} == {60.0}


@pytest.mark.parametrize("layout,command,road", [("straight", "follow_lane", {}),
                                                 ("t_junction", "right", {"junction_side": "dead_end"}),
                                                 ("four_way", "left", {})])
def test_the_ego_starts_at_the_route_start_along_it(layout, command, road):
    posed = scenario(layout=layout, command=command, ego={"speed": 4.0},
                     road={"approach_length": 100.0, **road})
    route = build_road(posed).route
    ego = ego_at_start(route, 4.0)
    assert (ego.x, ego.y) == tuple(float(v) for v in route.position(0.0))
    assert (ego.yaw, ego.speed, ego.steer) == (float(route.heading(0.0)), 4.0, 0.0)
    assert (ego.length, ego.width) == (bicycle.EGO_LENGTH, bicycle.EGO_WIDTH)


# -- what a simulator supports, and its options -------------------------------------------------------


def test_the_suite_scenarios_features_are_all_in_the_shared_world():
    posed = scenario(ACTORS, layout="four_way", command="left", light={"state": "yellow"})
    check_supported(posed, "any")
    assert posed.features() <= WORLD_FEATURES


def test_a_missing_feature_is_a_one_line_scenario_error_naming_the_first():
    posed = scenario(requires=["weather:snow", "weather:rain"])
    with pytest.raises(ScenarioError) as info:
        check_supported(posed, "mysim")
    message = str(info.value)
    assert message.startswith("scenario motion.toml: simulator 'mysim' cannot represent 'weather:rain' (it supports: ")
    assert "\n" not in message
    check_supported(posed, "mysim", WORLD_FEATURES | {"weather:rain", "weather:snow"})
    with pytest.raises(ScenarioError, match="cannot represent 'lanes:1' \\(it supports: stop_sign\\)"):
        check_supported(scenario(), "tiny", frozenset({"stop_sign"}))


GOOD = {"width": 160, "height": 80, "render": True, "hfov_deg": 90.0, "camera_height": 1.6, "pitch_deg": 0.0,
        "position_jitter": 0.2}
RANGES = {"width": (8, 4096), "height": (8, 4096), "hfov_deg": (10.0, 170.0), "camera_height": (0.2, 10.0),
          "pitch_deg": (-30.0, 60.0), "position_jitter": (0.0, 2.0)}


@settings(max_examples=100, deadline=None)
@given(st.sampled_from(sorted(RANGES)), st.one_of(st.floats(-1e4, 1e4), st.integers(-10**4, 10**4), st.booleans(),
                                                 st.text(max_size=3), st.none()))
def test_a_view_option_is_accepted_exactly_when_it_is_a_number_in_its_range(name, value):
    low, high = RANGES[name]
    whole = name in ("width", "height")
    valid = (not isinstance(value, bool) and isinstance(value, int if whole else (int, float))
             and low <= value <= high)
    values = {**GOOD, name: value}
    if valid:
        check_view_options("sim", values)
        return
    with pytest.raises(ConfigError) as info:
        check_view_options("sim", values)
    expected = f"a whole number between {low} and {high}" if whole else f"a number between {low:g} and {high:g}"
    assert str(info.value) == f"simulator 'sim': option {name} must be {expected}, got {value!r}"


def test_render_must_be_a_bool_and_the_first_bad_option_is_named():
    with pytest.raises(ConfigError, match="^simulator 'sim': option render must be true or false, got 'yes'$"):
        check_view_options("sim", {**GOOD, "render": "yes"})
    with pytest.raises(ConfigError, match="option height must"):
        check_view_options("sim", {**GOOD, "height": 2, "pitch_deg": 90.0})


def test_the_blank_image_is_black_read_only_and_of_the_camera_size():
    image = blank_image(40, 20)
    assert image.shape == (20, 40, 3) and image.dtype == np.uint8 and not image.any()
    with pytest.raises(ValueError):
        image[0, 0, 0] = 1
