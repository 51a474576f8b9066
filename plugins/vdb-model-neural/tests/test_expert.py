"""The expert driver's rules and the control rollout, as properties."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st
from vdb_model_neural import expert
from vdb_model_neural.kv_model import controls_to_trajectory, normalise_controls, rollout
from vladrivebench import Actor, EgoState, GroundTruth, Observation

STRAIGHT = tuple((float(i), 0.0) for i in range(51))


def observation(speed=8.0, kind=None, distance=None, blocking=False, light=None, offset=0.0):
    actors = ()
    critical = None
    if kind is not None:
        critical = "x"
        size = {"pedestrian": (0.5, 0.6, 1.75), "car": (4.6, 1.9, 1.5)}.get(kind, (0.5, 0.5, 3.0))
        actors = (Actor("x", kind, x=2.35 + distance, y=offset, length=size[0], width=size[1], height=size[2],
                        state=light),)
    gt = GroundTruth(step=0, time=0.0, actors=actors, critical_id=critical, critical_kind=kind,
                     distance_to_critical=distance, blocking=blocking, light_state=light, route_ahead=STRAIGHT)
    return Observation(step=0, time=0.0, image=np.zeros((8, 8, 3), np.uint8), ego=EgoState(0, 0, 0, speed),
                       command="follow_lane", ground_truth=gt)


def travelled(controls, speed):
    return rollout(controls[:, 0], controls[:, 1], speed, 0.1).path_length(3.0)


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.0, 10.0), stop=st.floats(0.0, 40.0))
def test_a_planned_stop_never_overshoots_and_speed_stays_non_negative(speed, stop):
    controls = expert.rollout_controls(speed, observation().ground_truth, stop, expert.CRUISE_SPEED)
    trajectory = rollout(controls[:, 0], controls[:, 1], speed, 0.1)
    # Braking is capped at MAX_DECEL: only a stop closer than that allows may be overshot.
    reachable = speed * speed / (2 * expert.MAX_DECEL * 0.8)
    if stop > reachable + 0.5:
        assert trajectory.forward_displacement(3.0) <= stop + 0.3
    assert np.all(np.diff(trajectory.xy[:, 0]) >= -1e-9)  # never reverses


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.5, 10.0), stop=st.floats(2.0, 40.0))
def test_braking_now_never_goes_further_than_braking_late(speed, stop):
    gt = observation().ground_truth
    late = expert.rollout_controls(speed, gt, stop, expert.CRUISE_SPEED)
    now = expert.rollout_controls(speed, gt, stop, expert.CRUISE_SPEED, brake_now=True)
    assert now[0, 0] <= late[0, 0] + 1e-9
    assert travelled(now, speed) <= travelled(late, speed) + 1e-6


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.0, 10.0))
def test_cruising_goes_at_least_as_far_as_stopping(speed):
    gt = observation().ground_truth
    go = expert.rollout_controls(speed, gt, None, expert.CRUISE_SPEED)
    stop = expert.rollout_controls(speed, gt, 5.0, expert.CRUISE_SPEED)
    assert travelled(go, speed) >= travelled(stop, speed) - 1e-9
    assert np.all(go[:, 0] <= expert.MAX_ACCEL + 1e-9) and np.all(stop[:, 0] >= -expert.MAX_DECEL - 1e-9)


@settings(max_examples=40, deadline=None)
@given(side=st.sampled_from([-1.0, 1.0]), lateral=st.floats(0.3, 3.0), heading=st.floats(-0.3, 0.3))
def test_pure_pursuit_steers_towards_the_route(side, lateral, heading):
    route = np.array([[float(i), side * lateral] for i in range(51)])
    kappa = expert.pursuit_curvature(route, 0.0, 0.0, 0.0, 6.0)
    assert math.copysign(1.0, kappa) == side


@settings(max_examples=60, deadline=None)
@given(distance=st.floats(-0.5, 40.0), kind=st.sampled_from(["pedestrian", "car"]), blocking=st.booleans(),
       offset=st.sampled_from([0.0, -4.0, 6.5]))
def test_the_expert_stops_exactly_for_blocking_road_users(distance, kind, blocking, offset):
    decision = expert.ExpertDriver().decide(observation(kind=kind, distance=distance, blocking=blocking,
                                                        offset=offset if not blocking else 0.0))
    stops = blocking or (kind == "pedestrian" and offset == 0.0)  # a walker in the lane is near the path
    assert decision.action == ("stop" if stops else "go")
    if stops:
        assert decision.stop_distance == distance - expert.OBSTACLE_MARGIN


@settings(max_examples=100, deadline=None)
@given(offset=st.floats(-8.0, 9.0), distance=st.floats(0.5, 40.0), kind=st.sampled_from(["pedestrian", "car"]),
       heading=st.floats(-0.2, 0.2))
def test_a_walker_on_the_carriageway_or_at_the_kerb_is_yielded_to_a_car_beside_the_lane_is_not(
        offset, distance, kind, heading):
    obs = observation(kind=kind, distance=distance, offset=offset)
    # the lane centre turned by ``heading`` around the ego: the offset is measured across the route
    c, s = math.cos(heading), math.sin(heading)
    route = tuple((c * x - s * y, s * x + c * y) for x, y in STRAIGHT)
    forward = 2.35 + distance
    actor = obs.ground_truth.actors[0]
    moved = type(actor)(actor.actor_id, kind, x=c * forward - s * offset, y=s * forward + c * offset,
                        length=actor.length, width=actor.width, height=actor.height)
    gt = type(obs.ground_truth)(**{**obs.ground_truth.__dict__, "actors": (moved,), "route_ahead": route})
    obs = type(obs)(**{**obs.__dict__, "ground_truth": gt})
    assert abs(expert.lateral_offset(obs, moved.x, moved.y) - offset) < 1e-6
    half = 0.3
    on_road = -expert.LANE_HALF_WIDTH - expert.KERB_CAUTION <= offset + half and \
        offset - half <= expert.LANE_HALF_WIDTH + expert.OPPOSITE_LANE_WIDTH
    assert expert.near_path(obs) == (kind == "pedestrian" and on_road)


@settings(max_examples=60, deadline=None)
@given(distance=st.floats(3.0, expert.LIGHT_SIGHT_DISTANCE), colour=st.sampled_from(["red", "green"]),
       seed=st.integers(0, 1000))
def test_the_expert_stops_for_red_and_passes_green_and_names_the_light_wherever_it_is_seen(distance, colour, seed):
    # A lamp is one pixel at every distance: "road clear" with a lamp in view would contradict "red light"
    # on the same pixel a few metres later.
    obs = observation(kind="traffic_light", distance=distance, light=colour)
    decision = expert.ExpertDriver().decide(obs)
    assert decision.action == ("stop" if colour == "red" else "go")
    assert colour in expert.sentence_cot(decision, 8.0, np.random.default_rng(seed)).lower()


@settings(max_examples=80, deadline=None)
@given(distance=st.floats(1.5, 60.0), colour=st.sampled_from(["red", "yellow", "green"]),
       speed=st.floats(0.0, 10.0), seed=st.integers(0, 1000))
def test_a_sentence_that_names_a_light_colour_names_the_true_one(distance, colour, speed, seed):
    obs = observation(speed=speed, kind="traffic_light", distance=distance, light=colour)
    decision = expert.ExpertDriver().decide(obs)
    sentence = expert.sentence_cot(decision, speed, np.random.default_rng(seed)).lower()
    named = {c for c in ("red", "yellow", "green") if c in sentence}
    assert named <= {colour}


def test_the_stop_sign_is_passed_after_a_full_stop():
    driver = expert.ExpertDriver()
    assert driver.decide(observation(speed=5.0, kind="stop_sign", distance=10.0)).action == "stop"
    assert driver.decide(observation(speed=0.0, kind="stop_sign", distance=1.5)).action == "go"
    assert driver.decide(observation(speed=2.0, kind="stop_sign", distance=1.0)).action == "go"


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), speed=st.floats(2.0, 9.0), distance=st.floats(4.0, 30.0))
def test_counterfactuals_state_the_opposite_and_follow_it_unless_vision_vetoes(seed, speed, distance):
    rng = np.random.default_rng(seed)
    clear = observation(speed=speed)
    action, text, controls = expert.counterfactual(clear, expert.Decision("go", "clear"), 8.0, rng)
    assert action == "stop" and text
    assert travelled(controls, speed) < travelled(expert.rollout_controls(speed, clear.ground_truth, None, 8.0),
                                                   speed)
    blocked = observation(speed=speed, kind="pedestrian", distance=distance, blocking=True)
    decision = expert.ExpertDriver().decide(blocked)
    action, text, controls = expert.counterfactual(blocked, decision, 8.0, rng)
    assert action == "go" and text in expert.GO_CLEAR + expert.GO_REASON["not_blocking_pedestrian"]
    obeyed = expert.salience(blocked) < expert.SALIENCE_THRESHOLD
    if obeyed:  # the "clear road" text is followed, at the cruise speed it commits to
        followed = expert.rollout_controls(speed, blocked.ground_truth, None, expert.cruise_for(text, 8.0))
    else:  # vision vetoes: the expert's own stop, braking now
        followed = expert.rollout_controls(speed, blocked.ground_truth, decision.stop_distance, 8.0, brake_now=True)
    assert np.array_equal(controls, followed)


def test_salience_is_larger_for_a_car_than_a_pedestrian_at_the_same_distance():
    car = observation(kind="car", distance=12.0, blocking=True)
    pedestrian = observation(kind="pedestrian", distance=12.0, blocking=True, offset=1.5)
    assert expert.salience(car) > expert.SALIENCE_THRESHOLD > expert.salience(pedestrian)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), speed=st.floats(0.0, 10.0))
def test_control_normalisation_round_trips_through_the_rollout(seed, speed):
    controls = np.random.default_rng(seed).normal(size=(30, 2)) * [2.0, 0.05]
    a = rollout(controls[:, 0], controls[:, 1], speed, 0.1)
    b = controls_to_trajectory(normalise_controls(controls), speed, 0.1)
    assert np.allclose(a.xy, b.xy) and a.problems() is None


def test_cot_templates_cover_every_decision():
    rng = np.random.default_rng(0)
    for kind in ("pedestrian", "car", "animal"):
        decision = expert.Decision("stop", "blocking", kind, 5.0)
        assert kind.split()[0] in expert.sentence_cot(decision, 5.0, rng).lower()
        slots = expert.slot_cot(observation(kind=kind, distance=10.0, blocking=True), decision, rng)
        assert set(slots) == {"scene", "objects", "decision"} and "stop" in slots["decision"]
        assert slots["objects"].startswith(kind.capitalize())
    for kind in ("pedestrian", "animal"):  # yielding to a walker near the path never claims it blocks the lane
        decision = expert.Decision("stop", "near_path", kind, 5.0)
        for speed in (0.0, 5.0):
            sentence = expert.sentence_cot(decision, speed, rng).lower()
            assert kind in sentence and "blocking" not in sentence
        slots = expert.slot_cot(observation(kind=kind, distance=10.0, offset=3.0), decision, rng)
        assert "blocking" not in slots["objects"] + slots["decision"] and "stop" in slots["decision"]


@settings(max_examples=60, deadline=None)
@given(speed=st.floats(0.0, 10.0), stop=st.floats(0.0, 120.0))
def test_a_stop_cot_stops_at_its_point_and_approaches_only_a_far_one(speed, stop):
    gt = observation(speed=speed).ground_truth
    committed = travelled(expert.rollout_controls(speed, gt, stop, 8.0, brake_now=True), speed)
    if speed * speed / (2 * expert.MAX_DECEL) < stop:
        assert committed <= stop + 0.25  # 10 Hz discretisation
    if speed == 0.0:  # from rest: approach a far stop point, wait for a near one
        assert (committed > 0.5) == (stop > expert.APPROACH_MIN_ROOM + 1.0) or \
            expert.APPROACH_MIN_ROOM <= stop <= expert.APPROACH_MIN_ROOM + 1.0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), slow=st.floats(0.0, 3.9), distance=st.floats(3.0, 9.0))
@example(seed=800, slow=0.0, distance=7.0)  # the expert's plan may roll on briefly before it brakes
def test_a_slow_step_near_a_salient_obstacle_is_also_learnt_at_speed_braking_hard(seed, slow, distance):
    from vdb_model_neural.data import FAST_SPEEDS, ExpertModel

    recorded = []
    model = ExpertModel(np.random.default_rng(seed), 8.0, recorded.append)
    obs = observation(speed=slow, kind="car", distance=distance, blocking=True)
    decision = model.driver.decide(obs)
    assert expert.vision_vetoes(obs, decision)
    model.generate_cot(obs, np.random.default_rng(0))
    assert recorded[-1]["speed"] == slow  # the step as driven is always recorded, last
    for fast in recorded[:-1]:
        speed = fast["speed"]
        assert FAST_SPEEDS[0] <= speed <= FAST_SPEEDS[1] and fast["decision"] == "stop"
        assert fast["cf_vetoed"] and fast["cf_controls"][0, 0] < 0  # "the road is clear" is overridden: brake now
        reachable = speed * speed / (2 * expert.MAX_DECEL * 0.8)
        if decision.stop_distance > reachable + 0.5:  # the expert's own plan stops short of the car
            assert travelled(fast["controls"], speed) <= decision.stop_distance + 0.3


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), scenario_id=st.sampled_from(["P.1", "P.4", "C.1", "C.2", "TL.1-red", "S.1"]))
def test_variants_keep_the_critical_object_and_a_green_light_stands_only_beyond_the_obstacles(seed, scenario_id):
    from vdb_model_neural.data import variant
    from vladrivebench.world import load_suite

    scenario = load_suite()[scenario_id]
    changed = variant(scenario, np.random.default_rng(seed))
    assert changed.family == scenario.family and changed.critical == scenario.critical
    if scenario.light is None and changed.light is not None:
        assert scenario.layout == "straight" and changed.light.state == "green"
        assert all(changed.light.stop_line > actor.s for actor in changed.actors)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), steps=st.integers(1, 60), speed=st.floats(1.0, 10.0))
def test_a_wandering_expert_veers_in_bounded_bursts_but_records_its_own_plan(seed, steps, speed):
    from vdb_model_neural.data import WANDER_CURVATURE, WANDER_STEPS, ExpertModel

    recorded = []
    model = ExpertModel(np.random.default_rng(seed), 8.0, recorded.append, wander=True)
    obs = observation(speed=speed)
    decision = model.driver.decide(obs)
    run, curvature = 0, None
    for _ in range(steps):
        executed = model.generate_cot(obs, np.random.default_rng(0)).state
        assert np.array_equal(recorded[-1]["controls"], model.driver.plan(obs, decision))  # the way back
        veered = not np.array_equal(executed, recorded[-1]["controls"])
        if veered:  # a constant-curvature arc within bounds, in bursts no longer than WANDER_STEPS allow
            assert np.all(executed[:, 1] == executed[0, 1])
            assert WANDER_CURVATURE[0] <= abs(executed[0, 1]) <= WANDER_CURVATURE[1]
        run = run + 1 if veered and executed[0, 1] == curvature else int(veered)  # bursts may follow one another
        curvature = executed[0, 1] if veered else None
        assert run <= WANDER_STEPS[1]
