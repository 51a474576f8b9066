"""Oriented-box collision (separating axes) against brute-force polygon sampling."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench.records import Actor, EgoState
from vladrivebench.world._boxes import Box, colliding, overlap

sizes = st.floats(0.2, 6.0)
positions = st.floats(-6.0, 6.0)
angles = st.floats(-math.pi, math.pi)
boxes = st.builds(Box, positions, positions, angles, sizes, sizes)


def sampled_overlap(a: Box, b: Box, n: int = 40) -> bool:
    """Do points sampled densely over either box (edges included) fall inside the other?"""
    grid = np.linspace(-0.5, 0.5, n)
    gx, gy = np.meshgrid(grid, grid)
    unit = np.column_stack([gx.ravel(), gy.ravel()])

    def points(box: Box) -> np.ndarray:
        local = unit * [box.length, box.width]
        return np.array([box.x, box.y]) + local @ box.axes()

    return bool(b.contains(points(a)).any() or a.contains(points(b)).any())


def separation(a: Box, b: Box) -> float:
    """The largest gap between the boxes' projections over the four candidate axes (> 0: disjoint)."""
    gap = -np.inf
    for axis in (*a.axes(), *b.axes()):
        pa, pb = a.corners() @ axis, b.corners() @ axis
        gap = max(gap, max(pb.min() - pa.max(), pa.min() - pb.max()))
    return gap


def _orientation(p, q, r) -> float:
    return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])


def _segments_cross(p1, p2, q1, q2) -> bool:
    d1, d2 = _orientation(q1, q2, p1), _orientation(q1, q2, p2)
    d3, d4 = _orientation(p1, p2, q1), _orientation(p1, p2, q2)
    if d1 == d2 == d3 == d4 == 0:  # collinear: do the intervals meet?
        return all(min(p1[k], p2[k]) <= max(q1[k], q2[k]) and min(q1[k], q2[k]) <= max(p1[k], p2[k])
                   for k in (0, 1))
    return d1 * d2 <= 0 and d3 * d4 <= 0


def edge_oracle(a: Box, b: Box) -> bool:
    """Brute force without projections: two convex polygons meet iff two edges cross or one holds a
    point (corner or centre) of the other."""
    ca, cb = a.corners(), b.corners()
    for i in range(4):
        for j in range(4):
            if _segments_cross(ca[i], ca[(i + 1) % 4], cb[j], cb[(j + 1) % 4]):
                return True
    centres = np.array([[a.x, a.y], [b.x, b.y]])
    return bool(a.contains(cb).any() or b.contains(ca).any() or a.contains(centres[1:]).any()
                or b.contains(centres[:1]).any())


@given(boxes, boxes)
@settings(max_examples=300)
def test_sat_agrees_with_brute_force(a, b):
    if abs(separation(a, b)) > 1e-6:  # exactly touching boxes are decided by rounding
        assert overlap(a, b) == edge_oracle(a, b)


@given(boxes, boxes)
@settings(max_examples=200)
def test_sampled_points_of_one_box_inside_the_other_mean_overlap(a, b):
    if sampled_overlap(a, b):
        assert overlap(a, b)
    if separation(a, b) > 1e-6:
        assert not sampled_overlap(a, b)


@given(boxes, boxes)
def test_overlap_is_symmetric(a, b):
    assert overlap(a, b) == overlap(b, a)


@given(boxes, boxes, angles, positions, positions)
def test_overlap_is_invariant_under_rigid_motion(a, b, turn, dx, dy):
    c, s = math.cos(turn), math.sin(turn)

    def moved(box: Box) -> Box:
        return Box(c * box.x - s * box.y + dx, s * box.x + c * box.y + dy, box.yaw + turn, box.length, box.width)

    if abs(separation(a, b)) > 1e-6:  # away from touching, where rounding decides
        assert overlap(moved(a), moved(b)) == overlap(a, b)


@given(boxes)
def test_a_box_overlaps_itself_and_its_corners_are_inside(box):
    assert overlap(box, box)
    assert box.contains(box.corners() * (1 - 1e-9) + np.array([box.x, box.y]) * 1e-9).all()


def test_touching_edges_overlap_and_a_gap_does_not():
    a = Box(0.0, 0.0, 0.0, 2.0, 2.0)
    assert overlap(a, Box(2.0, 0.0, 0.0, 2.0, 2.0))
    assert not overlap(a, Box(2.01, 0.0, 0.0, 2.0, 2.0))
    # Rotated 45°: the corner reaches sqrt(2) from the centre.
    assert overlap(a, Box(1.0 + math.sqrt(2) - 0.01, 0.0, math.pi / 4, 2.0, 2.0))
    assert not overlap(a, Box(1.0 + math.sqrt(2) + 0.01, 0.0, math.pi / 4, 2.0, 2.0))


def test_colliding_lists_the_actors_hit_by_the_ego():
    ego = EgoState(0.0, 0.0, 0.0, 5.0)
    actors = [Actor("near", "pedestrian", 2.5, 0.0), Actor("far", "car", 20.0, 0.0, length=4.6, width=1.9),
              Actor("side", "pedestrian", 0.0, 1.15), Actor("clear", "pedestrian", 0.0, 1.25)]
    assert colliding(ego, actors) == ("near", "side")
