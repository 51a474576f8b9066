"""Oriented boxes on the ground plane and their overlap test (separating-axis theorem).

Two convex polygons are disjoint if and only if some edge normal of one of them separates their
projections; a rectangle has two distinct edge normals, so two oriented boxes need four axis tests.
Touching boxes (projections meeting at a single point) count as overlapping.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from vladrivebench.records import Actor, EgoState


@dataclass(frozen=True)
class Box:
    """A rectangle centred at (x, y), rotated by ``yaw``; ``length`` along the heading, ``width`` across."""

    x: float
    y: float
    yaw: float
    length: float
    width: float

    @staticmethod
    def of_ego(ego: EgoState) -> Box:
        return Box(ego.x, ego.y, ego.yaw, ego.length, ego.width)

    @staticmethod
    def of_actor(actor: Actor) -> Box:
        return Box(actor.x, actor.y, actor.yaw, actor.length, actor.width)

    def axes(self) -> np.ndarray:
        """The two unit axes (heading, left) as rows."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, s], [-s, c]])

    def corners(self) -> np.ndarray:
        """The four corners, counter-clockwise from front-left, shape (4, 2)."""
        axes = self.axes()
        half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float) * [self.length / 2, self.width / 2]
        return np.array([self.x, self.y]) + half @ axes

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of ``points`` (shape (N, 2)) lie inside or on the box."""
        rel = np.asarray(points, dtype=float) - [self.x, self.y]
        local = rel @ self.axes().T
        return (np.abs(local[:, 0]) <= self.length / 2) & (np.abs(local[:, 1]) <= self.width / 2)


def _half_extent(box: Box, axis: np.ndarray) -> float:
    """Half the length of ``box`` projected on the unit ``axis``."""
    heading, left = box.axes()
    return box.length / 2 * abs(float(heading @ axis)) + box.width / 2 * abs(float(left @ axis))


def overlap(a: Box, b: Box) -> bool:
    """True when the two boxes intersect (separating-axis theorem)."""
    centre_gap = np.array([b.x - a.x, b.y - a.y])
    for axis in (*a.axes(), *b.axes()):
        if abs(float(centre_gap @ axis)) > _half_extent(a, axis) + _half_extent(b, axis):
            return False
    return True


def colliding(ego: EgoState, actors: Iterable[Actor]) -> tuple[str, ...]:
    """Ids of the actors whose box overlaps the ego's."""
    ego_box = Box.of_ego(ego)
    return tuple(a.actor_id for a in actors if overlap(ego_box, Box.of_actor(a)))
