"""A user's own SUMO network (``net_file``) with a route for the ego (``route=edge1,edge2,…``).

The network replaces the scenario's road table: the ego drives along the route's edges in its lane
(``ego.lane``, counted from the right among the lanes cars may use), starting with its centre
``depart_pos`` metres along the first edge, and the episode's route ends 5 m before the end of the last
edge. Everything else in the scenario keeps its meaning along that route: actors at ``s`` / ``offset``, the
traffic light and stop sign at their ``stop_line``. A scenario's traffic light must be one of the network's
own signals on the route (its stop line within :data:`STOP_LINE_MATCH` m of the scenario's); it is frozen
like the suite's.

The camera and the ground truth need the ground's materials: :class:`NetGeometry` rasterises the
network's junctions, lanes, sidewalks, walking areas and crossings (zebra stripes) once, and answers
:meth:`NetGeometry.classify` by lookup. Background traffic runs between the network's fringe edges.
"""

from __future__ import annotations

import difflib
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from vladrivebench import ConfigError, Scenario, ScenarioError
from vladrivebench.world import GRASS, MARK_WHITE, ROAD, ROUTE_STEP, SIDEWALK, FeaturePose, Route

from .traffic import Trip

ROUTE_END_MARGIN = 5.0
"""The episode's route ends this far (m) before the end of the last route edge."""
STOP_LINE_MATCH = 5.0
"""How close (m along the route) a network signal's stop line must be to the scenario's light's stop line."""
RASTER_RESOLUTION = 0.2
"""Size (m) of a ground raster cell; coarser for networks whose raster would exceed :data:`RASTER_CELLS`."""
RASTER_CELLS = 16_000_000
RASTER_MARGIN = 20.0
MAX_FRINGE = 8
"""At most this many fringe edges serve as origins (and as destinations) of background traffic."""
ZEBRA_STRIPE = 0.5


@dataclass(frozen=True, eq=False)
class NetGeometry:
    """The ground of a user network, duck-typed like :class:`~vladrivebench.world._roads.RoadGeometry` for
    the camera and the ground truth: ``route``, ``lane_width``, feature poses and :meth:`classify`."""

    route: Route
    lane_width: float
    sidewalk_width: float
    grid: np.ndarray = field(repr=False)
    origin: tuple[float, float]
    resolution: float
    light_pose: FeaturePose | None = None
    stop_sign_pose: FeaturePose | None = None
    props: tuple = ()
    layout: str = "user_net"

    def classify(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Ground material at world points (grass outside the network's raster)."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        col = np.floor((x - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((y - self.origin[1]) / self.resolution).astype(np.int64)
        rows, cols = self.grid.shape
        inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
        out = np.full(np.broadcast(x, y).shape, GRASS, dtype=np.uint8)
        out[inside] = self.grid[row[inside], col[inside]]
        return out

    def road_offset(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Like the suite geometry's: ≤ 0 on the road, within ``(0, sidewalk_width]`` on a sidewalk."""
        material = self.classify(x, y)
        on_road = (material == ROAD) | (material == MARK_WHITE)
        return np.where(on_road, -1.0, np.where(material == SIDEWALK, self.sidewalk_width / 2, np.inf))


@dataclass(frozen=True)
class UserWorld:
    """What the simulator needs from a user network for one scenario."""

    road: NetGeometry
    net: Path
    route_edges: tuple[str, ...]
    ego_lane: int
    tls: str | None
    approach: str | None
    drives: list[Trip]
    walks: list[Trip]


class UserNetwork:
    """A user's network file and the ego's route through it (validated when the simulator is built)."""

    def __init__(self, path: Path, edges: tuple[str, ...], depart_pos: float):
        self.path, self.edges, self.depart_pos = path, edges, depart_pos
        self._net: Any = None

    @classmethod
    def from_options(cls, net_file: str, route: str, depart_pos: float) -> UserNetwork:
        path = Path(net_file).expanduser()
        if not path.is_file():
            raise ConfigError(f"simulator 'sumo': option net_file: no such file {path} "
                              "(expected a SUMO network file, *.net.xml)")
        edges = tuple(e.strip() for e in route.split(",") if e.strip())
        if not edges:
            raise ConfigError("simulator 'sumo': option route must list the ego's edges, e.g. route=A0A1,A1B1")
        network = cls(path, edges, depart_pos)
        network.check_route()
        return network

    @property
    def net(self) -> Any:
        if self._net is None:
            import sumolib

            try:
                with warnings.catch_warnings():  # sumolib's note that the optional rtree index is missing
                    warnings.simplefilter("ignore")
                    self._net = sumolib.net.readNet(str(self.path), withInternal=True)
            except Exception as exc:
                text = " ".join(str(exc).split()) or type(exc).__name__
                raise ConfigError(f"simulator 'sumo': option net_file: {self.path} is not a readable SUMO "
                                  f"network ({text})") from None
        return self._net

    def check_route(self) -> None:
        """One-line errors for an unknown edge, two edges that do not connect, or a depart beyond the edge."""
        net = self.net
        known = [e.getID() for e in net.getEdges() if e.getFunction() == ""]
        for edge in self.edges:
            if not net.hasEdge(edge) or net.getEdge(edge).getFunction() != "":
                close = difflib.get_close_matches(edge, known, n=3)
                hint = f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""
                raise ConfigError(f"simulator 'sumo': option route: edge {edge!r} is not in {self.path}{hint}")
        for a, b in zip(self.edges[:-1], self.edges[1:], strict=True):
            if net.getEdge(b) not in net.getEdge(a).getOutgoing():
                raise ConfigError(f"simulator 'sumo': option route: edge {b!r} does not follow {a!r} in "
                                  f"{self.path} (no connection between them)")
        first = net.getEdge(self.edges[0])
        if self.depart_pos >= first.getLength():
            raise ConfigError(f"simulator 'sumo': option depart_pos must be less than the length of edge "
                              f"{first.getID()!r} ({first.getLength():.1f} m), got {self.depart_pos:g}")

    def world(self, scenario: Scenario) -> UserWorld:
        """The scenario's world on this network (see the module docstring)."""
        net = self.net
        lanes = self._ego_lanes(scenario)
        points = _route_polyline(net, lanes, self.depart_pos)
        route = _route(points, ROUTE_END_MARGIN)
        lane_width = lanes[0].getWidth()
        tls, approach = self._signal(scenario, route, lanes)
        light = sign = None
        if scenario.light is not None:
            light = _feature_pose(route, scenario.light.stop_line + 1.0, -(lane_width / 2 + 1.5))
        if scenario.stop_sign is not None:
            sign = _feature_pose(route, scenario.stop_sign.stop_line - 0.5, -(lane_width / 2 + 1.3))
        grid, origin, resolution, sidewalk = rasterise(net)
        road = NetGeometry(route, lane_width, sidewalk, grid, origin, resolution, light, sign)
        drives, walks = fringe_trips(net)
        return UserWorld(road, self.path, self.edges, lanes[0].getIndex(), tls, approach, drives, walks)

    def _ego_lanes(self, scenario: Scenario) -> list[Any]:
        lanes = []
        for edge_id in self.edges:
            edge = self.net.getEdge(edge_id)
            usable = [lane for lane in edge.getLanes() if lane.allows("passenger")]
            if not usable:
                raise ScenarioError(f"simulator 'sumo': route edge {edge_id!r} of {self.path} has no lane cars "
                                    "may use")
            lanes.append(usable[min(scenario.ego.lane, len(usable) - 1)])
        if scenario.ego.lane >= len([la for la in self.net.getEdge(self.edges[0]).getLanes()
                                      if la.allows("passenger")]):
            raise ScenarioError(f"scenario {scenario.source or scenario.id}: ego.lane = {scenario.ego.lane} but "
                                f"route edge {self.edges[0]!r} of {self.path} has fewer car lanes")
        return lanes

    def _signal(self, scenario: Scenario, route: Route, lanes: list[Any]) -> tuple[str | None, str | None]:
        """The network signal that plays the scenario's traffic light, and the ego's edge arriving there."""
        if scenario.light is None:
            return None, None
        found = []
        for lane in lanes:
            edge = lane.getEdge()
            node = edge.getToNode()
            if node.getType() != "traffic_light":
                continue
            end = lane.getShape()[-1]
            s, _ = route.project(np.array([end]))
            found.append((float(s[0]), node.getID(), edge.getID()))
        for s, node_id, edge_id in found:
            if abs(s - scenario.light.stop_line) <= STOP_LINE_MATCH:
                return node_id, edge_id
        where = scenario.source or scenario.id
        near = ", ".join(f"{node} at s = {s:.1f}" for s, node, _ in found) or "none"
        raise ScenarioError(f"scenario {where}: its traffic light (stop_line = {scenario.light.stop_line:g} m) "
                            f"matches no signal on the route through {self.path} (signals on the route: {near})")


def _route_polyline(net: Any, lanes: list[Any], depart_pos: float) -> np.ndarray:
    """The ego lane's centre line along the route (via the junctions' internal lanes), from ``depart_pos``."""
    points: list[tuple[float, float]] = []
    for i, lane in enumerate(lanes):
        points += [tuple(p[:2]) for p in lane.getShape()]
        if i + 1 < len(lanes):
            via = _via(net, lane, lanes[i + 1])
            points += [tuple(p[:2]) for p in via]
    pts = np.array(_dedupe(points), dtype=float)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    keep = arc > depart_pos
    start = np.array([np.interp(depart_pos, arc, pts[:, 0]), np.interp(depart_pos, arc, pts[:, 1])])
    return np.vstack([start, pts[keep]])


def _via(net: Any, lane: Any, next_lane: Any) -> list[tuple[float, ...]]:
    """The internal lane shape from ``lane`` into ``next_lane``'s edge (any lane of it if none from ``lane``)."""
    target = next_lane.getEdge()
    candidates = [c for c in lane.getOutgoing() if c.getTo() == target]
    if not candidates:
        candidates = [c for c in lane.getEdge().getConnections(target)]
    best = next((c for c in candidates if c.getToLane() == next_lane), candidates[0] if candidates else None)
    if best is None or not best.getViaLaneID():
        return []
    try:
        return list(net.getLane(best.getViaLaneID()).getShape())
    except (KeyError, AttributeError):
        return []


def _dedupe(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for p in points:
        if not out or math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > 1e-6:
            out.append(p)
    return out


def _route(points: np.ndarray, end_margin: float) -> Route:
    """A :class:`Route` resampled every :data:`ROUTE_STEP` m, ending ``end_margin`` before the polyline."""
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    total = float(arc[-1])
    if total <= end_margin + 1.0:
        raise ConfigError(f"simulator 'sumo': the route is only {total:.1f} m long from depart_pos; "
                          "give more edges or a smaller depart_pos")
    s = np.append(np.arange(0.0, total, ROUTE_STEP), total)
    xs, ys = np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])
    dx, dy = np.gradient(xs), np.gradient(ys)
    headings = np.unwrap(np.arctan2(dy, dx))
    return Route(np.stack([xs, ys], axis=1), s, headings, total - end_margin)


def _feature_pose(route: Route, s: float, offset: float) -> FeaturePose:
    x, y = (float(v) for v in route.to_world(s, offset))
    return FeaturePose(x, y, float(route.heading(s)) + math.pi, s)


def fringe_trips(net: Any) -> tuple[list[Trip], list[Trip]]:
    """Background trips between the network's fringe edges (where traffic enters and leaves it)."""
    normal = [e for e in net.getEdges() if e.getFunction() == ""]
    sources = [e for e in normal if e.allows("passenger") and not _incoming(e, "passenger")]
    sinks = [e for e in normal if e.allows("passenger") and not _outgoing(e, "passenger")]
    if not sources or not sinks:  # a network without dead ends (a ring, a grid of loops): any edges
        sources = sinks = [e for e in normal if e.allows("passenger")]
    sources, sinks = _spread(sources), _spread(sinks)
    drives = [Trip(f"{a.getID()}-{b.getID()}", a.getID(), b.getID()) for a in sources for b in sinks
              if a.getFromNode() != b.getToNode() and a != b]
    walkable = _spread([e for e in normal if e.allows("pedestrian")])
    walks = [Trip(f"{a.getID()}-{b.getID()}", a.getID(), b.getID()) for a in walkable for b in walkable if a != b]
    return drives, walks


def _incoming(edge: Any, vclass: str) -> bool:
    return any(e.allows(vclass) for e in edge.getIncoming() if e.getFunction() == "")


def _outgoing(edge: Any, vclass: str) -> bool:
    return any(e.allows(vclass) for e in edge.getOutgoing() if e.getFunction() == "")


def _spread(edges: list[Any]) -> list[Any]:
    """At most :data:`MAX_FRINGE` edges, evenly spaced in id order (deterministic)."""
    edges = sorted(edges, key=lambda e: e.getID())
    if len(edges) <= MAX_FRINGE:
        return edges
    step = len(edges) / MAX_FRINGE
    return [edges[int(i * step)] for i in range(MAX_FRINGE)]


# -- rasterising the ground ------------------------------------------------------------------------------
def rasterise(net: Any) -> tuple[np.ndarray, tuple[float, float], float, float]:
    """The network's ground as a grid of materials: (grid, origin, resolution, widest sidewalk)."""
    xmin, ymin, xmax, ymax = net.getBoundary()
    xmin, ymin, xmax, ymax = xmin - RASTER_MARGIN, ymin - RASTER_MARGIN, xmax + RASTER_MARGIN, ymax + RASTER_MARGIN
    area = (xmax - xmin) * (ymax - ymin)
    resolution = max(RASTER_RESOLUTION, math.sqrt(area / RASTER_CELLS))
    shape = (int(math.ceil((ymax - ymin) / resolution)), int(math.ceil((xmax - xmin) / resolution)))
    grid = np.full(shape, GRASS, dtype=np.uint8)
    raster = _Raster(grid, (xmin, ymin), resolution)
    for node in net.getNodes():
        node_shape = node.getShape()
        if len(node_shape) >= 3:
            raster.fill([p[:2] for p in node_shape], ROAD)
    sidewalk = 0.0
    edges = net.getEdges()
    for edge in edges:
        if edge.getFunction() == "walkingarea":
            for lane in edge.getLanes():
                raster.fill([p[:2] for p in lane.getShape()], SIDEWALK)
    for edge in edges:
        function = edge.getFunction()
        for lane in edge.getLanes():
            pedestrian_only = lane.allows("pedestrian") and not lane.allows("passenger")
            if function == "" and pedestrian_only:
                sidewalk = max(sidewalk, lane.getWidth())
                raster.strip(lane.getShape(), lane.getWidth(), SIDEWALK)
            elif function == "":
                raster.strip(lane.getShape(), lane.getWidth(), ROAD)
            elif function == "crossing":
                raster.zebra(lane.getShape(), lane.getWidth())
    return grid, (xmin, ymin), resolution, sidewalk


class _Raster:
    """Fills polygons into a material grid (even-odd scanline fill, vectorised per polygon)."""

    def __init__(self, grid: np.ndarray, origin: tuple[float, float], resolution: float):
        self.grid, self.origin, self.res = grid, origin, resolution

    def strip(self, shape: list, width: float, value: int) -> None:
        """A lane: one rectangle per segment of its centre line."""
        pts = np.array([p[:2] for p in shape], dtype=float)
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            quad = _segment_quad(a, b, width)
            if quad is not None:
                self.fill(quad, value)

    def zebra(self, shape: list, width: float) -> None:
        """A crossing: white stripes across its axis on the road."""
        pts = np.array([p[:2] for p in shape], dtype=float)
        if len(pts) < 2:
            return
        a, b = pts[0], pts[-1]
        quad = _segment_quad(a, b, width)
        if quad is None:
            return
        axis = (b - a) / np.linalg.norm(b - a)
        self.fill(quad, MARK_WHITE, lambda x, y: ((((x - a[0]) * axis[0] + (y - a[1]) * axis[1])
                                                   // ZEBRA_STRIPE) % 2) == 0)

    def fill(self, polygon: list | np.ndarray, value: int, keep: Any = None) -> None:
        """Set the cells whose centres lie inside ``polygon`` (and, if given, where ``keep(x, y)``)."""
        poly = np.asarray(polygon, dtype=float)
        if len(poly) < 3:
            return
        x0, y0 = self.origin
        rows, cols = self.grid.shape
        r0 = max(int(math.ceil((poly[:, 1].min() - y0) / self.res - 0.5)), 0)
        r1 = min(int(math.floor((poly[:, 1].max() - y0) / self.res - 0.5)), rows - 1)
        if r1 < r0:
            return
        yc = y0 + (np.arange(r0, r1 + 1) + 0.5) * self.res
        a, b = poly, np.roll(poly, -1, axis=0)
        ya, yb = a[:, 1:2], b[:, 1:2]
        crosses = ((ya <= yc) & (yc < yb)) | ((yb <= yc) & (yc < ya))
        edge, row = np.nonzero(crosses)
        if len(edge) == 0:
            return
        t = (yc[row] - poly[edge, 1]) / (b[edge, 1] - poly[edge, 1])
        x = poly[edge, 0] + t * (b[edge, 0] - poly[edge, 0])
        order = np.lexsort((x, row))
        pairs_x, pairs_row = x[order].reshape(-1, 2), row[order][::2]
        c0 = np.maximum(np.ceil((pairs_x[:, 0] - x0) / self.res - 0.5).astype(np.int64), 0)
        c1 = np.minimum(np.floor((pairs_x[:, 1] - x0) / self.res - 0.5).astype(np.int64), cols - 1)
        good = c1 >= c0
        if not np.any(good):
            return
        c0, c1, pairs_row = c0[good], c1[good], pairs_row[good]
        lo, hi = int(c0.min()), int(c1.max())
        coverage = np.zeros((r1 - r0 + 1, hi - lo + 2), dtype=np.int32)
        np.add.at(coverage, (pairs_row, c0 - lo), 1)
        np.add.at(coverage, (pairs_row, c1 - lo + 1), -1)
        inside = np.cumsum(coverage, axis=1)[:, :-1] > 0
        if keep is not None:
            cx = x0 + (np.arange(lo, hi + 1) + 0.5) * self.res
            inside &= keep(cx[None, :], yc[:, None])
        self.grid[r0:r1 + 1, lo:hi + 1][inside] = value


def _segment_quad(a: np.ndarray, b: np.ndarray, width: float) -> np.ndarray | None:
    d = b - a
    length = float(np.hypot(*d))
    if length < 1e-9:
        return None
    n = np.array([-d[1], d[0]]) / length * (width / 2)
    return np.array([a - n, b - n, b + n, a + n])
