"""SUMO road networks built from a scenario's shared geometry with SUMO's own ``netconvert``.

The shared geometry (:mod:`vladrivebench.world._roads`) is the reference the camera draws and the ground
truth measures; the network reproduces it so that SUMO's lanes lie exactly on the drawn ones:

* every road is a pair of one-way edges along its centre line (``spreadType="right"``), ``lanes`` lanes of
  ``lane_width`` each way and a sidewalk lane of ``sidewalk_width`` outside them (SUMO lane 0);
* a junction is one node with a custom shape: the square of half-size ``lanes·lane_width + corner_radius``
  cut where each arm begins, with quarter-circle corners, so every arm's lanes end exactly at the stop line
  (route position ``approach_length``); it has a pedestrian crossing on every arm;
* a traffic light makes the node a SUMO ``traffic_light`` junction (frozen by the simulator), a stop sign an
  ``allway_stop`` junction; on a straight road they get a short node whose shape starts at the stop line;
* a pedestrian that crosses the road gets a SUMO crossing at its crossing line: a mid-block node with a
  zebra crossing (pedestrians have priority) unless it crosses inside the junction, whose crossings serve.

Building is pure Python plus one ``netconvert`` run; the result is cached on disk by the hash of the
plain-XML input and SUMO's version, so each distinct road is converted once per machine.
"""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

from vladrivebench import Scenario, VdbError
from vladrivebench.world import ROAD_BEHIND, RoadGeometry, junction_arms

CROSSING_WIDTH = 2.0
"""Width (m) of a SUMO crossing, and the length along the road of its mid-block node."""
FEATURE_SPAN = 2.0
"""Length (m) along a straight road of the node that carries a traffic light or stop sign; its shape starts
at the stop line, so SUMO's stop line is the scenario's."""
SPEED_LIMIT = 13.89
"""Speed limit of every lane (m/s, 50 km/h): the background traffic's desired speed."""
END_MARGIN = 3.0
"""A mid-block node must stay this far (m) from the junction's shape and from the network's ends."""
NETCONVERT_OPTIONS = (
    "--offset.disable-normalization", "true",  # net coordinates are world coordinates
    "--no-turnarounds", "true",
    "--walkingareas", "true",
    "--tls.default-type", "static",
    "--junctions.corner-detail", "6",
    "--geometry.remove", "false",
    "--no-warnings", "true",
)

_DIRECTIONS = {"east": (1.0, 0.0), "north": (0.0, 1.0), "west": (-1.0, 0.0), "south": (0.0, -1.0)}
_CCW = ("east", "north", "west", "south")
_EXIT_ARM = {"straight": "east", "left": "north", "right": "south"}


@dataclass(frozen=True)
class Node:
    """A SUMO node; ``shape`` (world points) overrides netconvert's computed junction shape."""

    id: str
    x: float
    y: float
    type: str = "priority"
    shape: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class Edge:
    """A one-way SUMO edge from node ``start`` to node ``end``."""

    id: str
    start: str
    end: str


@dataclass(frozen=True)
class Crossing:
    """A pedestrian crossing at ``node`` over the (two opposite) ``edges``."""

    node: str
    edges: tuple[str, str]
    priority: bool


@dataclass(frozen=True)
class RoadEnd:
    """Where the network ends: the edge that enters the network there and the edge that leaves it."""

    name: str
    enter: str
    leave: str


@dataclass(frozen=True)
class NetworkPlan:
    """Everything ``netconvert`` needs to build a scenario's network, and how the simulator uses it.

    ``route`` is the ego's edges in order; ``ego_lane`` its SUMO lane index (the sidewalk is lane 0);
    ``tls``/``stop_node`` the nodes carrying the scenario's light / stop sign and ``feature_approach`` the
    ego's edge arriving there; ``crossing_nodes`` maps a crossing actor's id to its crossing's node.
    """

    nodes: tuple[Node, ...]
    edges: tuple[Edge, ...]
    crossings: tuple[Crossing, ...]
    lanes: int
    lane_width: float
    sidewalk_width: float
    route: tuple[str, ...]
    ego_lane: int
    ends: tuple[RoadEnd, ...]
    tls: str | None = None
    stop_node: str | None = None
    feature_approach: str | None = None
    crossing_nodes: dict[str, str] = field(default_factory=dict)

    @property
    def has_sidewalks(self) -> bool:
        return self.sidewalk_width > 0

    def plain_xml(self) -> dict[str, str]:
        """The node, edge and connection files (SUMO plain XML), by suffix."""
        nodes = ["<nodes>"]
        for n in self.nodes:
            shape = f" shape={quoteattr(_shape(n.shape))}" if n.shape else ""
            nodes.append(f'    <node id={quoteattr(n.id)} x="{n.x:.3f}" y="{n.y:.3f}" type="{n.type}"{shape}/>')
        nodes.append("</nodes>")
        sidewalk = f' sidewalkWidth="{self.sidewalk_width:.3f}"' if self.has_sidewalks else ""
        edges = ["<edges>"]
        for e in self.edges:
            edges.append(
                f'    <edge id={quoteattr(e.id)} from={quoteattr(e.start)} to={quoteattr(e.end)} '
                f'numLanes="{self.lanes}" width="{self.lane_width:.3f}" speed="{SPEED_LIMIT}" '
                f'spreadType="right"{sidewalk}/>'
            )
        edges.append("</edges>")
        connections = ["<connections>"]
        for c in self.crossings:
            connections.append(
                f'    <crossing node={quoteattr(c.node)} edges={quoteattr(" ".join(c.edges))} '
                f'priority="{str(c.priority).lower()}" width="{CROSSING_WIDTH:.3f}"/>'
            )
        connections.append("</connections>")
        return {"nod.xml": "\n".join(nodes) + "\n", "edg.xml": "\n".join(edges) + "\n",
                "con.xml": "\n".join(connections) + "\n"}

    def key(self, sumo_version: str) -> str:
        """A hash of the network's input and the SUMO version: the cache key of the built network."""
        digest = hashlib.sha256(sumo_version.encode())
        digest.update(repr(NETCONVERT_OPTIONS).encode())
        for suffix, text in sorted(self.plain_xml().items()):
            digest.update(suffix.encode() + b"\0" + text.encode())
        return digest.hexdigest()[:24]


def _shape(points: tuple[tuple[float, float], ...]) -> str:
    return " ".join(f"{x:.3f},{y:.3f}" for x, y in points)


# -- planning ------------------------------------------------------------------------------------------
def plan_network(scenario: Scenario, road: RoadGeometry) -> NetworkPlan:
    """The SUMO network of ``scenario`` whose geometry is ``road`` (see the module docstring)."""
    if scenario.layout == "straight":
        return _plan_straight(scenario, road)
    return _plan_junction(scenario, road)


@dataclass
class _Split:
    """A mid-road node over ``[start, end]`` along its road."""

    start: float
    end: float
    type: str = "priority"
    crossing: bool = False
    actors: list[str] = field(default_factory=list)
    feature: bool = False


_TYPE_RANK = {"priority": 0, "allway_stop": 1, "traffic_light": 2}


def _merge(splits: list[_Split]) -> list[_Split]:
    """Overlapping mid-road nodes become one (a light and a crossing at the same place share a node). A
    light's or stop sign's node keeps starting at its stop line: a crossing merged into it is served by
    that node's crossing, up to half a crossing width from its own line."""
    merged: list[_Split] = []
    for split in sorted(splits, key=lambda s: s.start):
        last = merged[-1] if merged else None
        if last is not None and split.start <= last.end + 0.5:
            last.end = max(last.end, split.end)
            if split.feature and not last.feature:
                last.start = split.start
            elif not last.feature:
                last.start = min(last.start, split.start)
            last.type = max(last.type, split.type, key=_TYPE_RANK.__getitem__)
            last.crossing = last.crossing or split.crossing
            last.feature = last.feature or split.feature
            last.actors.extend(split.actors)
        else:
            merged.append(split)
    return merged


def _crossing_actors(scenario: Scenario) -> list:
    return [a for a in scenario.actors if a.motion == "cross"]


def _plan_straight(scenario: Scenario, road: RoadGeometry) -> NetworkPlan:
    spec = scenario.road
    start, end = -ROAD_BEHIND, spec.approach_length + _tail(road)
    splits = []
    if scenario.light is not None:
        line = scenario.light.stop_line
        splits.append(_Split(line, line + FEATURE_SPAN, "traffic_light", feature=True))
    if scenario.stop_sign is not None:
        line = scenario.stop_sign.stop_line
        splits.append(_Split(line, line + FEATURE_SPAN, "allway_stop", feature=True))
    for actor in _crossing_actors(scenario):
        half = CROSSING_WIDTH / 2
        splits.append(_Split(actor.s - half, actor.s + half, crossing=True, actors=[actor.id]))
    splits = [s for s in _merge(splits) if s.start > start + END_MARGIN and s.end < end - END_MARGIN]
    outer = road.half_width + road.sidewalk_width
    nodes = [Node("west_end", start, 0.0)]
    for i, split in enumerate(splits):
        shape = ((split.start, -outer), (split.end, -outer), (split.end, outer), (split.start, outer))
        nodes.append(Node(f"mid{i}", (split.start + split.end) / 2, 0.0, split.type, shape))
    nodes.append(Node("east_end", end, 0.0))
    edges, crossings, crossing_nodes = [], [], {}
    for k in range(len(nodes) - 1):
        edges += [Edge(f"east.{k}", nodes[k].id, nodes[k + 1].id), Edge(f"west.{k}", nodes[k + 1].id, nodes[k].id)]
    tls = stop_node = approach = None
    for i, split in enumerate(splits):
        node = nodes[i + 1].id
        if split.crossing or split.type == "traffic_light":
            crossings.append(Crossing(node, (f"east.{i}", f"west.{i}"), priority=split.type == "priority"))
        for actor_id in split.actors:
            crossing_nodes[actor_id] = node
        if split.type == "traffic_light":
            tls, approach = node, f"east.{i}"
        elif split.type == "allway_stop":
            stop_node, approach = node, f"east.{i}"
    last = len(nodes) - 2
    return NetworkPlan(
        nodes=tuple(nodes), edges=tuple(edges), crossings=tuple(crossings), lanes=spec.lanes,
        lane_width=spec.lane_width, sidewalk_width=spec.sidewalk_width,
        route=tuple(f"east.{k}" for k in range(len(nodes) - 1)),
        ego_lane=scenario.ego.lane + (1 if spec.sidewalk_width > 0 else 0),
        ends=(RoadEnd("west", "east.0", "west.0"), RoadEnd("east", f"west.{last}", f"east.{last}")),
        tls=tls, stop_node=stop_node, feature_approach=approach, crossing_nodes=crossing_nodes,
    )


def _tail(road: RoadGeometry) -> float:
    """How far the drawn road continues past the route's end (the geometry's own margin)."""
    arm = road.arms[0]
    return arm.end - road.route.length


def _plan_junction(scenario: Scenario, road: RoadGeometry) -> NetworkPlan:
    spec = scenario.road
    jx, jy = road.junction
    half, box = road.half_width, road.junction_half
    outer = half + road.sidewalk_width
    names = junction_arms(scenario)
    arm_by_name = {arm.name: arm for arm in road.arms}
    node_type = "traffic_light" if scenario.light else "allway_stop" if scenario.stop_sign else "priority"
    nodes = [Node("J", jx, jy, node_type, junction_shape(road, names))]
    edges, crossings, crossing_nodes, ends = [], [], {}, []
    splits_by_arm = _junction_crossing_splits(scenario, road)
    segments: dict[str, int] = {}
    for name in _CCW:
        if name not in names:
            continue
        arm = arm_by_name[name]
        ux, uy = arm.direction
        splits = [s for s in _merge(splits_by_arm.get(name, []))
                  if s.start > box + END_MARGIN and s.end < arm.end - END_MARGIN]
        chain = ["J"]
        for i, split in enumerate(splits):
            a0, a1 = split.start, split.end
            shape = tuple((jx + a * ux - lat * uy, jy + a * uy + lat * ux)
                          for a, lat in ((a0, -outer), (a1, -outer), (a1, outer), (a0, outer)))
            mid = (a0 + a1) / 2
            node_id = f"{name}_mid{i}"
            nodes.append(Node(node_id, jx + mid * ux, jy + mid * uy, "priority", shape))
            chain.append(node_id)
            for actor_id in split.actors:
                crossing_nodes[actor_id] = node_id
        end_id = f"{name}_end"
        nodes.append(Node(end_id, jx + arm.end * ux, jy + arm.end * uy))
        chain.append(end_id)
        for k in range(len(chain) - 1):
            edges += [Edge(f"{name}.in.{k}", chain[k + 1], chain[k]), Edge(f"{name}.out.{k}", chain[k], chain[k + 1])]
            if k > 0:
                crossings.append(Crossing(chain[k], (f"{name}.in.{k}", f"{name}.out.{k}"), priority=True))
        crossings.append(Crossing("J", (f"{name}.in.0", f"{name}.out.0"), priority=False))
        segments[name] = len(chain) - 1
        last = segments[name] - 1
        ends.append(RoadEnd(name, f"{name}.in.{last}", f"{name}.out.{last}"))
    for actor in _crossing_actors(scenario):
        crossing_nodes.setdefault(actor.id, _junction_crossing_node(road, actor))
    exit_arm = _EXIT_ARM[scenario.command]
    route = tuple(f"west.in.{k}" for k in reversed(range(segments["west"])))
    route += tuple(f"{exit_arm}.out.{k}" for k in range(segments[exit_arm]))
    return NetworkPlan(
        nodes=tuple(nodes), edges=tuple(edges), crossings=tuple(crossings), lanes=spec.lanes,
        lane_width=spec.lane_width, sidewalk_width=spec.sidewalk_width, route=route,
        ego_lane=scenario.ego.lane + (1 if spec.sidewalk_width > 0 else 0), ends=tuple(ends),
        tls="J" if scenario.light else None, stop_node="J" if scenario.stop_sign else None,
        feature_approach="west.in.0" if (scenario.light or scenario.stop_sign) else None,
        crossing_nodes={k: v for k, v in crossing_nodes.items() if v},
    )


def _junction_crossing_splits(scenario: Scenario, road: RoadGeometry) -> dict[str, list[_Split]]:
    """Mid-block crossings of crossing pedestrians, by arm (along-coordinates from the junction)."""
    out: dict[str, list[_Split]] = {}
    for actor in _crossing_actors(scenario):
        found = _arm_position(road, actor.s)
        if found is None:
            continue
        name, along = found
        half = CROSSING_WIDTH / 2
        out.setdefault(name, []).append(_Split(along - half, along + half, crossing=True, actors=[actor.id]))
    return out


def _arm_position(road: RoadGeometry, s: float) -> tuple[str, float] | None:
    """The arm and the distance from the junction centre of route position ``s``, if it lies on an arm
    clear of the junction."""
    x, y = (float(v) for v in road.route.position(s))
    for arm in road.arms:
        along, lateral = arm.local(x, y)
        if road.junction_half < along <= arm.end and abs(lateral) <= road.half_width:
            return arm.name, float(along)
    return None


def _junction_crossing_node(road: RoadGeometry, actor) -> str:
    """``"J"`` when a crossing pedestrian crosses inside (or at the edge of) the junction, else ``""``."""
    x, y = (float(v) for v in road.route.position(actor.s))
    jx, jy = road.junction
    reach = road.junction_half + CROSSING_WIDTH
    return "J" if max(abs(x - jx), abs(y - jy)) <= reach else ""


def junction_shape(road: RoadGeometry, names: tuple[str, ...], arc_points: int = 6
                   ) -> tuple[tuple[float, float], ...]:
    """The junction's outline, counter-clockwise: each arm cut at ``junction_half`` across its lanes,
    quarter circles of ``corner_radius`` between adjacent arms, the kerb line where an arm is missing."""
    jx, jy = road.junction
    half, box, radius = road.half_width, road.junction_half, road.corner_radius
    sides = []
    for name in _CCW:
        d = _DIRECTIONS[name]
        n = (-d[1], d[0])
        reach = box if name in names else half
        right = (d[0] * reach - n[0] * half, d[1] * reach - n[1] * half)
        left = (d[0] * reach + n[0] * half, d[1] * reach + n[1] * half)
        sides.append((name, right, left))
    points: list[tuple[float, float]] = []
    for i, (name, right, left) in enumerate(sides):
        points += [right, left]
        nxt = sides[(i + 1) % 4][0]
        if name in names and nxt in names and radius > 0:
            d1, d2 = _DIRECTIONS[name], _DIRECTIONS[nxt]
            centre = (d1[0] * box + d2[0] * box, d1[1] * box + d2[1] * box)
            start = math.atan2(left[1] - centre[1], left[0] - centre[0])
            for k in range(1, arc_points):
                angle = start - (math.pi / 2) * k / arc_points
                points.append((centre[0] + radius * math.cos(angle), centre[1] + radius * math.sin(angle)))
    out: list[tuple[float, float]] = []
    for px, py in points:
        p = (round(jx + px, 6), round(jy + py, 6))
        if not out or p != out[-1]:
            out.append(p)
    if len(out) > 1 and out[0] == out[-1]:
        out.pop()
    return tuple(out)


# -- building ------------------------------------------------------------------------------------------
def default_cache_dir() -> Path:
    """Where built networks are kept: ``$VDB_SUMO_CACHE``, else ``$XDG_CACHE_HOME/vdb-sim-sumo``."""
    env = os.environ.get("VDB_SUMO_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "vdb-sim-sumo"


def build_network(plan: NetworkPlan, netconvert: str, sumo_version: str, cache_dir: Path,
                  what: str) -> Path:
    """The ``.net.xml`` of ``plan``: from the cache, or built with ``netconvert`` (atomically, so parallel
    processes building the same network never see a half-written file). ``what`` names the scenario in
    error messages."""
    cache_dir = Path(cache_dir)
    target = cache_dir / f"{plan.key(sumo_version)}.net.xml"
    if target.exists():
        return target
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix="build-", dir=cache_dir))
    except OSError as exc:
        raise VdbError(f"simulator 'sumo': cannot write the network cache {cache_dir}: {exc.strerror}; "
                       "set --sim-opt cache_dir=<writable directory>") from None
    try:
        inputs = {}
        for suffix, text in plan.plain_xml().items():
            inputs[suffix] = work / f"plan.{suffix}"
            inputs[suffix].write_text(text, encoding="utf-8")
        built = work / "plan.net.xml"
        run_netconvert(netconvert, [
            "--node-files", str(inputs["nod.xml"]), "--edge-files", str(inputs["edg.xml"]),
            "--connection-files", str(inputs["con.xml"]), "--output-file", str(built), *NETCONVERT_OPTIONS,
        ], what)
        os.replace(built, target)
    finally:
        for path in work.iterdir():
            path.unlink()
        work.rmdir()
    return target


def run_netconvert(netconvert: str, args: list[str], what: str) -> None:
    """Run ``netconvert``; a failure is one line naming ``what`` and netconvert's first error."""
    try:
        done = subprocess.run([netconvert, *args], capture_output=True, text=True, timeout=120,
                              env=sumo_environment())
    except FileNotFoundError:
        raise VdbError(f"simulator 'sumo': SUMO's netconvert is missing ({netconvert}); "
                       "install SUMO with: pip install eclipse-sumo") from None
    except subprocess.TimeoutExpired:
        raise VdbError(f"simulator 'sumo': netconvert took over 120 s building the network of {what}") from None
    if done.returncode != 0:
        lines = [ln.strip() for ln in (done.stderr + done.stdout).splitlines() if ln.strip()]
        errors = [ln for ln in lines if ln.lower().startswith("error")] or lines or ["no message"]
        raise VdbError(f"simulator 'sumo': netconvert could not build the network of {what}: {errors[0]}")


def sumo_environment() -> dict[str, str]:
    """The environment for SUMO's tools: ``SUMO_HOME`` set to the ``eclipse-sumo`` installation when unset."""
    env = dict(os.environ)
    if not env.get("SUMO_HOME"):
        try:
            import sumo
        except ImportError:
            return env
        home = getattr(sumo, "SUMO_HOME", None)
        if home:
            env["SUMO_HOME"] = home
    return env
