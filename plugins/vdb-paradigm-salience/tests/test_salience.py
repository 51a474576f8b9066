"""Salience geometry: the camera projection, angular size and rendered pixel coverage (property tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_paradigm_salience.salience import angular_size, box_corners, pixels_covered, to_camera
from vladrivebench import Actor, CameraSpec, EgoState
from vladrivebench.world import build_road, load_suite

FRONT = CameraSpec("front", 160, 80, 90.0)
EGO = EgoState(x=0.0, y=0.0, yaw=0.0, speed=0.0)


def ahead(distance: float, length: float = 0.5, width: float = 0.6, height: float = 1.6, left: float = 0.0) -> Actor:
    """A box facing the camera: its near face ``distance`` metres ahead of the camera, centred ``left``."""
    return Actor("ob", "pedestrian", FRONT.x + distance + length / 2, left, 0.0, length, width, height)


@given(st.floats(1, 100), st.floats(-3, 3), st.floats(0, 3))
def test_a_point_ahead_projects_right_down_depth(forward, left, up):
    point = np.array([[FRONT.x + forward, left, FRONT.z + up]])
    right, down, depth = to_camera(FRONT, EGO, point)[0]
    assert depth == pytest.approx(forward) and right == pytest.approx(-left) and down == pytest.approx(-up)


@given(st.floats(-math.pi, math.pi), st.floats(-50, 50), st.floats(-50, 50), st.floats(2, 60))
def test_the_projection_moves_with_the_ego(yaw, x, y, forward):
    ego = EgoState(x=x, y=y, yaw=yaw, speed=0.0)
    fx, fy = x + math.cos(yaw) * (FRONT.x + forward), y + math.sin(yaw) * (FRONT.x + forward)
    right, down, depth = to_camera(FRONT, ego, np.array([[fx, fy, FRONT.z]]))[0]
    assert (right, down, depth) == pytest.approx((0.0, 0.0, forward), abs=1e-6)


@given(st.floats(3, 80), st.floats(0.2, 3), st.floats(0.2, 3))
def test_the_angular_size_of_a_facing_box_is_the_pinhole_angle_of_its_near_face(distance, width, height):
    box = ahead(distance, length=1e-9, width=width, height=height)
    size = angular_size(FRONT, EGO, box)
    half_v = math.atan(FRONT.height / 2 / FRONT.focal)  # the image clips what lies beyond the field of view
    half_h = math.radians(FRONT.hfov_deg / 2)
    expected_w = 2 * min(math.atan(width / 2 / distance), half_h)
    top, bottom = math.atan((height - FRONT.z) / distance), math.atan(-FRONT.z / distance)
    expected_h = min(top, half_v) - max(bottom, -half_v)
    assert size["in_view"] and not size["partial"]
    assert size["angular_width_deg"] == pytest.approx(math.degrees(expected_w), rel=1e-6)
    assert size["angular_height_deg"] == pytest.approx(math.degrees(expected_h), rel=1e-6)
    assert size["solid_angle_deg2"] == pytest.approx(size["angular_width_deg"] * size["angular_height_deg"])

@given(st.floats(3, 60), st.floats(1.05, 3))
def test_nearer_or_bigger_is_never_smaller(distance, factor):
    base = angular_size(FRONT, EGO, ahead(distance))
    nearer = angular_size(FRONT, EGO, ahead(distance / factor))
    bigger = angular_size(FRONT, EGO, ahead(distance, 0.5 * factor, 0.6 * factor, 1.6 * factor))
    for other in (nearer, bigger):
        assert other["solid_angle_deg2"] >= base["solid_angle_deg2"] - 1e-9
        assert other["bbox_pixels"] >= base["bbox_pixels"] - 1e-9


def test_a_box_behind_the_camera_or_outside_the_image_is_not_in_view():
    behind = Actor("ob", "car", -10.0, 0.0, 0.0, 4.6, 1.9, 1.5)
    beside = Actor("ob", "car", FRONT.x + 1.0, 30.0, 0.0, 1.0, 1.0, 1.5)
    for actor in (behind, beside):
        size = angular_size(FRONT, EGO, actor)
        assert not size["in_view"] and size["bbox_pixels"] == 0.0 and size["solid_angle_deg2"] == 0.0
    assert box_corners(behind).shape == (8, 3)


def test_rendered_coverage_counts_the_obstacle_and_shrinks_with_distance():
    scenario = load_suite()["SAFE.centre-ped"]
    road = build_road(scenario)
    ego = EgoState(x=0.0, y=-1.75, yaw=0.0, speed=0.0)  # the ego lane's centre
    counts = []
    for distance in (8.0, 16.0, 32.0, 64.0):
        car = Actor("ob", "car", ego.x + FRONT.x + distance + 2.3, ego.y, 0.0, 4.6, 1.9, 1.5)
        counts.append(pixels_covered(FRONT, ego, road, (car,), "ob"))
    assert all(c > 0 for c in counts) and counts == sorted(counts, reverse=True), counts
    box = angular_size(FRONT, ego, Actor("ob", "car", ego.x + FRONT.x + 8.0 + 2.3, ego.y, 0.0, 4.6, 1.9, 1.5))
    assert counts[0] <= box["bbox_pixels"] + 2 * (box["angular_width_deg"] + box["angular_height_deg"])
    assert pixels_covered(FRONT, ego, road, (), "ob") == 0


@settings(max_examples=10, deadline=None)
@given(st.floats(4, 60))
def test_coverage_is_zero_without_the_obstacle_and_positive_with_it_in_view(distance):
    road = build_road(load_suite()["SAFE.centre-ped"])
    ego = EgoState(x=0.0, y=-1.75, yaw=0.0, speed=0.0)
    car = Actor("ob", "car", FRONT.x + distance + 2.3, -1.75, 0.0, 4.6, 1.9, 1.5)
    other = Actor("tl", "traffic_light", 115.0, -4.5, math.pi, 0.35, 0.45, 5.2, 0.0, "green")
    assert pixels_covered(FRONT, ego, road, (car, other), "ob") > 0
    assert pixels_covered(FRONT, ego, road, (other,), "ob") == 0
