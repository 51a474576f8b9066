"""The SUMO simulator: the scenario suite in SUMO through libsumo, seen by the shared camera.

The world of a scenario is a SUMO network built with ``netconvert`` from the shared road geometry
(:mod:`vdb_sim_sumo.network`) — or a user's own ``.net.xml`` with a route for the ego
(:mod:`vdb_sim_sumo.usernet`). Each step (dt = 0.1 s):

1. the ego moves under the control through the core's kinematic bicycle model (or is placed at an MPC
   controller's ``next_state``) and is placed in SUMO with ``vehicle.moveToXY``; SUMO's other vehicles see
   it as a road user (car following, junction right of way) but SUMO does not drive it;
2. scenario road users whose trigger the ego has reached start moving. With ``pedestrians="scripted"``
   (default) they follow the scenario's script (:mod:`vladrivebench.world._motion`), exactly as in the
   kinematic simulator, and a stand-in vehicle of their size is placed in SUMO with ``moveToXY`` so that
   SUMO's traffic sees them and SUMO's collision check covers them; with ``pedestrians="sumo"`` moving
   pedestrians and animals are SUMO persons walked by SUMO's striping model on the sidewalks and over the
   crossings netconvert built (:mod:`vdb_sim_sumo.persons`);
3. SUMO advances one step: background vehicles and pedestrians (``background_*_per_hour``), the frozen
   traffic light, the stop junction;
4. collisions: the ego's box against every actor's box (the shared separating-axis test) united with the
   collisions SUMO reports for the ego (its sublane model checks lateral overlap too), one entry per actor;
5. the shared :class:`~vladrivebench.world._truth.TruthTracker` computes the ground truth from the road
   users' poses (scripted ones from their script, SUMO's own from SUMO) — distance to the critical
   feature, blocking, light state, red-light and stop-sign violations (SUMO enforces no rule on a placed
   ego), terminal state — and the shared camera renders the image.

Determinism: SUMO's random-number generator is seeded from the episode's seed, pedestrians' start
positions are jittered from the same stream as the kinematic simulator's (so both simulators pose the same
episode), and one SUMO simulation runs per process (:mod:`vdb_sim_sumo.session`): the same
``(scenario, seed)`` gives the same episode, also after other episodes in the same process.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vladrivebench import Actor, CameraSpec, ConfigError, Control, Observation, Scenario, episode_rng
from vladrivebench.world import (
    DT,
    EGO_LENGTH,
    EGO_WIDTH,
    WORLD_FEATURES,
    RigRecorder,
    RoadGeometry,
    TruthTracker,
    apply_control,
    build_road,
    check_history_options,
    check_numbers,
    check_supported,
    colliding,
    ego_at_start,
    option_error,
    rig_from_options,
    route_text,
    scripted_users,
)

from . import network
from .lights import ego_colour, frozen_state
from .persons import PERSON_PREFIX
from .session import SumoSession, netconvert_binary, sumo_version
from .traffic import TrafficDensity, routes_xml, trips_between

SUPPORTED_FEATURES = WORLD_FEATURES
"""Every scenario feature (see :meth:`Scenario.features`) this simulator represents: the shared world's."""
PEDESTRIAN_MODELS = ("scripted", "sumo")
PERSON_KINDS = ("pedestrian", "animal")
EGO_ID = "vdb.ego"
ACTOR_PREFIX = "vdb.actor."
START_CLEARANCE = 30.0
"""Background vehicles within this distance (m) of the ego's start are removed when the episode begins."""
PERSON_CLEARANCE = 4.0
"""Background pedestrians within this distance (m) of the ego's start are removed when it begins."""
PEDESTRIAN_OPTIONS = {
    "scripted": ["--pedestrian.model", "striping"],
    "sumo": ["--pedestrian.model", "striping", "--pedestrian.striping.dawdling", "0"],
}
"""SUMO's pedestrian model per ``pedestrians`` mode (SUMO-walked pedestrians keep the scenario's speed)."""
SUMO_OPTIONS = (
    "--step-length", f"{DT}",
    "--no-step-log", "true",
    "--no-warnings", "true",
    "--collision.action", "warn",
    "--intermodal-collision.action", "warn",
    "--collision.check-junctions", "true",
    "--collision.mingap-factor", "0",
    "--lateral-resolution", "0.5",  # the sublane model: SUMO's collision check sees lateral offsets
    "--time-to-teleport", "-1",
    "--ignore-route-errors", "true",  # a background trip with no route is dropped, not fatal
    "--begin", "0",
)


@dataclass(frozen=True)
class World:
    """A scenario's SUMO world: geometry (the reference for the camera and the ground truth), network,
    background routes, the ego's edges and lane, and the traffic light's node and approach edge."""

    road: RoadGeometry
    net: Path
    routes: Path | None
    route_edges: tuple[str, ...]
    ego_lane: int
    tls: str | None
    approach: str | None
    crossing_nodes: dict[str, str]


class SumoSimulator:
    """SUMO through libsumo at 10 Hz (see the module docstring).

    Camera options as the kinematic simulator's: ``rig`` (``front`` or ``alpamayo``), ``cameras``,
    ``width`` × ``height`` pixels, ``frames`` at ``frame_rate_hz``, ``poses``, ``render`` (False: blank
    images) and, for the ``front`` rig, ``hfov_deg``, ``camera_height`` (m), ``pitch_deg``; ``position_jitter`` (m) shifts pedestrians'
    start along the route per seed. SUMO options: ``background_vehicles_per_hour`` and
    ``background_pedestrians_per_hour`` (whole network), ``background_warmup_s`` (SUMO runs this long
    before the episode so the traffic is under way), ``pedestrians`` (``"scripted"`` or ``"sumo"``),
    ``net_file`` + ``route`` (a user's SUMO network and the ego's edges, comma-separated) with
    ``depart_pos`` (m along the first edge), and ``cache_dir`` (where built networks are kept).
    """

    dt = DT

    def __init__(self, width: int | None = None, height: int | None = None, render: bool = True,
                 hfov_deg: float = 90.0, camera_height: float = 1.6, pitch_deg: float = 0.0,
                 position_jitter: float = 0.2, background_vehicles_per_hour: float = 0.0,
                 background_pedestrians_per_hour: float = 0.0, background_warmup_s: float = 30.0,
                 pedestrians: str = "scripted", net_file: str | None = None, route: str | None = None,
                 depart_pos: float = 0.0, cache_dir: str | None = None, rig: str = "front",
                 cameras: str | None = None, frames: int = 1, frame_rate_hz: float = 10.0, poses: int = 16):
        specs, stride = _check_options(locals())
        self.render = render
        self.position_jitter = float(position_jitter)
        self.density = TrafficDensity(float(background_vehicles_per_hour), float(background_pedestrians_per_hour))
        self.warmup_steps = int(round(float(background_warmup_s) / self.dt)) if not self.density.empty else 0
        self.pedestrians = pedestrians
        self.user_net = None
        if net_file is not None:
            from .usernet import UserNetwork

            self.user_net = UserNetwork.from_options(net_file, route, float(depart_pos))
        self.cache_dir = Path(cache_dir) if cache_dir else network.default_cache_dir()
        self.rig = RigRecorder(specs, frames, stride, poses, render)
        self.camera = self.rig.main
        self.netconvert = netconvert_binary()
        self.session = SumoSession(self)  # last: nothing after it may fail, or the process stays claimed
        self._release = weakref.finalize(self, self.session.close)
        self.libsumo = self.session.libsumo
        self.sumo_version = sumo_version(self.libsumo)
        self._worlds: dict[str, World] = {}
        self.scenario: Scenario | None = None
        self._terminal: str | None = None
        self._sizes: dict[str, tuple[float, float, float]] = {}

    # -- protocol -----------------------------------------------------------------------------------
    def reset(self, scenario: Scenario, seed: int) -> Observation:
        """Start an episode of ``scenario``; ``seed`` seeds SUMO and jitters pedestrians' start."""
        check_supported(scenario, "sumo", SUPPORTED_FEATURES)
        world = self._world(scenario)
        if self.pedestrians == "sumo":
            from .persons import check_walkable

            check_walkable(scenario, world)
        self.scenario, self.world, self.road = scenario, world, world.road
        self.users = scripted_users(scenario, seed, self.position_jitter)
        sumo_seed = int(episode_rng(seed, "sumo").integers(0, 2**31 - 1))
        args = ["-n", str(world.net), "--seed", str(sumo_seed), *SUMO_OPTIONS]
        args += PEDESTRIAN_OPTIONS[self.pedestrians]
        if world.routes is not None:
            args += ["-r", str(world.routes)]
        self.session.begin(args, f"scenario {scenario.source or scenario.id}")
        sumo = self.libsumo
        self._sizes.clear()
        self._ego_links, self._light_state = self._freeze_light(scenario, world)
        for _ in range(self.warmup_steps):
            sumo.simulationStep()
        self.ego = ego_at_start(self.road.route, scenario.ego.speed)
        self._clear_start()
        self._add_ego()
        self._native = None
        if self.pedestrians == "sumo":
            from .persons import NativePersons

            self._native = NativePersons(sumo, scenario, world)
        self._add_road_users()
        # Where crossing pedestrians cross: a scripted one where its (jittered) script puts it, a SUMO-walked
        # one on the SUMO crossing built at the scenario's crossing line.
        crossing = {u.spec.id: u.s if self._native is None or not self._native.handles(u.spec.id) else u.spec.s
                    for u in self.users if u.spec.motion == "cross"}
        self.truth = TruthTracker(scenario, self.road, crossing)
        self.step_index = 0
        self._terminal = None
        self.rig.reset()
        # One step to insert the new road users, one with them placed: a person placed in the step it
        # departs would land short of its place.
        self._place()
        sumo.simulationStep()
        self._place()
        sumo.simulationStep()
        return self._observe()

    def step(self, control: Control) -> Observation:
        """Advance one step (see the module docstring for the order of events)."""
        if self.scenario is None:
            raise RuntimeError("SumoSimulator.step() called before reset()")
        if self._terminal is not None:
            raise RuntimeError(f"the episode has ended ({self._terminal}); call reset() to start another")
        self.ego = apply_control(self.ego, control, self.dt)
        self._move_users()
        self._place()
        self.libsumo.simulationStep()
        self.step_index += 1
        return self._observe()

    def close(self) -> None:
        """End the SUMO simulation (another simulator may then start one in this process)."""
        self._release()

    # -- the world ----------------------------------------------------------------------------------
    def _world(self, scenario: Scenario) -> World:
        key = repr(scenario.to_json())
        if key not in self._worlds:
            self._worlds[key] = self._build_world(scenario)
        return self._worlds[key]

    def _build_world(self, scenario: Scenario) -> World:
        what = f"scenario {scenario.source or scenario.id}"
        if self.user_net is not None:
            user = self.user_net.world(scenario)
            road, net, edges, lane, tls, approach = (user.road, user.net, user.route_edges, user.ego_lane,
                                                     user.tls, user.approach)
            drives, walks = user.drives, user.walks
            crossing_nodes: dict[str, str] = {}
        else:
            road = build_road(scenario)
            plan = network.plan_network(scenario, road)
            net = network.build_network(plan, self.netconvert, self.sumo_version, self.cache_dir, what)
            edges, lane = plan.route, plan.ego_lane
            tls, approach, crossing_nodes = plan.tls, plan.feature_approach, dict(plan.crossing_nodes)
            drives, walks = trips_between(plan.ends, plan.has_sidewalks)
        routes = None
        if not self.density.empty:
            end_s = math.ceil(self.warmup_steps * self.dt + scenario.max_time_s + 10.0)
            text = routes_xml(drives, walks, self.density, end_s)
            routes = _cached_text(self.cache_dir, text, ".rou.xml")
        return World(road, net, routes, tuple(edges), lane, tls, approach, crossing_nodes)

    def _freeze_light(self, scenario: Scenario, world: World) -> tuple[list[int], str | None]:
        """Freeze the scenario's light in SUMO; returns the ego's link indices and the frozen state."""
        if scenario.light is None or world.tls is None:
            return [], None
        tl = self.libsumo.trafficlight
        links = tl.getControlledLinks(world.tls)
        ego_links = [i for i, group in enumerate(links)
                     if group and group[0][0].rsplit("_", 1)[0] == world.approach]
        phases = [p.state for p in tl.getAllProgramLogics(world.tls)[0].phases]
        state = frozen_state(phases, ego_links, scenario.light.state)
        tl.setRedYellowGreenState(world.tls, state)
        return ego_links, state

    def light_colour(self) -> str | None:
        """The colour SUMO's traffic light shows the ego now (``None`` without a light)."""
        if not self._ego_links:
            return None
        return ego_colour(self.libsumo.trafficlight.getRedYellowGreenState(self.world.tls), self._ego_links)

    def _clear_start(self) -> None:
        """Remove warm-up traffic where the ego appears, so that the episode does not begin in a crash."""
        sumo = self.libsumo
        for vid in sumo.vehicle.getIDList():
            x, y = sumo.vehicle.getPosition(vid)
            if math.hypot(x - self.ego.x, y - self.ego.y) < START_CLEARANCE:
                sumo.vehicle.remove(vid)
        for pid in sumo.person.getIDList():
            x, y = sumo.person.getPosition(pid)
            if math.hypot(x - self.ego.x, y - self.ego.y) < PERSON_CLEARANCE:
                sumo.person.remove(pid)

    def _add_ego(self) -> None:
        sumo = self.libsumo
        vtype = sumo.vehicletype
        vtype.copy("DEFAULT_VEHTYPE", EGO_ID)
        vtype.setVehicleClass(EGO_ID, "passenger")
        vtype.setLength(EGO_ID, EGO_LENGTH)
        vtype.setWidth(EGO_ID, EGO_WIDTH)
        vtype.setMinGap(EGO_ID, 0.0)
        sumo.route.add(EGO_ID, list(self.world.route_edges))
        sumo.vehicle.add(EGO_ID, EGO_ID, typeID=EGO_ID, depart="now", departLane=str(self.world.ego_lane),
                         departSpeed="0")

    def _add_road_users(self) -> None:
        """Every scenario road user gets a stand-in in SUMO: a vehicle of its size (of SUMO's class
        ``ignoring`` for pedestrians and animals, so it may stand on any lane) placed where the scenario
        puts it, which SUMO's traffic sees and SUMO's collision check covers. (SUMO persons cannot be
        placed: the striping model crashes when one is moved onto a walking area, the non-interacting model
        walks it away.) SUMO-walked pedestrians become SUMO persons while they walk."""
        vtype = self.libsumo.vehicletype
        for user in self.users:
            spec = user.spec
            type_id = ACTOR_PREFIX + spec.id
            vtype.copy("DEFAULT_VEHTYPE", type_id)
            vtype.setVehicleClass(type_id, "passenger")
            if spec.kind in PERSON_KINDS:
                vtype.setShapeClass(type_id, "pedestrian")
            vtype.setMinGap(type_id, 0.0)
            for setter, value in ((vtype.setLength, spec.length), (vtype.setWidth, spec.width),
                                  (vtype.setHeight, spec.height)):
                setter(type_id, value)
            if self._native is not None and self._native.handles(spec.id):
                self._native.prepare(user)
                if user.started:  # no trigger: it walks from the first step
                    self._native.start(spec.id)
                    continue
            self._add_stand_in(spec.id, user.actor(self.road.route))

    def _add_stand_in(self, actor_id: str, actor: Actor) -> None:
        sumo, sumo_id = self.libsumo, ACTOR_PREFIX + actor_id
        edge, pos, lane = sumo.simulation.convertRoad(actor.x, actor.y, False, "passenger")
        route_id = f"{sumo_id}@{sumo.simulation.getTime():g}"
        sumo.route.add(route_id, [edge])
        sumo.vehicle.add(sumo_id, route_id, typeID=sumo_id, depart="now", departLane=str(lane),
                         departPos=f"{pos:.3f}", departSpeed="0")

    # -- per step -----------------------------------------------------------------------------------
    def _move_users(self) -> None:
        front = self.truth.ego_s(self.ego) + self.ego.length / 2
        route = self.road.route
        for user in self.users:
            started = user.check_trigger(front)
            if self._native is not None and self._native.handles(user.spec.id):
                if started:
                    self.libsumo.vehicle.remove(ACTOR_PREFIX + user.spec.id)
                    self._native.start(user.spec.id)
                continue
            user.advance(route, self.ego, self.dt)

    def _place(self) -> None:
        """Place the ego and the road users' stand-ins in SUMO for the coming step."""
        sumo = self.libsumo
        ego = self.ego
        fx, fy = ego.to_world_frame(ego.length / 2, 0.0)
        sumo.vehicle.moveToXY(EGO_ID, "", self.world.ego_lane, fx, fy, _sumo_angle(ego.yaw), 2)
        for actor in self._scenario_actors():
            if self._native is not None and self._native.walking(actor.actor_id):
                continue
            yaw = self._along_lane(actor)
            fx = actor.x + math.cos(yaw) * actor.length / 2
            fy = actor.y + math.sin(yaw) * actor.length / 2
            sumo.vehicle.moveToXY(ACTOR_PREFIX + actor.actor_id, "", -1, fx, fy, _sumo_angle(yaw), 2)

    def _along_lane(self, actor: Actor) -> float:
        """The actor's heading, or the opposite one if it faces against the lane it stands on: the same box,
        turned so that SUMO (which takes a vehicle's position as its front along its lane) sees where it
        really begins and ends along the lane."""
        sumo = self.libsumo
        edge, pos, lane = sumo.simulation.convertRoad(actor.x, actor.y, False, "passenger")
        length = sumo.lane.getLength(f"{edge}_{lane}")
        a, b = max(pos - 0.25, 0.0), min(pos + 0.25, length)
        (ax, ay), (bx, by) = (sumo.simulation.convert2D(edge, p, lane) for p in (a, b))
        if (bx - ax) * math.cos(actor.yaw) + (by - ay) * math.sin(actor.yaw) < 0:
            return math.remainder(actor.yaw + math.pi, 2 * math.pi)
        return actor.yaw

    def _scenario_actors(self) -> list[Actor]:
        """The scenario's road users now, in scenario order: scripted ones where their script puts them,
        SUMO-walked ones where SUMO walks them (or where they stand)."""
        route = self.road.route
        out = []
        for user in self.users:
            if self._native is not None and self._native.handles(user.spec.id):
                out.append(self._native.pose(user.spec.id))
            else:
                out.append(user.actor(route))
        return out

    def actors(self) -> tuple[Actor, ...]:
        """Every road user now: the scenario's (see :meth:`_scenario_actors`), then SUMO's background
        vehicles and pedestrians."""
        if self._native is not None:
            for actor_id in sorted(self._native.walkers):
                if self._native.update(actor_id):  # its walk ended: it stands where it stopped
                    self._add_stand_in(actor_id, self._native.pose(actor_id))
        out = self._scenario_actors()
        sumo = self.libsumo
        for vid in sumo.vehicle.getIDList():
            if vid != EGO_ID and not vid.startswith(ACTOR_PREFIX):
                out.append(self._vehicle_actor(vid, vid, "car", *self._size(vid, vehicle=True)))
        for pid in sumo.person.getIDList():
            if not pid.startswith(PERSON_PREFIX):
                out.append(self._person_actor(pid, pid, "pedestrian", *self._size(pid, vehicle=False)))
        return tuple(out)

    def sumo_pose(self, actor_id: str) -> Actor:
        """Where SUMO has the scenario road user ``actor_id``: its walking person, or its stand-in."""
        spec = self.scenario.actor(actor_id)
        if self._native is not None and self._native.walking(actor_id):
            return self._person_actor(PERSON_PREFIX + actor_id, spec.id, spec.kind, spec.length, spec.width,
                                      spec.height)
        return self._vehicle_actor(ACTOR_PREFIX + actor_id, spec.id, spec.kind, spec.length, spec.width,
                                   spec.height)

    def _vehicle_actor(self, sumo_id: str, actor_id: str, kind: str, length: float, width: float,
                       height: float) -> Actor:
        vehicle = self.libsumo.vehicle
        x, y = vehicle.getPosition(sumo_id)  # the front bumper
        yaw = _yaw(vehicle.getAngle(sumo_id))
        cx, cy = x - math.cos(yaw) * length / 2, y - math.sin(yaw) * length / 2
        return Actor(actor_id, kind, cx, cy, yaw, length, width, height, max(vehicle.getSpeed(sumo_id), 0.0))

    def _person_actor(self, sumo_id: str, actor_id: str, kind: str, length: float, width: float,
                      height: float) -> Actor:
        person = self.libsumo.person
        x, y = person.getPosition(sumo_id)
        yaw = _yaw(person.getAngle(sumo_id))
        return Actor(actor_id, kind, x, y, yaw, length, width, height, max(person.getSpeed(sumo_id), 0.0))

    def _size(self, sumo_id: str, vehicle: bool) -> tuple[float, float, float]:
        """(length, width, height) of a background road user, from its SUMO type."""
        domain = self.libsumo.vehicle if vehicle else self.libsumo.person
        type_id = domain.getTypeID(sumo_id)
        if type_id not in self._sizes:
            vt = self.libsumo.vehicletype
            self._sizes[type_id] = (vt.getLength(type_id), vt.getWidth(type_id), vt.getHeight(type_id))
        return self._sizes[type_id]

    def sumo_collisions(self) -> tuple[str, ...]:
        """Actor ids SUMO reports colliding with the ego this step."""
        out = []
        for c in self.libsumo.simulation.getCollisions():
            if EGO_ID not in (c.collider, c.victim):
                continue
            other = c.victim if c.collider == EGO_ID else c.collider
            for prefix in (ACTOR_PREFIX, PERSON_PREFIX):
                if other.startswith(prefix):
                    other = other[len(prefix):]
            out.append(other)
        return tuple(out)

    def _observe(self) -> Observation:
        actors = self.actors()
        collisions = tuple(dict.fromkeys(colliding(self.ego, actors) + self.sumo_collisions()))
        truth = self.truth.observe(self.step_index, self.ego, actors, collisions)
        self._terminal = truth.terminal
        image, cameras, poses = self.rig.observe(self.step_index, truth.time, self.ego, self.road, truth.actors)
        text = route_text(self.scenario.command, truth.route_progress, truth.route_length,
                          getattr(self.road, "junction_span", None))  # a user's network has no known junction
        return Observation(step=self.step_index, time=truth.time, image=image, ego=self.ego,
                           command=self.scenario.command, ground_truth=truth, scenario_id=self.scenario.id,
                           cameras=cameras, pose_history=poses, route_text=text)


def _sumo_angle(yaw: float) -> float:
    """World yaw (rad, counter-clockwise from east) → SUMO angle (degrees, clockwise from north)."""
    return (90.0 - math.degrees(yaw)) % 360.0


def _yaw(angle: float) -> float:
    """SUMO angle → world yaw in (-π, π]."""
    return math.remainder(math.radians(90.0 - angle), 2 * math.pi)


def _cached_text(cache_dir: Path, text: str, suffix: str) -> Path:
    import hashlib
    import os
    import tempfile

    target = Path(cache_dir) / f"{hashlib.sha256(text.encode()).hexdigest()[:24]}{suffix}"
    if not target.exists():
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, target)
    return target


def _check_options(values: dict[str, Any]) -> tuple[tuple[CameraSpec, ...], int]:
    """One-line :class:`ConfigError` for the first bad option; the rig's cameras and frame stride."""
    def fail(name: str, expected: str) -> ConfigError:
        return option_error("sumo", name, expected, values[name])

    specs = rig_from_options("sumo", values)
    stride = check_history_options("sumo", values, DT)
    check_numbers("sumo", values, (("background_vehicles_per_hour", 0.0, 20000.0),
                                   ("background_pedestrians_per_hour", 0.0, 20000.0),
                                   ("background_warmup_s", 0.0, 3600.0), ("depart_pos", 0.0, 1e6)))
    if values["pedestrians"] not in PEDESTRIAN_MODELS:
        raise fail("pedestrians", " or ".join(repr(m) for m in PEDESTRIAN_MODELS))
    for name in ("net_file", "route", "cache_dir"):
        value = values[name]
        if value is not None and (not isinstance(value, str) or not value.strip()):
            raise fail(name, "a non-empty string")
    if (values["net_file"] is None) != (values["route"] is None):
        missing = "route" if values["route"] is None else "net_file"
        given = "net_file" if missing == "route" else "route"
        raise ConfigError(f"simulator 'sumo': option {given} needs option {missing} too "
                          "(a SUMO network and the ego's route through it: route=edge1,edge2,...)")
    return specs, stride
