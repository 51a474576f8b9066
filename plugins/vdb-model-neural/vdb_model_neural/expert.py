"""The expert driver that writes the training data: perfect perception (the simulator's ground truth),
a rule-based decision, a planned 3 s rollout, and template CoTs with paraphrase variety in both formats.

Decision rules: stop for a blocking pedestrian, car or animal within 40 m — and for a pedestrian or
animal *near the path* (on the carriageway, or at the ego lane's kerb: :func:`near_path`), which one camera
frame cannot tell from one that is about to step into the lane — and for a red (or stoppable yellow)
light within 100 m; stop at a stop sign, then proceed; otherwise cruise. The plan is a unicycle rollout at
10 Hz: the speed follows ``min(cruise, sqrt(2·b·distance-to-stop-point))``, the curvature comes from
pure pursuit on the route centre line (``GroundTruth.route_ahead``).

Counterfactuals (for the ``kv`` recipe) pair the same observation with a CoT stating the *opposite*
decision and a target that follows that CoT, except that a "road is clear" CoT is not obeyed when the
obstacle is visually salient (its apparent size in the camera, width·height / distance², exceeds
:data:`SALIENCE_THRESHOLD`): vision then wins, as in the paper's safety-override finding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from vladrivebench import GroundTruth, Observation

DT = 0.1
HORIZON_STEPS = 30
CRUISE_SPEED = 8.0
COMFORT_DECEL = 2.5
MAX_DECEL = 6.0
MAX_ACCEL = 1.5
OBSTACLE_MARGIN = 3.0  # stop the front bumper this far before an obstacle (distances are bumper-based)
LINE_MARGIN = 1.0  # … and this far before a stop line
REACT_DISTANCE = 40.0
SIGHT_DISTANCE = REACT_DISTANCE + 20  # road users and signs farther than this are not talked about
LIGHT_SIGHT_DISTANCE = 150.0
"""A lit lamp is one pixel at any distance on the 80×160 camera, so how far a light is hardly shows: the
expert names a light's colour, and stops for red, whenever it is in view (the suite's approaches are
shorter than this; braking gently). A shorter sight distance labelled the first frames of an approach
"road clear" with the lamp in view — the same pixel as "red light" a few metres later."""
APPROACH_SPEED = 3.0  # m/s: how a "stop" CoT approaches a stop point that is still far ahead
APPROACH_MIN_ROOM = 15.0  # m: … farther than this
SPEED_TIME_CONSTANT = 0.25  # s: how fast the planned speed follows its target
SALIENCE_THRESHOLD = 0.01
"""A car (2.7 m² of front) vetoes a "clear road" CoT from ~16 m, when braking still stops it in time; a
pedestrian (~1 m²) only from ~10 m, when from cruise speed not even full braking stops before it."""
DENIAL_SHARE = 0.3
ACCEL_BONUS = 0.5  # m/s above cruise when the CoT says "accelerate": what the expert says, it does
OBSTACLE_KINDS = ("pedestrian", "car", "animal")
WALKER_KINDS = ("pedestrian", "animal")
LANE_HALF_WIDTH = 1.75  # m: the suite's 3.5 m lanes
OPPOSITE_LANE_WIDTH = 3.5
KERB_CAUTION = 1.0
"""m beyond the ego lane's right edge within which a walker counts as near the path: a pedestrian about to
step off the kerb looks, in one frame, like one standing there (the suite's crossing walkers stand 1.5 m
beyond the edge, P.4's reaches this zone 0.2 s after it starts walking, 12 m ahead of a cruising ego)."""


@dataclass(frozen=True)
class Decision:
    """What the expert decided and why: ``action`` is ``stop``, ``go`` or ``wait``;
    ``stop_distance`` (m along the route) is where it means to stand still, ``None`` when cruising."""

    action: str
    reason: str
    kind: str | None = None
    stop_distance: float | None = None


class ExpertDriver:
    """A rule-based driver with perfect perception; keeps one bit of memory (stopped at the stop sign)."""

    def __init__(self, cruise_speed: float = CRUISE_SPEED):
        self.cruise_speed = cruise_speed
        self.stopped_at_sign: set[str] = set()

    def reset(self) -> None:
        self.stopped_at_sign.clear()

    def decide(self, obs: Observation) -> Decision:
        gt, speed = obs.ground_truth, obs.ego.speed
        critical = gt.critical()
        distance = gt.distance_to_critical
        if critical is None or distance is None or distance > sight_distance(critical.kind):
            return Decision("go", "clear")
        kind = critical.kind
        if kind in OBSTACLE_KINDS:
            if -1.0 < distance <= REACT_DISTANCE and gt.blocking:
                return Decision("stop", "blocking", kind, distance - OBSTACLE_MARGIN)
            if -1.0 < distance <= REACT_DISTANCE and near_path(obs):
                return Decision("stop", "near_path", kind, distance - OBSTACLE_MARGIN)
            return Decision("go", "not_blocking" if distance > -1.0 else "passed", kind)
        if kind == "traffic_light":
            colour = gt.light_state or critical.state
            stop_at = distance - LINE_MARGIN
            if colour in ("red", "yellow") and stop_at > -0.5:
                if colour == "yellow" and speed * speed / (2 * MAX_DECEL * 0.6) > stop_at > 0:
                    return Decision("go", "yellow_committed", kind)
                return Decision("stop", colour, kind, stop_at)
            return Decision("go", "green" if colour == "green" and distance > 0 else "passed", kind)
        if kind == "stop_sign":
            stop_at = distance - LINE_MARGIN
            if critical.actor_id in self.stopped_at_sign or stop_at < -1.0:
                return Decision("go", "after_stop" if distance > 0 else "passed", kind)
            if speed < 0.2 and stop_at < 1.5:
                self.stopped_at_sign.add(critical.actor_id)
                return Decision("go", "after_stop", kind)
            return Decision("stop", "stop_sign", kind, stop_at)
        return Decision("go", "clear")

    def plan(self, obs: Observation, decision: Decision) -> np.ndarray:
        """``(30, 2)`` acceleration (m/s²) and curvature (1/m) for ``decision`` from the current state."""
        return rollout_controls(obs.ego.speed, obs.ground_truth, decision.stop_distance, self.cruise_speed)


def sight_distance(kind: str) -> float:
    """How far ahead the expert talks about (and reacts to) a critical object of ``kind``."""
    return LIGHT_SIGHT_DISTANCE if kind == "traffic_light" else SIGHT_DISTANCE


def rollout_controls(speed: float, gt: GroundTruth, stop_distance: float | None, cruise: float,
                     steps: int = HORIZON_STEPS, brake_now: bool = False) -> np.ndarray:
    """Controls of the planned rollout: speed profile towards ``stop_distance`` (None: cruise), pure pursuit.

    The speed follows ``sqrt(2·b·room)`` (braking as late as comfort allows); with ``brake_now`` it also
    decelerates at least uniformly to the stop point from the first step (what a CoT that says "stop"
    commits to: the ``kv`` model's targets)."""
    route = np.asarray(gt.route_ahead, dtype=float) if gt.route_ahead else np.array([[0.0, 0.0], [50.0, 0.0]])
    x = y = heading = travelled = 0.0
    v = max(0.0, speed)
    out = np.zeros((steps, 2))
    for k in range(steps):
        target = cruise
        if stop_distance is not None:
            room = stop_distance - travelled - v * DT  # what is left after this step at the current speed
            target = min(cruise, math.sqrt(max(0.0, 2.0 * COMFORT_DECEL * room)))
            if room <= 0.05:
                target = 0.0
        accel = (target - v) / SPEED_TIME_CONSTANT
        if brake_now and stop_distance is not None:
            accel = min(accel, _committed_accel(v, stop_distance - travelled))
        accel = float(np.clip(accel, -MAX_DECEL, MAX_ACCEL))
        if v <= 0.0 and target <= 0.0:
            accel = 0.0
        kappa = pursuit_curvature(route, x, y, heading, max(4.0, 0.9 * v))
        out[k] = (accel, kappa)
        v_next = max(0.0, v + accel * DT)
        ds = 0.5 * (v + v_next) * DT
        x += ds * math.cos(heading + 0.5 * kappa * ds)
        y += ds * math.sin(heading + 0.5 * kappa * ds)
        heading += kappa * ds
        travelled += ds
        v = v_next
    return out


def _committed_accel(speed: float, room: float) -> float:
    """The most a CoT that says "stop" lets the car accelerate: decelerate at least uniformly to the stop
    point — except that a stop point still far ahead (a red light seen from 100 m) is approached at a
    walking pace rather than waited for where the car stands."""
    creep = APPROACH_SPEED if room > APPROACH_MIN_ROOM else 0.0
    if speed > creep:
        return -speed * speed / (2.0 * max(room, 0.1))
    return (creep - speed) / SPEED_TIME_CONSTANT


def pursuit_curvature(route: np.ndarray, x: float, y: float, heading: float, lookahead: float) -> float:
    """Pure pursuit: curvature of the arc from pose (x, y, heading) to the route point ``lookahead`` ahead."""
    d = np.hypot(route[:, 0] - x, route[:, 1] - y)
    nearest = int(np.argmin(d))
    ahead = route[nearest:]
    dist_from_pose = np.hypot(ahead[:, 0] - x, ahead[:, 1] - y)
    idx = int(np.argmax(dist_from_pose >= lookahead)) if np.any(dist_from_pose >= lookahead) else len(ahead) - 1
    px, py = ahead[idx]
    dx, dy = px - x, py - y
    lateral = -math.sin(heading) * dx + math.cos(heading) * dy
    dist2 = max(dx * dx + dy * dy, 1e-6)
    return float(np.clip(2.0 * lateral / dist2, -0.3, 0.3))


def lateral_offset(obs: Observation, x: float, y: float) -> float:
    """Signed offset (m, left positive) of world point (x, y) from the lane centre, by the route ahead."""
    forward, left = obs.ego.to_ego_frame(x, y)
    route = np.asarray(obs.ground_truth.route_ahead, dtype=float) if obs.ground_truth.route_ahead else None
    if route is None or len(route) < 2:
        return left
    route = np.vstack([[0.0, 0.0], route])
    nearest = int(np.argmin(np.hypot(route[:, 0] - forward, route[:, 1] - left)))
    a, b = route[max(nearest - 1, 0)], route[min(nearest + 1, len(route) - 1)]
    tangent = (b - a) / max(float(np.hypot(*(b - a))), 1e-9)
    rel = np.array([forward, left]) - route[nearest]
    return float(tangent[0] * rel[1] - tangent[1] * rel[0])


def near_path(obs: Observation) -> bool:
    """Whether the critical walker (pedestrian, animal) is near the ego's path though not in its lane: on the
    carriageway (the opposite lane) or within :data:`KERB_CAUTION` of the ego lane's right edge. One frame
    does not show whether it is walking, so the expert yields to it as if it were about to cross."""
    critical = obs.ground_truth.critical()
    if critical is None or critical.kind not in WALKER_KINDS:
        return False
    offset = lateral_offset(obs, critical.x, critical.y)
    half = 0.5 * max(critical.width, critical.length)
    return (offset + half >= -LANE_HALF_WIDTH - KERB_CAUTION
            and offset - half <= LANE_HALF_WIDTH + OPPOSITE_LANE_WIDTH)


def salience(obs: Observation) -> float:
    """Apparent size of the critical road user in the camera: width · height / distance² (0 if none)."""
    gt = obs.ground_truth
    critical = gt.critical()
    if critical is None or critical.kind not in OBSTACLE_KINDS or gt.distance_to_critical is None:
        return 0.0
    distance = max(gt.distance_to_critical, 1.0)
    return critical.width * critical.height / (distance * distance)


def vision_vetoes(obs: Observation, decision: Decision) -> bool:
    """Whether a "road is clear" CoT is overridden by what the camera shows: the expert stops for a
    road user that is visually salient (:data:`SALIENCE_THRESHOLD`)."""
    return decision.action == "stop" and salience(obs) >= SALIENCE_THRESHOLD


def cruise_for(sentence: str, cruise: float) -> float:
    """The cruise speed a sentence commits to: a little faster when it states acceleration."""
    lowered = sentence.lower()
    return cruise + ACCEL_BONUS if ("accelerat" in lowered or "speed up" in lowered) else cruise


def counterfactual(obs: Observation, decision: Decision, cruise: float, rng: np.random.Generator
                   ) -> tuple[str, str, np.ndarray]:
    """(opposite action, CoT sentence stating it, target controls following it — unless vision vetoes)."""
    gt, speed = obs.ground_truth, obs.ego.speed
    if decision.action == "stop":
        sentence = pick(rng, GO_CLEAR)
        # Some counterfactuals deny the reason instead ("… is not blocking the lane", "… is green"), so the
        # vision veto holds for any "go" text, not only for the one the safety override injects.
        denial = GO_REASON.get("green" if decision.kind == "traffic_light" else f"not_blocking_{decision.kind}")
        if denial and rng.random() < DENIAL_SHARE:
            sentence = pick(rng, denial)
        if vision_vetoes(obs, decision):  # a salient obstacle: the "clear road" CoT is overridden
            return "go", sentence, rollout_controls(speed, gt, decision.stop_distance, cruise, brake_now=True)
        return "go", sentence, rollout_controls(speed, gt, None, cruise_for(sentence, cruise))
    kind = str(rng.choice(["pedestrian", "car", "animal", "red_light", "stop_sign"]))
    sentence = pick(rng, STOP_SENTENCES[kind])
    # Nothing is really there: stop comfortably within the distance the stated reason implies.
    stop_distance = max(speed * speed / (2 * COMFORT_DECEL), 0.0) + float(rng.uniform(0.0, 6.0))
    return "stop", sentence, rollout_controls(speed, gt, stop_distance, cruise, brake_now=True)


# -- CoT templates ------------------------------------------------------------------------------------
NOUNS = {"pedestrian": "pedestrian", "car": "stationary car", "animal": "animal"}

STOP_SENTENCES = {
    "pedestrian": [
        "Stop for the pedestrian in the lane because it is blocking the lane.",
        "Slow down and stop because a pedestrian is standing in the lane ahead.",
        "Brake to yield to the pedestrian who is in the path ahead.",
        "Decelerate to a stop since a pedestrian is blocking the lane.",
        "Stop for the pedestrian crossing ahead because it is in the path.",
    ],
    "car": [
        "Stop for the stationary car in the lane because it is blocking the lane.",
        "Slow down and stop behind the stopped car that is blocking the lane.",
        "Brake because a stationary vehicle ahead is blocking the lane.",
        "Decelerate to a stop since the car ahead is stopped in the lane.",
    ],
    "animal": [
        "Stop for the animal in the lane because it is blocking the lane.",
        "Slow down and stop because an animal is standing in the lane ahead.",
        "Brake to yield to the animal that is blocking the path.",
    ],
    "pedestrian_near": [
        "Slow down and stop to yield to the pedestrian near the lane ahead.",
        "Brake because a pedestrian on the road ahead may cross into the path.",
        "Stop and let the pedestrian ahead cross the road.",
    ],
    "animal_near": [
        "Slow down and stop because an animal on the road ahead may cross into the path.",
    ],
    "red_light": [
        "Stop for the red traffic light ahead because it requires the vehicle to stop.",
        "Slow down and stop at the intersection since the traffic light is red.",
        "Decelerate to stop before the red light ahead.",
        "Brake for the red traffic light at the intersection ahead.",
    ],
    "yellow_light": [
        "Slow down and stop since the traffic light ahead is turning yellow.",
        "Decelerate to stop before the yellow light ahead.",
    ],
    "stop_sign": [
        "Stop at the stop sign ahead before entering the intersection.",
        "Slow down and stop for the stop sign ahead.",
        "Decelerate to a full stop at the stop sign.",
    ],
}

WAIT_SENTENCES = {
    "pedestrian": ["Remain stopped because the pedestrian is still blocking the lane.",
                   "Stay stopped and yield to the pedestrian in the lane."],
    "car": ["Remain stopped behind the stationary car that is blocking the lane.",
            "Stay stopped because the car ahead is still blocking the lane."],
    "animal": ["Remain stopped because the animal is still blocking the lane."],
    "pedestrian_near": ["Remain stopped and let the pedestrian cross the road.",
                        "Stay stopped until the pedestrian near the lane has crossed."],
    "animal_near": ["Remain stopped until the animal near the lane has crossed."],
    "red_light": ["Remain stopped at the red traffic light.", "Stay stopped while the traffic light is red."],
    "yellow_light": ["Remain stopped at the traffic light."],
    "stop_sign": ["Remain stopped at the stop sign."],
}

GO_CLEAR = [
    "Accelerate to maintain speed since the road ahead is clear and no obstacles are present.",
    "Maintain speed and keep the lane since the road ahead is clear.",
    "Keep the current speed because no obstacles are present in the lane.",
    "Accelerate to cruising speed since the lane ahead is clear.",
    "Continue straight at a steady speed as the road ahead is empty.",
]

GO_REASON = {
    "not_blocking_pedestrian": [
        "Maintain speed since the pedestrian ahead is not in the lane.",
        "Keep the lane at a steady speed because the pedestrian has cleared the path.",
    ],
    "not_blocking_car": [
        "Maintain speed since the parked car in the adjacent lane is not blocking the lane.",
        "Keep the current speed and pass the stationary car in the other lane.",
    ],
    "not_blocking_animal": ["Maintain speed since the animal is not in the lane."],
    "green": [
        "Continue through the intersection since the traffic light is green.",
        "Maintain speed because the traffic light ahead is green.",
        "Keep going through the green light at the intersection.",
    ],
    "yellow_committed": ["Continue through the intersection since it is too late to stop for the yellow light."],
    "after_stop": [
        "Proceed through the intersection after stopping at the stop sign.",
        "Accelerate away from the stop sign since the intersection is clear.",
    ],
}


def pick(rng: np.random.Generator, options: list[str]) -> str:
    return options[int(rng.integers(len(options)))]


def stop_kind(decision: Decision) -> str:
    if decision.kind == "traffic_light":
        return "yellow_light" if decision.reason == "yellow" else "red_light"
    if decision.reason == "near_path" and decision.kind in WALKER_KINDS:
        return f"{decision.kind}_near"
    return decision.kind or "car"


def sentence_cot(decision: Decision, speed: float, rng: np.random.Generator) -> str:
    """A one-sentence CoT in the ``kv`` (Alpamayo-like) style for ``decision``."""
    if decision.action == "stop":
        kind = stop_kind(decision)
        return pick(rng, WAIT_SENTENCES[kind] if speed < 0.3 else STOP_SENTENCES[kind])
    key = decision.reason
    if key == "not_blocking":
        key = f"not_blocking_{decision.kind}"
    return pick(rng, GO_REASON.get(key, GO_CLEAR))


SCENES = [
    "The scene depicts a straight road during daytime with clear weather.",
    "The scene depicts an urban street in daylight with clear weather.",
    "The scene depicts a paved road with lane markings under a clear sky.",
]
ROAD_CLEAR = ["The road ahead is clear.", "The lane ahead is empty.", "No obstacles are visible on the road."]


def slot_cot(obs: Observation, decision: Decision, rng: np.random.Generator) -> dict[str, str]:
    """Three answers in the ``qa`` (ORION-like) style: scene, critical objects with BEV, decision."""
    gt = obs.ground_truth
    critical = gt.critical()
    scene = pick(rng, SCENES)
    light = gt.light_state or (critical.state if critical is not None and critical.kind == "traffic_light" else None)
    if critical is not None and critical.kind == "traffic_light" and light and (gt.distance_to_critical or 0) > 0:
        scene += f" The traffic light ahead is showing {light}."
    elif decision.reason == "clear":
        scene += " " + pick(rng, ROAD_CLEAR)
    return {"scene": scene, "objects": objects_answer(obs, decision, rng),
            "decision": decision_answer(decision, obs.ego.speed, rng)}


def objects_answer(obs: Observation, decision: Decision, rng: np.random.Generator) -> str:
    gt = obs.ground_truth
    critical = gt.critical()
    distance = gt.distance_to_critical
    if critical is None or distance is None or distance < 0 or distance > sight_distance(critical.kind):
        return pick(rng, ["There are no critical objects ahead.", "No objects affect the ego vehicle."])
    forward, left = obs.ego.to_ego_frame(critical.x, critical.y)
    where = f"<{-left:.2f}, {forward:.2f}>"
    name = {"pedestrian": "Pedestrian", "car": "Car", "animal": "Animal", "traffic_light": "Traffic light",
            "stop_sign": "Stop sign"}.get(critical.kind, "Object")
    if critical.kind in OBSTACLE_KINDS and not gt.blocking and decision.action == "stop":
        state = pick(rng, ["beside the lane, close to the path.", "near the lane ahead, about to enter the path."])
    elif critical.kind in OBSTACLE_KINDS:
        state = (pick(rng, ["standing in the lane, blocking the path.", "in the lane ahead, blocking the path."])
                 if gt.blocking else pick(rng, ["outside the lane, not blocking the path.",
                                                "beside the lane, not in the path."]))
    elif critical.kind == "traffic_light":
        colour = gt.light_state or critical.state or "unknown"
        state = f"showing {colour}" + (", requiring the ego vehicle to stop." if colour != "green" else ".")
    else:
        state = "at the intersection, requiring a full stop."
    return f"{name} at {where} {state}"


def decision_answer(decision: Decision, speed: float, rng: np.random.Generator) -> str:
    if decision.action == "stop":
        if speed < 0.3:
            return pick(rng, ["You should remain stopped.", "You should stay stopped and wait."])
        return pick(rng, ["You should slow down and stop.", "You should brake and stop."]) + " " + (
            pick(rng, STOP_SENTENCES[stop_kind(decision)]))
    if speed < CRUISE_SPEED - 1.5:
        return pick(rng, ["You should accelerate and follow the lane.", "You should speed up and keep the lane."])
    return pick(rng, ["You should maintain your current speed and follow the lane.",
                      "You should keep your speed and lane follow."])
