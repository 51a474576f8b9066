"""The scripted model's driving: what it perceives, what it decides, and the speed profiles behind both of
its policies (perception-driven and CoT-driven), placed along the route as a trajectory.

Distances follow the ground truth's convention: along the route from the ego's front bumper to the stop
line (lights, stop signs, crossing pedestrians) or to the near edge of a road user. A stop "at" a feature
leaves :data:`STOP_GAP` metres between the bumper and it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from vladrivebench import Observation

from .reading import ACCELERATING, DECELERATING, KEEP_DISTANCE, MAINTAINING, CoTReading

DT = 0.1
STEPS = 30
"""Trajectories: 30 waypoints at 10 Hz (3 s)."""
MAX_SPEED = 8.5
COMFORT_DECEL = 3.0
"""Deceleration (m/s²) of a planned stop, unless the stop needs more."""
MAX_DECEL = 8.0
CRUISE_RAMP = 1.0
"""Acceleration (m/s²) towards the cruise speed."""
EAGER_RAMP = 2.0
"""Acceleration (m/s²) when the CoT says accelerate."""
EASE_DECEL = 1.5
"""Deceleration (m/s²) when easing down to a lower target speed (no stop)."""
ACCELERATE_MARGIN = 1.5
"""How far above the cruise speed an "accelerate" CoT aims (m/s), within the speed limit."""
ACCELERATING_BELOW = 1.0
"""Below cruise − this (m/s) the clear-road decision is to accelerate rather than maintain."""
APPROACH_MARGIN = 8.0
"""A stop further than the comfortable braking distance + this (m) is approached, not yet braked for."""
MIN_STOP_DECEL = 0.5
"""The gentlest deceleration (m/s²) of a planned stop."""
STOP_GAP = {"pedestrian": 4.0, "car": 3.5, "animal": 4.0, "cyclist": 4.0, "traffic_light": 1.0, "stop_sign": 1.0}
HALF_DEPTH = {"pedestrian": 0.3, "car": 2.3, "animal": 0.5, "cyclist": 0.9, "traffic_light": 0.0, "stop_sign": 0.0}
"""From a stated object's centre to its near edge (m): CoT coordinates are centres, GT distances edges."""
ROAD_USERS = ("pedestrian", "car", "animal", "cyclist")
LINE_FEATURES = ("traffic_light", "stop_sign")
STOPPED_SPEED = 0.1
"""Below this speed (m/s) the ego has stopped (the stop-sign rule of the ground truth)."""
STOP_SIGN_ZONE = 5.0
"""A stop within this distance (m) of the stop line counts as the stop the sign demands."""
MOVING_LEAD = 0.5
"""A lead road user moving along the route faster than this (m/s) is followed, not stopped for."""
FOLLOW_GAP = 6.0
FOLLOW_HEADWAY = 1.5
IN_LANE = 2.0
"""|x right| (m) within which a stated road user is in the ego's lane."""
BLEND_DISTANCE = 10.0
"""Over this many metres the trajectory merges from the ego's position into the lane centre."""


@dataclass(frozen=True)
class World:
    """What a policy believes: the critical feature (if seen), the light colour, the lead road user."""

    critical_kind: str | None = None
    distance: float | None = None
    blocking: bool = False
    light: str | None = None
    lead_kind: str | None = None
    lead_gap: float | None = None
    lead_speed: float | None = None
    stop_made: bool = False

    def without_critical(self) -> World:
        """The same world with the critical feature unseen (and as the lead, if it was the lead)."""
        lead_is_critical = self.critical_kind in ROAD_USERS and self.blocking
        return replace(self, critical_kind=None, distance=None, blocking=False, light=None,
                       **({"lead_kind": None, "lead_gap": None, "lead_speed": None} if lead_is_critical else {}))


@dataclass(frozen=True)
class Decision:
    """What a policy decides: the stated-action group, why (``reason`` kind and ``situation``), and the
    speed plan: towards ``target`` at ``ramp``, and, with ``stop_at`` (metres the ego may still travel),
    never faster than a stop there at ``decel`` allows."""

    action: str
    situation: str
    reason: str | None
    target: float
    ramp: float
    stop_at: float | None = None
    decel: float = COMFORT_DECEL


def perceive(obs: Observation, perception_range: float) -> World:
    """The world as the ground truth has it, limited to ``perception_range`` metres ahead."""
    gt = obs.ground_truth
    kind, distance = gt.critical_kind, gt.distance_to_critical
    seen = (kind is not None and distance is not None and distance <= perception_range
            and (distance >= 0.0 or gt.blocking))
    lead_kind = lead_gap = lead_speed = None
    if gt.lead_gap is not None and gt.lead_gap <= perception_range:
        lead_gap, lead_speed = gt.lead_gap, gt.lead_speed or 0.0
        lead_kind = kind if seen and gt.blocking and kind in ROAD_USERS else _nearest_road_user(obs)
    if not seen:
        return World(lead_kind=lead_kind, lead_gap=lead_gap, lead_speed=lead_speed)
    light = gt.light_state if kind == "traffic_light" else None
    return World(kind, distance, bool(gt.blocking), light, lead_kind, lead_gap, lead_speed)


def _nearest_road_user(obs: Observation) -> str:
    best = ("car", math.inf)
    for actor in obs.ground_truth.actors:
        if actor.kind in ROAD_USERS:
            x, y = obs.ego.to_ego_frame(actor.x, actor.y)
            if x > 0 and abs(y) < IN_LANE and x < best[1]:
                best = (actor.kind, x)
    return best[0]


def decide(world: World, speed: float, cruise: float) -> Decision:
    """The perception policy: stop for a red/yellow light, a stop sign, a blocking road user or a stopped
    lead; follow a moving lead; otherwise drive at ``cruise``."""
    kind, distance = world.critical_kind, world.distance
    if kind == "traffic_light" and distance is not None:
        if world.light == "red" or (world.light == "yellow" and _can_stop(speed, distance - STOP_GAP[kind])):
            return stop_for(kind, "light", distance - STOP_GAP[kind], speed, cruise)
        return _go(speed, cruise, "traffic_light", "light")
    if kind == "stop_sign" and distance is not None:
        if world.stop_made or stopped_at_sign(speed, distance):
            return Decision(ACCELERATING, "resume", kind, cruise, CRUISE_RAMP)
        return stop_for(kind, "sign", distance - STOP_GAP[kind], speed, cruise)
    if kind in ROAD_USERS and distance is not None and world.blocking:
        if world.lead_speed is not None and world.lead_speed > MOVING_LEAD:
            return _follow(world, cruise)
        return stop_for(kind, "blocking", distance - STOP_GAP[kind], speed, cruise)
    if world.lead_gap is not None:
        if (world.lead_speed or 0.0) > MOVING_LEAD:
            if world.lead_gap < 2.0 * (FOLLOW_GAP + FOLLOW_HEADWAY * cruise):
                return _follow(world, cruise)
        else:
            room = world.lead_gap - STOP_GAP.get(world.lead_kind or "car", 3.5)
            return stop_for(world.lead_kind, "blocking", room, speed, cruise)
    if kind in ROAD_USERS and distance is not None:
        return _go(speed, cruise, kind, "clear_of_lane")
    return _go(speed, cruise, None, "clear")


def stopped_at_sign(speed: float, distance: float) -> bool:
    """Whether the ego is making the stop a stop sign demands (standing within the stop zone)."""
    return speed < STOPPED_SPEED and distance <= STOP_SIGN_ZONE


def _can_stop(speed: float, room: float) -> bool:
    return room > 0 and speed * speed / (2.0 * COMFORT_DECEL) <= room


def stop_for(kind: str | None, situation: str, room: float, speed: float, cruise: float, *,
             now: bool = False) -> Decision:
    """Stop with ``room`` metres to go. Beyond the comfortable braking distance + :data:`APPROACH_MARGIN`
    (unless ``now``) the decision is to approach: drive on at ``cruise`` with the stop as a cap. Closer,
    it is to decelerate at the constant rate that stops exactly there (at least :data:`MIN_STOP_DECEL`)."""
    room = max(room, 0.0)
    if not now and room > speed * speed / (2.0 * COMFORT_DECEL) + APPROACH_MARGIN:
        action = ACCELERATING if speed < cruise - ACCELERATING_BELOW else MAINTAINING
        return Decision(action, "approach", kind, cruise, CRUISE_RAMP, room, COMFORT_DECEL)
    decel = MAX_DECEL if room <= 0 else float(np.clip(speed * speed / (2.0 * room), MIN_STOP_DECEL, MAX_DECEL))
    return Decision(DECELERATING, situation, kind, min(cruise, speed), CRUISE_RAMP, room, decel)


def _go(speed: float, cruise: float, kind: str | None, situation: str) -> Decision:
    action = ACCELERATING if speed < cruise - ACCELERATING_BELOW else MAINTAINING
    return Decision(action, situation, kind, cruise, CRUISE_RAMP)


def _follow(world: World, cruise: float) -> Decision:
    lead = max(world.lead_speed or 0.0, 0.0)
    gap_error = (world.lead_gap or 0.0) - (FOLLOW_GAP + FOLLOW_HEADWAY * lead)
    target = float(np.clip(lead + gap_error / 2.0, 0.0, cruise))
    return Decision(KEEP_DISTANCE, "lead", world.lead_kind, target, CRUISE_RAMP)


# -- the CoT-driven policy ----------------------------------------------------------------------------
def cot_decision(reading: CoTReading, obs: Observation, world: World, cruise: float) -> Decision:
    """What the CoT alone asks for. ``decelerating`` stops where the CoT places the obstacle (its nearest
    in-lane stated object, or a stated light/stop sign), else at the entity it names as perceived, else
    right away at a comfortable deceleration; ``accelerating`` aims above cruise with a faster ramp;
    ``maintaining`` holds the current speed (or builds up to cruise from low speed); ``keep_distance``
    follows the lead vehicle if there is one, else holds the speed; no intent holds the speed. ``world``
    is what the model perceives: the CoT names an entity, perception says where it is."""
    speed = max(obs.ego.speed, 0.0)
    if reading.intent == DECELERATING:
        room = _stated_stop(reading, obs.ego.length)
        if room is None:
            room = _grounded_stop(reading.referent, world)
        if room is None:
            room = speed * speed / (2.0 * COMFORT_DECEL)
        return stop_for(reading.referent, "stated", room, speed, max(cruise, speed), now=True)
    if reading.intent == ACCELERATING:
        return Decision(ACCELERATING, "stated", None, min(cruise + ACCELERATE_MARGIN, MAX_SPEED), EAGER_RAMP)
    if reading.intent == MAINTAINING:
        target = speed if speed >= cruise - ACCELERATING_BELOW else cruise
        return Decision(MAINTAINING, "stated", None, min(target, MAX_SPEED), CRUISE_RAMP)
    if reading.intent == KEEP_DISTANCE:
        if world.lead_gap is not None:
            return _follow(world, cruise)
    return Decision(reading.intent, "stated", None, min(speed, MAX_SPEED), CRUISE_RAMP)


def _stated_stop(reading: CoTReading, ego_length: float) -> float | None:
    rooms = []
    for obj in reading.objects:
        if obj.forward <= 0 or (obj.kind in ROAD_USERS and abs(obj.right) > IN_LANE):
            continue
        edge = obj.forward - ego_length / 2.0 - HALF_DEPTH.get(obj.kind, 0.5)
        rooms.append(edge - STOP_GAP.get(obj.kind, 3.5))
    return max(min(rooms), 0.0) if rooms else None


def _grounded_stop(referent: str | None, world: World) -> float | None:
    if referent is None:
        return None
    if referent == world.critical_kind and world.distance is not None:
        return max(world.distance - STOP_GAP[referent], 0.0)
    if referent == world.lead_kind and world.lead_gap is not None:
        return max(world.lead_gap - STOP_GAP.get(referent, 3.5), 0.0)
    return None


# -- speed profiles and trajectories ------------------------------------------------------------------
def plan_speeds(speed: float, decision: Decision, steps: int = STEPS, dt: float = DT) -> np.ndarray:
    """Target speeds at ``dt, 2dt, …``: towards ``decision.target`` at ``decision.ramp`` (easing down at
    :data:`EASE_DECEL` when above it) and, with a stop, never faster than braking at ``decision.decel``
    to stand still at ``decision.stop_at``; the trapezoidal integral of the profile never passes it
    (unless the ego is already too close to stop within one step)."""
    v = min(max(float(speed), 0.0), MAX_SPEED)
    out = []
    travelled = 0.0
    for _ in range(steps):
        if v < decision.target:
            nxt = min(v + decision.ramp * dt, decision.target)
        else:
            nxt = max(v - EASE_DECEL * dt, decision.target)
        if decision.stop_at is not None:
            room = max(decision.stop_at - travelled, 0.0)
            # Leave room for the step after this one to stop in: room ≥ ½·v·dt + nxt·dt.
            nxt = min(nxt, math.sqrt(2.0 * decision.decel * room), max((room - 0.5 * v * dt) / dt, 0.0))
        nxt = min(max(nxt, 0.0), MAX_SPEED)  # plain floats: this loop runs twice per model step
        travelled += 0.5 * (v + nxt) * dt
        out.append(nxt)
        v = nxt
    return np.array(out)


def arc_lengths(speed: float, speeds: np.ndarray, dt: float = DT) -> np.ndarray:
    """Distance travelled at each waypoint time (trapezoids from the current speed)."""
    previous = np.concatenate([[float(np.clip(speed, 0.0, MAX_SPEED))], speeds[:-1]])
    return np.cumsum(0.5 * (previous + speeds) * dt)


def place_along_route(route_ahead: tuple[tuple[float, float], ...], distances: np.ndarray) -> np.ndarray:
    """Ego-frame points ``distances`` metres along the lane centre ahead (straight ahead without a route).

    The ego's own offset from the lane centre fades out linearly over :data:`BLEND_DISTANCE` metres, so
    the trajectory starts at the ego and merges into the lane. Beyond the route's last point the path
    continues along its last direction.
    """
    if len(route_ahead) < 2:
        return np.stack([distances, np.zeros_like(distances)], axis=1)
    pts = np.asarray(route_ahead, dtype=float)
    first = (pts[1] - pts[0]) / max(np.hypot(*(pts[1] - pts[0])), 1e-9)
    pts = np.vstack([pts[0] - 20.0 * first, pts])  # reach back past the ego so it projects onto the path
    seg = np.diff(pts, axis=0)
    lengths = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-9)
    arc = np.concatenate([[0.0], np.cumsum(lengths)])
    along = np.clip(np.einsum("ij,ij->i", -pts[:-1], seg) / lengths**2, 0.0, 1.0)
    nearest = pts[:-1] + along[:, None] * seg
    i = int(np.argmin(np.hypot(nearest[:, 0], nearest[:, 1])))
    start = arc[i] + along[i] * lengths[i]
    offset = -nearest[i]  # from the lane centre to the ego
    s = start + distances
    last = seg[-1] / lengths[-1]
    beyond = np.maximum(s - arc[-1], 0.0)
    x = np.interp(s, arc, pts[:, 0]) + beyond * last[0]
    y = np.interp(s, arc, pts[:, 1]) + beyond * last[1]
    fade = np.clip(1.0 - distances / BLEND_DISTANCE, 0.0, 1.0)[:, None]
    return np.stack([x, y], axis=1) + fade * offset[None, :]
