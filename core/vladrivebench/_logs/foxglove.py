"""Foxglove channels of an episode log: what a player (Foxglove, Lichtblick) draws of each step.

Next to the project's own channels every step gets, JSON-encoded with the JSON schemas below (written
for this project from the field names of Foxglove's published message schemas):

=========================  ========================  ===================================================
``/foxglove/tf``           ``foxglove.FrameTransforms``  ``world`` → ``ego`` (the ego pose) → ``front_camera``
                                                     (an optical frame: z forward, x right, y down)
``/foxglove/scene``        ``foxglove.SceneUpdate``  the road ahead (lane surface and centre line), the
                                                     ego and every actor as boxes coloured by kind (a
                                                     traffic light in its colour), labels, the light state
``/foxglove/trajectory``   ``foxglove.PosesInFrame``  the predicted waypoints in the ``ego`` frame
``/foxglove/cot``          ``foxglove.Log``          the chain-of-thought text (``name`` says whether it
                                                     was generated or injected)
``/camera``                ``foxglove.CompressedImage``  the front camera as PNG (only with ``log_images``)
=========================  ========================  ===================================================

Every scene update first deletes all entities, so actors that left the scene disappear.
``foxglove_layout.json`` beside this module is a layout showing these channels.
"""

from __future__ import annotations

import math
from typing import Any

from vladrivebench.records import CoT, Observation, Trajectory

TF_CHANNEL = "/foxglove/tf"
SCENE_CHANNEL = "/foxglove/scene"
TRAJECTORY_CHANNEL = "/foxglove/trajectory"
COT_CHANNEL = "/foxglove/cot"
CAMERA_CHANNEL = "/camera"
FOXGLOVE_CHANNELS = (TF_CHANNEL, SCENE_CHANNEL, TRAJECTORY_CHANNEL, COT_CHANNEL)

WORLD_FRAME, EGO_FRAME, CAMERA_FRAME = "world", "ego", "front_camera"
CAMERA_MOUNT = (1.5, 0.0, 1.4)  # metres ahead of and above the ego's reference point
_OPTICAL = {"x": -0.5, "y": 0.5, "z": -0.5, "w": 0.5}  # ego axes (x fwd, y left, z up) → optical (z fwd)
_LOG_INFO = 2
_DELETE_ALL = 1
_LINE_STRIP = 0
LANE_WIDTH = 3.5
ROAD_SAMPLE = 5  # every 5th point of route_ahead (one a metre): one every 5 m draws the lane well enough
EGO_HEIGHT = 1.5

_KIND_COLOURS = {
    "pedestrian": (1.0, 0.55, 0.0),
    "car": (0.2, 0.6, 1.0),
    "animal": (0.6, 0.4, 0.2),
    "stop_sign": (0.85, 0.0, 0.0),
    "traffic_light": (0.3, 0.3, 0.3),
}
_LIGHT_COLOURS = {"red": (1.0, 0.0, 0.0), "yellow": (1.0, 0.85, 0.0), "green": (0.0, 0.9, 0.2)}
_EGO_COLOUR = (0.1, 0.9, 0.9)

# -- JSON schemas (draft 2020-12 subset; every field of the Foxglove message is required) ----------------------
_TIME = {"type": "object", "title": "time", "required": ["sec", "nsec"],
         "properties": {"sec": {"type": "integer", "minimum": 0},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}
_DURATION = {"type": "object", "title": "duration", "required": ["sec", "nsec"],
             "properties": {"sec": {"type": "integer"},
                            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}


def _object(title: str, **properties: Any) -> dict[str, Any]:
    return {"type": "object", "title": title, "required": list(properties), "properties": properties}


_NUMBER = {"type": "number"}
_VECTOR3 = _object("foxglove.Vector3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
_POINT3 = _object("foxglove.Point3", x=_NUMBER, y=_NUMBER, z=_NUMBER)
_QUATERNION = _object("foxglove.Quaternion", x=_NUMBER, y=_NUMBER, z=_NUMBER, w=_NUMBER)
_POSE = _object("foxglove.Pose", position=_VECTOR3, orientation=_QUATERNION)
_COLOR = _object("foxglove.Color", **{c: {"type": "number", "minimum": 0, "maximum": 1} for c in "rgba"})
_CUBE = _object("foxglove.CubePrimitive", pose=_POSE, size=_VECTOR3, color=_COLOR)
_LINE = _object("foxglove.LinePrimitive", type={"type": "integer", "enum": [0, 1, 2]}, pose=_POSE,
                thickness={"type": "number", "minimum": 0}, scale_invariant={"type": "boolean"},
                points={"type": "array", "items": _POINT3}, color=_COLOR,
                colors={"type": "array", "items": _COLOR}, indices={"type": "array", "items": {"type": "integer"}})
_TEXT = _object("foxglove.TextPrimitive", pose=_POSE, billboard={"type": "boolean"},
                font_size={"type": "number"}, scale_invariant={"type": "boolean"}, color=_COLOR,
                text={"type": "string"})
_KEY_VALUE = _object("foxglove.KeyValuePair", key={"type": "string"}, value={"type": "string"})
_UNUSED = {"type": "array", "maxItems": 0}  # primitive kinds this project does not draw
_ENTITY = _object("foxglove.SceneEntity", timestamp=_TIME, frame_id={"type": "string"}, id={"type": "string"},
                  lifetime=_DURATION, frame_locked={"type": "boolean"},
                  metadata={"type": "array", "items": _KEY_VALUE}, arrows=_UNUSED,
                  cubes={"type": "array", "items": _CUBE}, spheres=_UNUSED, cylinders=_UNUSED,
                  lines={"type": "array", "items": _LINE}, triangles=_UNUSED,
                  texts={"type": "array", "items": _TEXT}, models=_UNUSED)
_DELETION = _object("foxglove.SceneEntityDeletion", timestamp=_TIME, type={"type": "integer", "enum": [0, 1]},
                    id={"type": "string"})
_TRANSFORM = _object("foxglove.FrameTransform", timestamp=_TIME, parent_frame_id={"type": "string"},
                     child_frame_id={"type": "string"}, translation=_VECTOR3, rotation=_QUATERNION)

SCHEMAS: dict[str, dict[str, Any]] = {
    TF_CHANNEL: _object("foxglove.FrameTransforms", transforms={"type": "array", "items": _TRANSFORM}),
    SCENE_CHANNEL: _object("foxglove.SceneUpdate", deletions={"type": "array", "items": _DELETION},
                           entities={"type": "array", "items": _ENTITY}),
    TRAJECTORY_CHANNEL: _object("foxglove.PosesInFrame", timestamp=_TIME, frame_id={"type": "string"},
                                poses={"type": "array", "items": _POSE}),
    COT_CHANNEL: _object("foxglove.Log", timestamp=_TIME,
                         level={"type": "integer", "enum": [0, 1, 2, 3, 4, 5]}, message={"type": "string"},
                         name={"type": "string"}, file={"type": "string"},
                         line={"type": "integer", "minimum": 0}),
    CAMERA_CHANNEL: _object("foxglove.CompressedImage", timestamp=_TIME, frame_id={"type": "string"},
                            data={"type": "string", "contentEncoding": "base64"},
                            format={"type": "string", "enum": ["png", "jpeg", "webp", "avif"]}),
}
for _topic, _schema in SCHEMAS.items():
    _schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"


# -- message builders -----------------------------------------------------------------------------------------
def stamp(time_ns: int) -> dict[str, int]:
    """A Foxglove ``time`` (``sec``, ``nsec``) from nanoseconds."""
    seconds, nanos = divmod(int(time_ns), 1_000_000_000)
    return {"sec": seconds, "nsec": nanos}


def _vector(x: float, y: float, z: float = 0.0) -> dict[str, float]:
    """A vector rounded to the millimetre: players need no more, and short numbers compress well."""
    return {"x": round(float(x), 3) + 0.0, "y": round(float(y), 3) + 0.0, "z": round(float(z), 3) + 0.0}


def _yaw_quaternion(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": round(math.sin(yaw / 2.0), 6) + 0.0, "w": round(math.cos(yaw / 2.0), 6) + 0.0}


def _pose(x: float, y: float, z: float, yaw: float) -> dict[str, Any]:
    return {"position": _vector(x, y, z), "orientation": _yaw_quaternion(yaw)}


def _colour(rgb: tuple[float, float, float], alpha: float = 1.0) -> dict[str, float]:
    return {"r": rgb[0], "g": rgb[1], "b": rgb[2], "a": alpha}


def frame_transforms(obs: Observation, time_ns: int) -> dict[str, Any]:
    """``world`` → ``ego`` at the ego's pose, ``ego`` → ``front_camera`` at the camera mount."""
    ego = obs.ego
    when = stamp(time_ns)
    return {"transforms": [
        {"timestamp": when, "parent_frame_id": WORLD_FRAME, "child_frame_id": EGO_FRAME,
         "translation": _vector(ego.x, ego.y), "rotation": _yaw_quaternion(ego.yaw)},
        {"timestamp": when, "parent_frame_id": EGO_FRAME, "child_frame_id": CAMERA_FRAME,
         "translation": _vector(*CAMERA_MOUNT), "rotation": dict(_OPTICAL)},
    ]}


def _entity(when: dict[str, int], entity_id: str, frame: str, *, cubes=(), lines=(), texts=(),
            metadata: dict[str, str] | None = None) -> dict[str, Any]:
    return {"timestamp": when, "frame_id": frame, "id": entity_id, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [{"key": k, "value": v} for k, v in (metadata or {}).items()],
            "arrows": [], "cubes": list(cubes), "spheres": [], "cylinders": [], "lines": list(lines),
            "triangles": [], "texts": list(texts), "models": []}


def _label(x: float, y: float, z: float, text: str) -> dict[str, Any]:
    return {"pose": _pose(x, y, z, 0.0), "billboard": True, "font_size": 14.0, "scale_invariant": True,
            "color": _colour((1.0, 1.0, 1.0)), "text": text}


def _box(x: float, y: float, yaw: float, length: float, width: float, height: float,
         rgb: tuple[float, float, float], alpha: float = 0.9) -> dict[str, Any]:
    return {"pose": _pose(x, y, height / 2.0, yaw), "size": _vector(length, width, height),
            "color": _colour(rgb, alpha)}


def _road_entity(obs: Observation, when: dict[str, int]) -> dict[str, Any] | None:
    """The lane ahead (route centre line, privileged) as a wide grey strip with a white centre line."""
    ahead = obs.ground_truth.route_ahead
    if len(ahead) < 2:
        return None
    sampled = list(ahead[::ROAD_SAMPLE]) + ([ahead[-1]] if (len(ahead) - 1) % ROAD_SAMPLE else [])
    ego = obs.ego
    c, s = math.cos(ego.yaw), math.sin(ego.yaw)  # EgoState.to_world_frame, its sine and cosine taken once
    points = [_vector(ego.x + c * ex - s * ey, ego.y + s * ex + c * ey, 0.0)
              for ex, ey in ((float(x), float(y)) for x, y in sampled)]
    line = {"type": _LINE_STRIP, "pose": _pose(0.0, 0.0, 0.0, 0.0), "scale_invariant": False, "colors": [],
            "indices": []}
    surface = {**line, "thickness": LANE_WIDTH, "points": points, "color": _colour((0.35, 0.35, 0.38), 0.8)}
    centre = {**line, "thickness": 0.15, "points": [{**p, "z": 0.02} for p in points],
              "color": _colour((1.0, 1.0, 1.0), 0.9)}
    return _entity(when, "road", WORLD_FRAME, lines=[surface, centre])


def scene_update(obs: Observation, time_ns: int) -> dict[str, Any]:
    """Every entity of one step: the road ahead, the ego, each actor (boxes and labels), the light state."""
    when, ego, truth = stamp(time_ns), obs.ego, obs.ground_truth
    entities = []
    road = _road_entity(obs, when)
    if road is not None:
        entities.append(road)
    ego_label = f"ego {ego.speed:.1f} m/s" + (f", light {truth.light_state}" if truth.light_state else "")
    entities.append(_entity(when, "ego", WORLD_FRAME,
                            cubes=[_box(ego.x, ego.y, ego.yaw, ego.length, ego.width, EGO_HEIGHT, _EGO_COLOUR)],
                            texts=[_label(ego.x, ego.y, EGO_HEIGHT + 1.0, ego_label)],
                            metadata={"light_state": str(truth.light_state or "none"),
                                      "critical": str(truth.critical_id or "none")}))
    for actor in truth.actors:
        rgb = _KIND_COLOURS.get(actor.kind, (0.8, 0.8, 0.8))
        if actor.kind == "traffic_light":
            rgb = _LIGHT_COLOURS.get(str(actor.state), rgb)
        critical = actor.actor_id == truth.critical_id
        text = f"{actor.kind} {actor.actor_id}" + (f" ({actor.state})" if actor.state else "") + \
            (" [critical]" if critical else "")
        entities.append(_entity(
            when, f"actor/{actor.actor_id}", WORLD_FRAME,
            cubes=[_box(actor.x, actor.y, actor.yaw, actor.length, actor.width, actor.height, rgb)],
            texts=[_label(actor.x, actor.y, actor.height + 0.8, text)],
            metadata={"kind": actor.kind, "state": str(actor.state or "none"), "critical": str(critical).lower()}))
    return {"deletions": [{"timestamp": when, "type": _DELETE_ALL, "id": ""}], "entities": entities}


def poses_in_frame(trajectory: Trajectory, time_ns: int) -> dict[str, Any]:
    """The predicted waypoints in the ``ego`` frame, each heading along the path to it (vectorised)."""
    import numpy as np

    xy = np.asarray(trajectory.xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1:] != (2,) or len(xy) == 0:
        return {"timestamp": stamp(time_ns), "frame_id": EGO_FRAME, "poses": []}
    step = np.diff(np.vstack([[0.0, 0.0], xy]), axis=0)
    heading = np.where(np.hypot(step[:, 0], step[:, 1]) > 0, np.arctan2(step[:, 1], step[:, 0]), 0.0)
    columns = (np.round(xy[:, 0], 3) + 0.0, np.round(xy[:, 1], 3) + 0.0,
               np.round(np.sin(heading / 2.0), 6) + 0.0, np.round(np.cos(heading / 2.0), 6) + 0.0)
    poses = [{"position": {"x": x, "y": y, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": qz, "w": qw}}
             for x, y, qz, qw in zip(*(c.tolist() for c in columns), strict=True)]
    return {"timestamp": stamp(time_ns), "frame_id": EGO_FRAME, "poses": poses}


def cot_log(cot: CoT, time_ns: int) -> dict[str, Any]:
    """The CoT as a log line; slotted CoTs list each slot; the name says generated or injected."""
    message = cot.text if not cot.slots else "\n".join(f"[{k}] {v}" for k, v in cot.slots.items())
    return {"timestamp": stamp(time_ns), "level": _LOG_INFO, "message": message,
            "name": "cot (injected)" if cot.spliced else "cot", "file": "", "line": 0}


def step_messages(obs: Observation, cot: CoT, trajectory: Trajectory, time_ns: int) -> dict[str, Any]:
    """The message of every Foxglove channel for one step (the camera is added by the writer)."""
    return {
        TF_CHANNEL: frame_transforms(obs, time_ns),
        SCENE_CHANNEL: scene_update(obs, time_ns),
        TRAJECTORY_CHANNEL: poses_in_frame(trajectory, time_ns),
        COT_CHANNEL: cot_log(cot, time_ns),
    }
