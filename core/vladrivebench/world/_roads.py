"""Road layouts: the route the ego follows (a polyline with arc length s) and the ground's geometry.

World frame: x east, y north. The ego starts at the origin's x heading east, with its lane centre at
``y = -H + (lane + 0.5) w`` (right-hand traffic, ``H = lanes * w`` the half-width of the road). A junction
(T or 4-way) is a square centred at ``(J, 0)`` with ``J = approach_length + B``: its entry, where the
stop line is, lies at the route position ``s = approach_length``. ``B = H + corner_radius``: kerbs round
the corners between two existing arms with quarter circles of ``corner_radius``.

Every ground point gets a *road offset* ``m``: how far the road would have to grow to contain it
(``m <= 0`` on the road). Kerbs, sidewalks and open ground are bands of ``m``, which makes the kerbs follow
the rounded corners without special cases. The geometry is simulator-independent: the kinematic
simulator, the camera renderer and the ground-truth computation all read it, and another simulator can
build its network from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vladrivebench._scenarios.spec import Scenario

ROUTE_STEP = 0.25
"""Spacing of the route polyline's points (m)."""
ROUTE_TAIL = 80.0
"""How far the road and the route polyline continue past the route's end (m)."""
ROAD_BEHIND = 40.0
"""How far the road extends behind the ego's start (m)."""
KERB_WIDTH = 0.3

GRASS, SIDEWALK, KERB, ROAD, MARK_WHITE, MARK_YELLOW = range(6)
"""Ground material codes returned by :meth:`RoadGeometry.classify`."""

_DIRECTIONS = {"east": (1.0, 0.0), "west": (-1.0, 0.0), "north": (0.0, 1.0), "south": (0.0, -1.0)}
_CYCLE = ("east", "north", "west", "south")  # counter-clockwise; adjacent names share a corner


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(angle) + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True, eq=False)
class Route:
    """The centre line of the ego's lane along its route.

    ``points`` (N, 2) are spaced at most :data:`ROUTE_STEP` apart, ``s`` their arc length and
    ``headings`` the (unwrapped) tangent direction at each point. ``length`` is where the route ends;
    the polyline continues :data:`ROUTE_TAIL` metres further so that look-ahead never runs out.
    """

    points: np.ndarray
    s: np.ndarray
    headings: np.ndarray
    length: float

    def position(self, s: np.ndarray | float) -> np.ndarray:
        """World points at arc lengths ``s`` (clamped to the polyline), shape (..., 2)."""
        s = np.asarray(s, dtype=float)
        return np.stack([np.interp(s, self.s, self.points[:, 0]), np.interp(s, self.s, self.points[:, 1])], -1)

    def heading(self, s: np.ndarray | float) -> np.ndarray:
        """Tangent direction (rad, wrapped to [-π, π)) at arc lengths ``s``."""
        return _wrap(np.interp(np.asarray(s, dtype=float), self.s, self.headings))

    def to_world(self, s: np.ndarray | float, offset: np.ndarray | float) -> np.ndarray:
        """World points ``offset`` metres left of the route at arc lengths ``s``."""
        base = self.position(s)
        h = np.interp(np.asarray(s, dtype=float), self.s, self.headings)
        offset = np.asarray(offset, dtype=float)
        return base + np.stack([-np.sin(h) * offset, np.cos(h) * offset], -1)

    def project(self, points: np.ndarray, s_min: float | None = None, s_max: float | None = None) -> tuple[
            np.ndarray, np.ndarray]:
        """Route coordinates (s, offset to the left) of world ``points`` (M, 2): the nearest point of the
        polyline, optionally searched only between ``s_min`` and ``s_max``."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        lo = 0 if s_min is None else max(int(np.searchsorted(self.s, s_min)) - 1, 0)
        hi = len(self.s) if s_max is None else min(int(np.searchsorted(self.s, s_max)) + 2, len(self.s))
        hi = max(hi, lo + 2)
        a = self.points[lo:hi - 1]
        seg = self.points[lo + 1:hi] - a
        seg_len2 = np.einsum("ij,ij->i", seg, seg)
        rel = pts[:, None, :] - a[None, :, :]
        t = np.clip(np.einsum("mij,ij->mi", rel, seg) / seg_len2, 0.0, 1.0)
        nearest = a[None] + t[..., None] * seg[None]
        dist2 = np.sum((pts[:, None, :] - nearest) ** 2, axis=-1)
        best = np.argmin(dist2, axis=1)
        rows = np.arange(len(pts))
        seg_b, t_b = seg[best], t[rows, best]
        s = self.s[lo:hi - 1][best] + t_b * np.sqrt(seg_len2[best])
        rel_b = rel[rows, best]
        cross = seg_b[:, 0] * rel_b[:, 1] - seg_b[:, 1] * rel_b[:, 0]
        offset = cross / np.sqrt(seg_len2[best])
        return s, offset


class RouteBuilder:
    """Builds a route like a turtle: straight runs and circular arcs from a start pose."""

    def __init__(self, x: float, y: float, heading: float):
        self.points = [(x, y)]
        self.headings = [heading]
        self.s = [0.0]

    @property
    def pose(self) -> tuple[float, float, float]:
        return (*self.points[-1], self.headings[-1])

    def straight(self, length: float) -> RouteBuilder:
        x, y, h = self.pose
        n = max(1, math.ceil(length / ROUTE_STEP))
        for i in range(1, n + 1):
            d = length * i / n
            self._add(x + d * math.cos(h), y + d * math.sin(h), h, length / n)
        return self

    def arc(self, radius: float, sweep: float) -> RouteBuilder:
        """Turn by ``sweep`` rad (positive = left) on a circle of ``radius``."""
        x, y, h = self.pose
        side = 1.0 if sweep > 0 else -1.0
        cx, cy = x - side * radius * math.sin(h), y + side * radius * math.cos(h)
        length = radius * abs(sweep)
        n = max(1, math.ceil(length / ROUTE_STEP))
        for i in range(1, n + 1):
            hh = h + sweep * i / n
            self._add(cx + side * radius * math.sin(hh), cy - side * radius * math.cos(hh), hh, length / n)
        return self

    def _add(self, x: float, y: float, heading: float, ds: float) -> None:
        self.points.append((x, y))
        self.headings.append(heading)
        self.s.append(self.s[-1] + ds)

    def build(self, length: float) -> Route:
        return Route(np.array(self.points), np.array(self.s), np.array(self.headings), float(length))


@dataclass(frozen=True)
class Arm:
    """A straight strip of road: from ``origin`` along the unit ``direction``, between ``start`` and
    ``end`` metres; ``lateral`` is measured to the left of ``direction``. ``marked_from`` is where lane
    markings begin (they stop at the junction box)."""

    name: str
    origin: tuple[float, float]
    direction: tuple[float, float]
    start: float
    end: float
    marked_from: float

    def local(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(along, lateral) of world points."""
        dx, dy = x - self.origin[0], y - self.origin[1]
        ux, uy = self.direction
        return dx * ux + dy * uy, -dx * uy + dy * ux


@dataclass(frozen=True)
class StopLine:
    """A painted stop line on ``arm``: ``along`` from ``along_from`` to ``along_from + 0.4``, across
    lateral ``lat_from``..``lat_to``."""

    arm: int
    along_from: float
    lat_from: float
    lat_to: float


@dataclass(frozen=True)
class Prop:
    """A static scenery object (``building``, ``house``, ``tree``): a box on the ground."""

    kind: str
    x: float
    y: float
    yaw: float
    length: float
    width: float
    height: float


@dataclass(frozen=True)
class FeaturePose:
    """Where a traffic light head or a stop-sign plate stands: centre (x, y), facing ``yaw``, ``height``
    the top above the ground; ``stop_line`` its route position."""

    x: float
    y: float
    yaw: float
    stop_line: float


@dataclass(frozen=True, eq=False)
class RoadGeometry:
    """The ground of a scenario: arms, junction, markings, route, feature poses and scenery."""

    layout: str
    lanes: int
    lane_width: float
    sidewalk_width: float
    corner_radius: float
    arms: tuple[Arm, ...]
    junction: tuple[float, float] | None
    fillets: tuple[tuple[float, float, float, float], ...]
    route: Route
    stop_lines: tuple[StopLine, ...]
    ego_lane_y: float
    junction_span: tuple[float, float] | None = None
    light_pose: FeaturePose | None = None
    stop_sign_pose: FeaturePose | None = None
    props: tuple[Prop, ...] = field(default=())

    @property
    def half_width(self) -> float:
        return self.lanes * self.lane_width

    @property
    def junction_half(self) -> float:
        return self.half_width + self.corner_radius

    def road_offset(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """How far the road would have to grow to contain each point (≤ 0: on the road)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return self._road_offset(x, y, [arm.local(x, y) for arm in self.arms])

    def _road_offset(self, x: np.ndarray, y: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        half = self.half_width
        m = np.full(np.broadcast(x, y).shape, np.inf)
        for arm, (along, lat) in zip(self.arms, frames, strict=True):
            inside = (along >= arm.start) & (along <= arm.end)
            m = np.minimum(m, np.where(inside, np.abs(lat) - half, np.inf))
        if self.junction is not None:
            jx, jy = self.junction
            m = np.minimum(m, np.maximum(np.abs(x - jx), np.abs(y - jy)) - half)
            radius = self.corner_radius
            for cx, cy, sx, sy in self.fillets:
                # The corner square spans from the fillet centre (cx, cy) towards the junction by radius.
                in_square = ((x - cx) * sx >= 0) & ((x - cx) * sx <= radius) & ((y - cy) * sy >= 0) & (
                    (y - cy) * sy <= radius)
                m = np.minimum(m, np.where(in_square, radius - np.hypot(x - cx, y - cy), np.inf))
        return m

    def classify(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground material (:data:`GRASS` … :data:`MARK_YELLOW`) at world points, as uint8."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        frames = [arm.local(x, y) for arm in self.arms]  # each arm's (along, lateral), shared by both passes
        m = self._road_offset(x, y, frames)
        out = np.full(m.shape, GRASS, dtype=np.uint8)
        out[m <= self.sidewalk_width] = SIDEWALK
        out[m <= KERB_WIDTH] = KERB
        road = m <= 0.0
        out[road] = ROAD
        if np.any(road):
            self._paint(frames, road, out)
        return out

    def _paint(self, frames: list[tuple[np.ndarray, np.ndarray]], road: np.ndarray, out: np.ndarray) -> None:
        w = self.lane_width
        for index, (arm, (along, lat)) in enumerate(zip(self.arms, frames, strict=True)):
            on_arm = road & (along >= arm.marked_from) & (along <= arm.end) & (np.abs(lat) <= self.half_width)
            if not np.any(on_arm):
                continue
            centre = on_arm & (np.abs(lat) >= 0.06) & (np.abs(lat) <= 0.20)
            out[centre] = MARK_YELLOW
            dashes = np.mod(along, 9.0) < 3.0
            for k in range(1, self.lanes):
                out[on_arm & dashes & (np.abs(np.abs(lat) - k * w) <= 0.07)] = MARK_WHITE
            for line in self.stop_lines:
                if line.arm == index:
                    band = (along >= line.along_from) & (along <= line.along_from + 0.4)
                    out[road & band & (lat >= line.lat_from) & (lat <= line.lat_to)] = MARK_WHITE


def build_road(scenario: Scenario) -> RoadGeometry:
    """The geometry of ``scenario``'s road, route, features and scenery."""
    road = scenario.road
    half = road.lanes * road.lane_width
    ego_y = -half + (scenario.ego.lane + 0.5) * road.lane_width
    if scenario.layout == "straight":
        geometry = _straight(scenario, half, ego_y)
    else:
        geometry = _junction(scenario, half, ego_y)
    props = scenery_props(geometry, road.scenery)
    return RoadGeometry(**{**geometry, "props": props})


def _straight(scenario: Scenario, half: float, ego_y: float) -> dict:
    road = scenario.road
    length = road.approach_length
    arm = Arm("road", (0.0, 0.0), (1.0, 0.0), -ROAD_BEHIND, length + ROUTE_TAIL, -ROAD_BEHIND)
    route = RouteBuilder(0.0, ego_y, 0.0).straight(length + ROUTE_TAIL).build(length)
    stop_lines, light, sign = [], None, None
    for spec in (scenario.light, scenario.stop_sign):
        if spec is not None:
            stop_lines.append(StopLine(0, spec.stop_line - 0.4, -half, 0.0))
    if scenario.light is not None:
        s = scenario.light.stop_line
        light = FeaturePose(s + 15.0, -half - 1.0, math.pi, s)
    if scenario.stop_sign is not None:
        s = scenario.stop_sign.stop_line
        sign = FeaturePose(s - 0.5, -half - 0.8, math.pi, s)
    return dict(
        layout="straight", lanes=road.lanes, lane_width=road.lane_width, sidewalk_width=road.sidewalk_width,
        corner_radius=road.corner_radius, arms=(arm,), junction=None, fillets=(), route=route,
        stop_lines=tuple(stop_lines), ego_lane_y=ego_y, light_pose=light, stop_sign_pose=sign,
    )


def junction_arms(scenario: Scenario) -> tuple[str, ...]:
    """Which arms the junction has: the ego arrives from the west."""
    if scenario.layout == "four_way":
        return ("west", "east", "north", "south")
    if scenario.road.junction_side == "dead_end":
        return ("west", "north", "south")
    return ("west", "east", "north" if scenario.road.stem_side == "left" else "south")


def _junction(scenario: Scenario, half: float, ego_y: float) -> dict:
    road = scenario.road
    rc = road.corner_radius
    box = half + rc
    jx = road.approach_length + box
    names = junction_arms(scenario)
    exit_end = box + road.exit_length + ROUTE_TAIL
    arms = []
    for name in names:
        end = jx + ROAD_BEHIND if name == "west" else exit_end
        arms.append(Arm(name, (jx, 0.0), _DIRECTIONS[name], half, end, box))
    fillets = []
    for i, name in enumerate(_CYCLE):
        nxt = _CYCLE[(i + 1) % 4]
        if name in names and nxt in names:
            # The corner between two adjacent arms; (sx, sy) points from its centre into the junction.
            dx, dy = np.add(_DIRECTIONS[name], _DIRECTIONS[nxt])
            fillets.append((jx + dx * box, dy * box, -dx, -dy))
    builder = RouteBuilder(0.0, ego_y, 0.0).straight(road.approach_length)
    if scenario.command == "straight":
        turn_length = 2 * box
        builder.straight(turn_length)
    elif scenario.command == "left":
        radius = box - ego_y
        turn_length = radius * math.pi / 2
        builder.arc(radius, math.pi / 2)
    else:
        radius = box + ego_y
        turn_length = radius * math.pi / 2
        builder.arc(radius, -math.pi / 2)
    builder.straight(road.exit_length + ROUTE_TAIL)
    route = builder.build(road.approach_length + turn_length + road.exit_length)
    stop_lines = tuple(StopLine(i, box, 0.0, half) for i in range(len(arms)))
    light = sign = None
    if scenario.light is not None:
        far_x = jx + (half if road.junction_side == "dead_end" else box) + 1.0
        light = FeaturePose(far_x, -half - 1.0, math.pi, road.approach_length)
    if scenario.stop_sign is not None:
        sign = FeaturePose(jx - box - 0.5, -half - 0.8, math.pi, road.approach_length)
    return dict(
        layout=scenario.layout, lanes=road.lanes, lane_width=road.lane_width,
        sidewalk_width=road.sidewalk_width, corner_radius=rc, arms=tuple(arms), junction=(jx, 0.0),
        fillets=tuple(fillets), route=route, stop_lines=stop_lines, ego_lane_y=ego_y,
        junction_span=(road.approach_length, road.approach_length + turn_length),
        light_pose=light, stop_sign_pose=sign,
    )


# Scenery: deterministic patterns (no randomness), so that every seed sees the same street.
_URBAN_LENGTHS = (18.0, 26.0, 14.0, 30.0, 22.0)
_URBAN_HEIGHTS = (14.0, 22.0, 9.0, 30.0, 17.0, 12.0)
_URBAN_GAP = 3.0
_HOUSE_SPACING = 28.0


def scenery_props(geometry: dict, scenery: str) -> tuple[Prop, ...]:
    """Buildings (urban) or houses and trees (suburban) behind the sidewalks of every arm."""
    if scenery == "plain":
        return ()
    half, sidewalk = geometry["lanes"] * geometry["lane_width"], geometry["sidewalk_width"]
    box = half + geometry["corner_radius"] if geometry["junction"] is not None else None
    props: list[Prop] = []
    for arm in geometry["arms"]:
        first = (box + sidewalk + 2.0) if box is not None else arm.start
        for side in (1.0, -1.0):
            if scenery == "urban":
                props += _urban_row(arm, side, first, half + sidewalk)
            else:
                props += _suburban_row(arm, side, first, half + sidewalk)
    return tuple(props)


def _place(arm: Arm, along: float, lateral: float) -> tuple[float, float, float]:
    ux, uy = arm.direction
    return (arm.origin[0] + along * ux - lateral * uy, arm.origin[1] + along * uy + lateral * ux,
            math.atan2(uy, ux))


def _urban_row(arm: Arm, side: float, first: float, edge: float) -> list[Prop]:
    props, along, i = [], first, 0 if side > 0 else 2
    depth = 12.0
    while along < arm.end:
        length = min(_URBAN_LENGTHS[i % len(_URBAN_LENGTHS)], arm.end - along)
        if length > 4.0:
            x, y, yaw = _place(arm, along + length / 2, side * (edge + 1.0 + depth / 2))
            props.append(Prop("building", x, y, yaw, length, depth, _URBAN_HEIGHTS[i % len(_URBAN_HEIGHTS)]))
        along += length + _URBAN_GAP
        i += 1
    return props


def _suburban_row(arm: Arm, side: float, first: float, edge: float) -> list[Prop]:
    props, along = [], first + (0.0 if side > 0 else _HOUSE_SPACING / 2)
    while along + 10.0 < arm.end:
        x, y, yaw = _place(arm, along + 5.0, side * (edge + 6.0 + 4.0))
        props.append(Prop("house", x, y, yaw, 10.0, 8.0, 6.0))
        tx, ty, _ = _place(arm, along + 15.0, side * (edge + 2.0))
        props.append(Prop("tree", tx, ty, yaw, 2.0, 2.0, 6.0))
        along += _HOUSE_SPACING
    return props
