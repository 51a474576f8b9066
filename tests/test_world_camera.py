"""The pinhole renderer: visual salience is physical (nearer / bigger ⇒ more pixels), colours show."""

from __future__ import annotations

import math

import numpy as np
import pytest
import vladrivebench.world._camera as camera_module
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._scenarios.spec import parse_scenario
from vladrivebench.records import Actor, EgoState
from vladrivebench.world._camera import LAMP_COLOURS, Camera, _fill_convex, count_pixels_differing
from vladrivebench.world._roads import build_road

EGO = EgoState(0.0, -1.75, 0.0, 0.0)


@pytest.fixture(scope="module")
def road():
    data = {"id": "T", "title": "t", "family": "intervention", "group": "g", "layout": "straight",
            "command": "follow_lane", "max_time_s": 30.0, "road": {"approach_length": 150.0}}
    return build_road(parse_scenario(data, "t.toml"))


@pytest.fixture(scope="module")
def camera():
    return Camera(160, 80)


def footprint(camera, road, actor, ego=EGO) -> int:
    empty = camera.render(road, ego, [], props=())
    return count_pixels_differing(empty, camera.render(road, ego, [actor], props=()))


def pedestrian(x, y=-1.75):
    return Actor("p", "pedestrian", x, y, math.pi / 2, 0.5, 0.6, 1.75)


def car(x, y=-1.75):
    return Actor("c", "car", x, y, 0.0, 4.6, 1.9, 1.5)


def test_image_shape_dtype_and_sky_over_ground(camera, road):
    image = camera.render(road, EGO, [])
    assert image.shape == (80, 160, 3) and image.dtype == np.uint8
    top, bottom = image[2].astype(int), image[-2].astype(int)
    assert top[:, 2].mean() > top[:, 0].mean() + 40  # blue sky
    assert abs(bottom[80, 0] - bottom[80, 2]) < 15  # grey asphalt under the ego


@pytest.mark.parametrize("make", [pedestrian, car])
def test_nearer_objects_cover_more_pixels(camera, road, make):
    sizes = [footprint(camera, road, make(EGO.x + d)) for d in (8.0, 15.0, 30.0, 60.0)]
    assert sizes[0] > sizes[1] > sizes[2] > sizes[3] > 0


def test_bigger_objects_cover_more_pixels(camera, road):
    for distance in (10.0, 25.0):
        assert footprint(camera, road, car(distance)) > 3 * footprint(camera, road, pedestrian(distance))


@pytest.mark.parametrize("distance", [10.0, 20.0, 30.0])
def test_blocking_car_dwarfs_a_kerbside_pedestrian(camera, road, distance):
    kerbside = footprint(camera, road, pedestrian(distance, y=-1.75 - 1.0))
    blocking = footprint(camera, road, car(distance))
    assert 0 < kerbside and blocking > 4 * kerbside


def test_a_sub_pixel_pedestrian_still_tints_the_image(camera, road):
    assert 0 < footprint(camera, road, pedestrian(90.0)) <= 4


def test_pixel_count_follows_inverse_square_of_distance(camera, road):
    big = Camera(640, 320)
    near, far = footprint(big, road, car(15.0)), footprint(big, road, car(30.0))
    assert near / far == pytest.approx(4.0, rel=0.35)


@pytest.mark.parametrize("state", ["red", "yellow", "green"])
def test_the_lit_lamp_colour_is_visible(camera, road, state):
    light = Actor("tl0", "traffic_light", 25.0, -4.5, math.pi, 0.35, 0.45, 5.2, 0.0, state)
    image = camera.render(road, EGO, [light], props=())
    target = np.array(LAMP_COLOURS[state])
    assert np.any(np.all(image == target, axis=-1))
    for other in {"red", "yellow", "green"} - {state}:
        assert not np.any(np.all(image == np.array(LAMP_COLOURS[other]), axis=-1))


def test_a_far_lit_lamp_still_shows_one_pixel(camera, road):
    light = Actor("tl0", "traffic_light", 150.0, -4.5, math.pi, 0.35, 0.45, 5.2, 0.0, "red")
    image = camera.render(road, EGO, [light], props=())
    assert np.any(np.all(image == np.array(LAMP_COLOURS["red"]), axis=-1))


def test_a_lamp_is_dark_from_behind(camera, road):
    light = Actor("tl0", "traffic_light", 25.0, -4.5, 0.0, 0.35, 0.45, 5.2, 0.0, "red")  # facing away
    image = camera.render(road, EGO, [light], props=())
    assert not np.any(np.all(image == np.array(LAMP_COLOURS["red"]), axis=-1))


def test_stop_sign_is_red(camera, road):
    sign = Actor("s", "stop_sign", 12.0, -4.0, math.pi, 0.05, 0.75, 2.4)
    image = camera.render(road, EGO, [sign], props=()).astype(int)
    reds = (image[..., 0] > 150) & (image[..., 1] < 60) & (image[..., 2] < 60)
    assert reds.sum() >= 4


def test_painter_order_nearer_object_occludes_farther(camera, road):
    near, far = car(12.0), car(24.0)
    both = camera.render(road, EGO, [near, far], props=())
    reversed_order = camera.render(road, EGO, [far, near], props=())
    only_near = camera.render(road, EGO, [near], props=())
    assert np.array_equal(both, reversed_order)
    # The far car is hidden exactly where the near one is drawn.
    mask = np.any(only_near != camera.render(road, EGO, [], props=()), axis=-1)
    assert np.array_equal(both[mask], only_near[mask])


def test_objects_behind_the_camera_are_not_drawn(camera, road):
    assert footprint(camera, road, car(-10.0)) == 0


def test_rendering_is_deterministic(camera, road):
    scene = [car(20.0), pedestrian(12.0, -3.0)]
    assert camera.render(road, EGO, scene).tobytes() == camera.render(road, EGO, scene).tobytes()


polygons = st.lists(st.tuples(st.floats(-10, 50), st.floats(-10, 30)), min_size=3, max_size=6)


@given(st.floats(-5, 40), st.floats(-5, 25), st.floats(0.5, 20), st.floats(0.5, 15), st.floats(-math.pi, math.pi))
@settings(max_examples=100)
def test_fill_convex_paints_exactly_the_pixel_centres_inside(cx, cy, a, b, angle):
    c, s = math.cos(angle), math.sin(angle)
    corners = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in ((a, b), (-a, b), (-a, -b), (a, -b))]
    u, v = [p[0] for p in corners], [p[1] for p in corners]
    image = np.zeros((24, 40, 3))
    painted = _fill_convex(image, u, v, np.array([1.0, 1.0, 1.0]))
    # Brute force: a pixel centre is inside the rectangle iff its local coordinates are within ±a, ±b.
    pu, pv = np.meshgrid(np.arange(40) + 0.5, np.arange(24) + 0.5)
    lx = c * (pu - cx) + s * (pv - cy)
    ly = -s * (pu - cx) + c * (pv - cy)
    margin = 1e-9
    surely_in = (np.abs(lx) < a - margin) & (np.abs(ly) < b - margin)
    surely_out = (np.abs(lx) > a + margin) | (np.abs(ly) > b + margin)
    full = image[..., 0] == 1.0
    assert np.all(full[surely_in]) and not np.any(full[surely_out])
    if full.any():
        assert painted == int(full.sum()) == int((image[..., 0] > 0).sum())
    else:  # smaller than a pixel: blended into at most one pixel by the area it covers
        assert painted <= 1 and int((image[..., 0] > 0).sum()) == painted


def _fill_face_by_face(faces, image, colours, at_least_one):
    """The reference: every face through :func:`_fill_convex`, one after the other."""
    for m in range(len(faces.area)):
        u, v = faces.polygon(m)
        _fill_convex(image, u, v, colours[m], at_least_one=bool(at_least_one[m]))


actor_kinds = st.sampled_from(("pedestrian", "car", "animal", "traffic_light", "stop_sign", "cone"))
scene_actors = st.lists(st.tuples(actor_kinds, st.floats(-3.0, 120.0), st.floats(-25.0, 25.0),
                                  st.floats(-math.pi, math.pi), st.floats(0.05, 6.0), st.floats(0.05, 3.0),
                                  st.floats(0.1, 5.0), st.sampled_from(("red", "yellow", "green"))),
                        min_size=1, max_size=12)


@given(scene_actors, st.sampled_from([(160, 80, 90.0), (33, 17, 150.0), (97, 41, 30.0)]))
@settings(max_examples=60, deadline=None)
def test_the_vectorised_face_fill_paints_what_filling_face_by_face_paints(road, monkeypatch_faces, actors, size):
    """Painter's order, sub-pixel blends, near-plane clipping: the one-pass fill equals the face-by-face one."""
    width, height, hfov = size
    camera = Camera(width, height, hfov)
    scene = [Actor(f"a{i}", kind, x, y, yaw, ln, wd, h, state=state if kind == "traffic_light" else None)
             for i, (kind, x, y, yaw, ln, wd, h, state) in enumerate(actors)]
    fast = camera.render(road, EGO, scene)
    with monkeypatch_faces() as patch:
        patch.setattr(camera_module._FaceList, "fill", _fill_face_by_face)
        reference = camera.render(road, EGO, scene)
    assert np.array_equal(fast, reference)


@pytest.fixture(scope="module")
def monkeypatch_faces():
    return pytest.MonkeyPatch.context
