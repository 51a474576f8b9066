"""The camera rig: presets, camera geometry (intrinsics, extrinsics, where each camera looks), the recorder's
frame and pose history, rig options, route text, and the observation records that carry them."""

from __future__ import annotations

import dataclasses
import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench import CameraSpec, CameraView, ConfigError, EgoState, Observation, PoseHistory
from vladrivebench.records import Actor, GroundTruth
from vladrivebench.world import (
    ALPAMAYO_RIG,
    FRONT_RIG,
    RIG_PRESETS,
    Camera,
    RigRecorder,
    build_road,
    check_history_options,
    count_pixels_differing,
    parse_scenario,
    rig_from_options,
    route_text,
)

DEFAULTS = {"rig": "front", "cameras": None, "width": None, "height": None, "render": True, "hfov_deg": 90.0,
            "camera_height": 1.6, "pitch_deg": 0.0, "position_jitter": 0.2}
HISTORY = {"frames": 1, "frame_rate_hz": 10.0, "poses": 16}


def scenario(layout="straight", command="follow_lane"):
    road = {"approach_length": 60.0, **({"junction_side": "through"} if layout == "t_junction" else {})}
    data = {"id": "R.1", "title": "t", "family": "intervention", "group": "g", "layout": layout,
            "command": command, "max_time_s": 20.0, "road": road}
    return parse_scenario(data, "rig.toml")


@pytest.fixture(scope="module")
def road():
    return build_road(scenario())


def ego_at_start(road):
    x, y = (float(v) for v in road.route.position(0.0))
    return EgoState(x, y, float(road.route.heading(0.0)), 5.0)


# -- presets and options --------------------------------------------------------------------------


def test_presets_name_their_cameras_with_their_sizes():
    assert set(RIG_PRESETS) == {"front", "alpamayo"}
    assert FRONT_RIG.names == ("front",) and (FRONT_RIG.cameras[0].width, FRONT_RIG.cameras[0].height) == (160, 80)
    assert ALPAMAYO_RIG.names == ("front_wide", "front_tele", "cross_left", "cross_right")
    assert all((spec.width, spec.height) == (576, 320) for spec in ALPAMAYO_RIG.cameras)


def test_default_options_give_the_single_front_camera_of_before():
    (spec,) = rig_from_options("sim", DEFAULTS)
    assert spec == CameraSpec("front", 160, 80, 90.0, x=0.8, y=0.0, z=1.6, yaw_deg=0.0, pitch_deg=0.0)
    assert check_history_options("sim", HISTORY) == 1


def test_the_default_front_camera_renders_exactly_as_the_camera_of_before(road):
    ego = ego_at_start(road)
    (spec,) = rig_from_options("sim", {**DEFAULTS, "width": 48, "height": 24, "pitch_deg": 5.0})
    before = Camera(48, 24, 90.0, mount_height=1.6, pitch_deg=5.0).render(road, ego)
    assert np.array_equal(Camera.from_spec(spec).render(road, ego), before)


def test_width_height_and_a_camera_subset_apply_to_the_chosen_rig():
    specs = rig_from_options("sim", {**DEFAULTS, "rig": "alpamayo", "cameras": "cross_right,front_wide",
                                     "width": 64, "height": 40})
    assert [s.name for s in specs] == ["cross_right", "front_wide"]
    assert all((s.width, s.height) == (64, 40) for s in specs)
    assert rig_from_options("sim", {**DEFAULTS, "rig": "alpamayo", "cameras": ["front_tele"]})[0].hfov_deg == 30.0


@pytest.mark.parametrize("changes,needle", [
    ({"rig": "bogus"}, "option rig must be one of alpamayo, front, got 'bogus'"),
    ({"rig": 3}, "option rig must be one of alpamayo, front, got 3"),
    ({"rig": "alpamayo", "cameras": "front_wide,rear"}, "option cameras must be camera names of rig 'alpamayo'"),
    ({"cameras": "front,front"}, "each once, got 'front'"),
    ({"cameras": []}, "option cameras must be"),
    ({"width": 4}, "option width must be a whole number between 8 and 4096, got 4"),
    ({"rig": "alpamayo", "height": 7}, "option height must be a whole number between 8 and 4096, got 7"),
    ({"rig": "alpamayo", "hfov_deg": 60.0}, "option hfov_deg applies to rig 'front' only, got 60.0"),
    ({"rig": "alpamayo", "pitch_deg": 3}, "option pitch_deg applies to rig 'front' only"),
])
def test_bad_rig_options_are_one_line_errors_naming_the_option(changes, needle):
    with pytest.raises(ConfigError) as info:
        rig_from_options("sim", {**DEFAULTS, **changes})
    assert needle in str(info.value) and "\n" not in str(info.value)
    assert str(info.value).startswith("simulator 'sim': option ")


@pytest.mark.parametrize("changes,needle", [
    ({"frames": 0}, "option frames must be a whole number between 1 and 16, got 0"),
    ({"frames": 17}, "got 17"),
    ({"frames": 2.0}, "option frames must be a whole number"),
    ({"frame_rate_hz": 3}, "option frame_rate_hz must be 10 Hz divided by a whole number from 1 to 100"),
    ({"frame_rate_hz": 0}, "option frame_rate_hz"),
    ({"frame_rate_hz": 20}, "option frame_rate_hz"),
    ({"frame_rate_hz": float("nan")}, "option frame_rate_hz"),
    ({"frame_rate_hz": "fast"}, "got 'fast'"),
    ({"poses": -1}, "option poses must be a whole number between 0 and 100, got -1"),
    ({"poses": True}, "option poses"),
])
def test_bad_history_options_are_one_line_errors(changes, needle):
    with pytest.raises(ConfigError) as info:
        check_history_options("sim", {**HISTORY, **changes})
    assert needle in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("rate,stride", [(10, 1), (5.0, 2), (2.5, 4), (2, 5), (1, 10), (0.1, 100)])
def test_frame_rates_are_whole_strides_of_the_step(rate, stride):
    assert check_history_options("sim", {**HISTORY, "frame_rate_hz": rate}) == stride


# -- camera geometry ------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(yaw=st.floats(-180, 180), pitch=st.floats(-30, 60), x=st.floats(-2, 2), y=st.floats(-1, 1),
       z=st.floats(0.3, 3), point=st.tuples(st.floats(-30, 30), st.floats(-30, 30), st.floats(0, 5)),
       ego_yaw=st.floats(-math.pi, math.pi))
def test_extrinsics_and_intrinsics_agree_with_the_renderers_projection(yaw, pitch, x, y, z, point, ego_yaw):
    spec = CameraSpec("c", 64, 32, 75.0, x=x, y=y, z=z, yaw_deg=yaw, pitch_deg=pitch)
    ego = EgoState(3.0, -2.0, ego_yaw, 0.0)
    world = np.array([*ego.to_world_frame(point[0], point[1]), point[2]])
    rendered = Camera.from_spec(spec)._to_camera(ego, world)
    transform = np.array(spec.extrinsics)
    rotation, origin = transform[:3, :3], transform[:3, 3]
    assert np.allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.allclose(rotation.T @ (np.array(point) - origin), rendered, atol=1e-9)
    assert np.allclose(transform[3], (0, 0, 0, 1))
    k = np.array(spec.intrinsics)
    assert k[0, 0] == pytest.approx(Camera.from_spec(spec).focal) and (k[0, 2], k[1, 2]) == (32.0, 16.0)


def car_beside(ego: EgoState, forward: float, left: float) -> Actor:
    x, y = ego.to_world_frame(forward, left)
    return Actor("car0", "car", x, y, ego.yaw, 4.5, 1.8, 1.5)


@pytest.mark.parametrize("left,seen_by", [(8.0, "cross_left"), (-8.0, "cross_right"), (25.0, None)])
def test_a_car_to_one_side_appears_only_in_that_sides_cross_camera(road, left, seen_by):
    ego = ego_at_start(road)
    forward = 2.0 if seen_by else 30.0  # the last case: far ahead, seen by the front cameras only
    pixels, columns = {}, {}
    for spec in ALPAMAYO_RIG.cameras:
        camera = Camera.from_spec(dataclasses.replace(spec, width=96, height=54))
        empty = camera.render(road, ego, (), props=())
        with_car = camera.render(road, ego, (car_beside(ego, forward, left if seen_by else 0.0),), props=())
        pixels[spec.name] = count_pixels_differing(empty, with_car)
        columns[spec.name] = np.flatnonzero(np.any(empty != with_car, axis=(0, 2)))
    if seen_by:
        other = "cross_right" if seen_by == "cross_left" else "cross_left"
        assert pixels[seen_by] > 50 and pixels[other] == 0 and pixels["front_wide"] == 0
        # The car is straight ahead of the sideways camera (both 2 m ahead of the ego's centre).
        assert abs(columns[seen_by].mean() - 48) < 3
    else:
        assert pixels["front_wide"] > 0 and pixels["front_tele"] > pixels["front_wide"]
        assert pixels["cross_left"] == pixels["cross_right"] == 0


def test_the_alpamayo_rig_renders_four_images_of_its_size(road):
    recorder = RigRecorder(ALPAMAYO_RIG.cameras, frames=4, stride=1, poses=16)
    recorder.reset()
    image, views, _ = recorder.observe(0, 0.0, ego_at_start(road), road, ())
    assert list(views) == list(ALPAMAYO_RIG.names)
    assert all(view.latest.shape == (320, 576, 3) and view.latest.dtype == np.uint8 for view in views.values())
    assert image is views["front_wide"].latest and not image.flags.writeable  # shared by 4 steps
    assert not np.array_equal(views["cross_left"].latest, views["cross_right"].latest)


# -- history --------------------------------------------------------------------------------------


def drive(recorder, road, steps, speed=5.0, actors=()):
    ego = ego_at_start(road)
    recorder.reset()
    out = []
    for step in range(steps):
        moved = EgoState(*ego.to_world_frame(speed * 0.1 * step, 0.0), ego.yaw, speed)
        out.append((moved, recorder.observe(step, round(0.1 * step, 10), moved, road, actors)))
    return out


@settings(max_examples=25, deadline=None)
@given(frames=st.integers(1, 5), stride=st.integers(1, 4), steps=st.integers(1, 14))
def test_windows_hold_the_last_frames_taken_every_stride_oldest_first(frames, stride, steps):
    recorder = RigRecorder((CameraSpec("a", 8, 8), CameraSpec("b", 10, 8)), frames, stride, poses=0, render=False)
    road = build_road(scenario())
    _, (_, views, poses) = drive(recorder, road, steps)[-1]
    taken = [s for s in range(steps) if s % stride == 0][-frames:]
    for view in views.values():
        assert view.times == tuple(round(0.1 * s, 10) for s in taken)
        assert len(view.frames) == len(taken)
    assert views["b"].latest.shape == (8, 10, 3) and poses == PoseHistory()


def test_frames_are_rendered_only_on_their_steps_and_reused_between(road):
    recorder = RigRecorder((dataclasses.replace(FRONT_RIG.cameras[0], width=32, height=16),), frames=3, stride=2)
    history = drive(recorder, road, 6, actors=(car_beside(ego_at_start(road), 12.0, 0.0),))
    views = [views["front"] for _, (_, views, _) in history]
    assert views[1].frames[-1] is views[0].frames[-1]  # step 1: no new frame
    assert views[2].frames[-1] is not views[1].frames[-1] and views[2].times == (0.0, 0.2)
    assert not np.array_equal(views[4].frames[-1], views[0].frames[-1])  # the ego moved 2 m
    assert views[5].times == (0.0, 0.2, 0.4) and views[5].frames[0] is views[0].frames[0]
    assert not views[5].frames[0].flags.writeable


def test_the_default_rig_gives_each_step_its_own_writable_image_as_before(road):
    recorder = RigRecorder((dataclasses.replace(FRONT_RIG.cameras[0], width=16, height=8),))
    images = [image for _, (image, _, _) in drive(recorder, road, 3)]
    assert all(image.flags.writeable for image in images) and images[0] is not images[1]


def test_pose_history_holds_the_last_poses_newest_last(road):
    recorder = RigRecorder((CameraSpec("a", 8, 8),), poses=4, render=False)
    history = drive(recorder, road, 7, speed=10.0)
    egos = [ego for ego, _ in history]
    poses = history[-1][1][2]
    assert poses.states == tuple(egos[-4:]) and poses.times == (0.3, 0.4, 0.5, 0.6)
    relative = poses.in_ego_frame()
    assert [round(x, 9) for x, _, _ in relative] == [-3.0, -2.0, -1.0, 0.0]
    assert all(abs(y) < 1e-9 and abs(yaw) < 1e-12 for _, y, yaw in relative)
    first = history[0][1][2]
    assert first.states == (egos[0],) and first.in_ego_frame() == ((0.0, 0.0, 0.0),)


# -- route text -----------------------------------------------------------------------------------


def test_route_text_names_the_manoeuvre_and_its_distance():
    junction = build_road(scenario("t_junction", "left"))
    start, end = junction.junction_span
    span = junction.junction_span
    assert route_text("left", start - 12.4, 200.0, span) == "In 12 m, turn left at the junction."
    assert route_text("right", start + 1.0, 200.0, span) == "At the junction: turn right."
    assert route_text("straight", 0.0, 200.0, span).endswith("go straight at the junction.")
    assert route_text("left", end + 1.0, end + 31.0, span) == "Follow the road for 30 m to the end of the route."
    assert build_road(scenario()).junction_span is None
    assert route_text("left", 10.0, 70.0) == "Follow the road for 60 m to the end of the route."


# -- records --------------------------------------------------------------------------------------


def observation(**extra) -> Observation:
    image = np.full((4, 6, 3), 7, np.uint8)
    return Observation(0, 0.0, image, EgoState(0, 0, 0, 0), "follow_lane", GroundTruth(0, 0.0), **extra)


def test_observations_without_a_rig_have_a_front_view_of_their_image():
    obs = observation()
    assert obs.cameras == {} and obs.pose_history == PoseHistory() and obs.route_text == ""
    (name, view), = obs.camera_views().items()
    assert name == "front" and view.latest is obs.image and (view.spec.width, view.spec.height) == (6, 4)


def test_camera_records_pickle_and_keep_images_out_of_repr_and_comparison():
    spec = CameraSpec("cross_left", 6, 4, 120.0, yaw_deg=90.0)
    view = CameraView(spec, (np.zeros((4, 6, 3), np.uint8), np.ones((4, 6, 3), np.uint8)), (0.0, 0.1))
    obs = observation(cameras={"cross_left": view}, route_text="go",
                      pose_history=PoseHistory((0.0,), (EgoState(0, 0, 0, 0),)))
    copy = pickle.loads(pickle.dumps(obs))
    assert copy == obs and np.array_equal(copy.cameras["cross_left"].frames[1], view.frames[1])
    assert "array" not in repr(obs) and "array" not in repr(view)
    assert obs == observation(route_text="go", pose_history=obs.pose_history)
    assert obs != observation(route_text="other", pose_history=obs.pose_history)
