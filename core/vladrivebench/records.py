"""Frozen records that flow between simulators, models, controllers, labelers and metrics.

Frames and units: world frame x east, y north, yaw counter-clockwise from +x (radians); the ego frame has
x forward and y to the left. Distances in metres, speeds in m/s, times in seconds.
Records are plain frozen dataclasses so that they pickle (process pools) and serialise (episode logs).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is imported where it is used: `vdb list-plugins` imports records
    import numpy as np

ACTOR_KINDS = ("pedestrian", "car", "animal", "traffic_light", "stop_sign")
LIGHT_COLOURS = ("red", "yellow", "green")
NAV_COMMANDS = ("follow_lane", "straight", "left", "right")
STATED_ACTIONS = ("maintaining", "accelerating", "decelerating", "keep_distance", "none")


class _LoggedKeys:
    """Deprecated read access by logged key, for code written when episode steps held JSON dicts.

    ``record["x"]`` and ``record.get("x", default)`` return the field's value in the form the episode
    log holds it (records as dicts, tuples and arrays as lists). New code reads attributes
    (``record.x``); this shim goes once no reader in the project uses keys.
    """

    __slots__ = ()

    def __getitem__(self, key: str) -> Any:
        if not isinstance(key, str) or key not in {f.name for f in fields(self)}:
            raise KeyError(key)
        return _logged_form(getattr(self, key))

    def get(self, key: str, default: Any = None) -> Any:
        try:
            return self[key]
        except KeyError:
            return default


def _logged_form(value: Any) -> Any:
    if hasattr(value, "__dataclass_fields__") and not isinstance(value, type):
        return {f.name: _logged_form(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, (list, tuple)):
        return [_logged_form(v) for v in value]
    if isinstance(value, dict):
        return {k: _logged_form(v) for k, v in value.items()}
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return value.tolist()
    return value


@dataclass(frozen=True)
class EgoState(_LoggedKeys):
    """The ego vehicle's pose and motion in the world frame."""

    x: float
    y: float
    yaw: float
    speed: float
    steer: float = 0.0
    length: float = 4.7
    width: float = 1.9

    def to_ego_frame(self, wx: float, wy: float) -> tuple[float, float]:
        """World point → ego frame (x forward, y left)."""
        dx, dy = wx - self.x, wy - self.y
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return c * dx + s * dy, -s * dx + c * dy

    def to_world_frame(self, ex: float, ey: float) -> tuple[float, float]:
        """Ego-frame point → world frame."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.x + c * ex - s * ey, self.y + s * ex + c * ey


@dataclass(frozen=True)
class Actor(_LoggedKeys):
    """One thing in the world the ego must reason about: a road user or a road feature.

    ``kind`` is one of :data:`ACTOR_KINDS`. ``state`` holds the light colour for a traffic light and is
    ``None`` otherwise. ``length`` is along the actor's heading, ``width`` across it.
    """

    actor_id: str
    kind: str
    x: float
    y: float
    yaw: float = 0.0
    length: float = 0.5
    width: float = 0.5
    height: float = 1.7
    speed: float = 0.0
    state: str | None = None


@dataclass(frozen=True)
class GroundTruth(_LoggedKeys):
    """What was true at one step: everything the labelers and quality metrics compare a CoT against.

    ``distance_to_critical`` is measured along the route from the ego's position to the critical feature
    (positive ahead, negative once passed); it defines the distance zones (far > 20 m, med 10–20 m,
    near < 10 m, past < 0). ``lead_gap``/``lead_speed`` describe the nearest actor ahead in the ego's lane,
    for time-to-collision. ``collisions`` and ``violations`` list the events of this step only;
    ``terminal`` is set on the last step of an episode (``route_complete``, ``collision``, ``timeout``).
    ``route_ahead`` is the centre line of the ego's lane along the route ahead, as ego-frame points every
    metre up to 50 m (privileged: for expert drivers and the scripted model).
    """

    step: int
    time: float
    actors: tuple[Actor, ...] = ()
    critical_id: str | None = None
    critical_kind: str | None = None
    distance_to_critical: float | None = None
    blocking: bool = False
    light_state: str | None = None
    lead_gap: float | None = None
    lead_speed: float | None = None
    route_progress: float = 0.0
    route_length: float = 0.0
    collisions: tuple[str, ...] = ()
    violations: tuple[str, ...] = ()
    terminal: str | None = None
    route_ahead: tuple[tuple[float, float], ...] = ()

    def actor(self, actor_id: str) -> Actor | None:
        return next((a for a in self.actors if a.actor_id == actor_id), None)

    def critical(self) -> Actor | None:
        return self.actor(self.critical_id) if self.critical_id else None


@dataclass(frozen=True)
class CameraSpec:
    """One camera of a rig: its name, image size, pinhole intrinsics and mounting on the ego.

    ``width`` × ``height`` pixels with horizontal field of view ``hfov_deg`` (square pixels, principal
    point at the image centre). Mounting in the ego frame: ``x`` forward and ``y`` left of the ego's
    centre, ``z`` above the ground (metres); ``yaw_deg`` turns the camera to the left (90 looks left),
    ``pitch_deg`` tilts it down. Pixel ``(u, v)`` sees the ray through ``(u + 0.5, v + 0.5)``.
    """

    name: str
    width: int
    height: int
    hfov_deg: float = 90.0
    x: float = 0.8
    y: float = 0.0
    z: float = 1.6
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0

    @property
    def focal(self) -> float:
        """The focal length in pixels."""
        return (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def intrinsics(self) -> tuple[tuple[float, float, float], ...]:
        """The 3×3 pinhole matrix K: ``(u, v, 1) ∝ K @ (right, down, depth)`` in the camera frame."""
        f = self.focal
        return ((f, 0.0, self.width / 2), (0.0, f, self.height / 2), (0.0, 0.0, 1.0))

    @property
    def extrinsics(self) -> tuple[tuple[float, float, float, float], ...]:
        """The 4×4 camera → ego transform. Camera frame: x right, y down, z along the optical axis (the
        OpenCV convention); ego frame: x forward, y left, z up, origin on the ground under the centre."""
        yaw, pitch = math.radians(self.yaw_deg), math.radians(self.pitch_deg)
        cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
        right = (sy, -cy, 0.0)
        down = (-sp * cy, -sp * sy, -cp)
        axis = (cp * cy, cp * sy, -sp)
        origin = (self.x, self.y, self.z)
        return tuple((right[i], down[i], axis[i], origin[i]) for i in range(3)) + ((0.0, 0.0, 0.0, 1.0),)


@dataclass(frozen=True)
class CameraView:
    """A window of one camera's past frames: ``frames`` oldest → newest, each ``(height, width, 3)`` uint8
    (read-only when shared with other steps' observations), taken at simulated ``times`` (seconds, increasing). Early in an episode the window
    holds fewer frames than requested; the newest frame may be older than the observation when the rig's
    frame rate is below the simulator's step rate."""

    spec: CameraSpec
    frames: tuple[np.ndarray, ...] = field(repr=False, compare=False)
    times: tuple[float, ...] = ()

    @property
    def latest(self) -> np.ndarray:
        """The newest frame."""
        return self.frames[-1]


@dataclass(frozen=True)
class PoseHistory:
    """The ego's past states, oldest → newest (the newest is the observation's own ``ego``), at ``times``."""

    times: tuple[float, ...] = ()
    states: tuple[EgoState, ...] = ()

    def in_ego_frame(self) -> tuple[tuple[float, float, float], ...]:
        """Every state as ``(x, y, yaw)`` in the ego frame of the newest state (the newest is ``(0, 0, 0)``)."""
        if not self.states:
            return ()
        now = self.states[-1]
        return tuple((*now.to_ego_frame(s.x, s.y), math.remainder(s.yaw - now.yaw, 2 * math.pi))
                     for s in self.states)


@dataclass(frozen=True)
class Observation:
    """What a model is given at one step.

    ``image`` is the front camera, ``(H, W, 3)`` uint8 (the newest frame of the rig's first camera).
    ``cameras`` maps each camera's name to its :class:`CameraView` (empty when the simulator has no rig;
    :meth:`camera_views` then makes a front view of ``image``). ``pose_history`` holds the ego's past
    states and ``route_text`` a navigation instruction in words (``""`` if none). ``ground_truth`` is
    privileged information: the scripted reference model reads it as its "perception"; a real VLA
    adapter must not. Images never take part in comparisons or the repr.

    ``episode`` names the episode the observation belongs to. The runner sets it (a simulator leaves it
    ``""``): it is the same at every step of an episode and differs between the episodes one model
    instance serves at once, so a model that keeps memory while serving a lockstep batch keys that
    memory by it (:class:`~vladrivebench.EpisodeMemory`). It is never logged and takes no part in
    comparisons.
    """

    step: int
    time: float
    image: np.ndarray = field(repr=False, compare=False)
    ego: EgoState
    command: str
    ground_truth: GroundTruth
    scenario_id: str = ""
    cameras: Mapping[str, CameraView] = field(default_factory=dict, repr=False, compare=False)
    pose_history: PoseHistory = field(default_factory=PoseHistory, repr=False)
    route_text: str = ""
    episode: str = field(default="", compare=False, repr=False)

    def camera_views(self) -> Mapping[str, CameraView]:
        """``cameras``, or, when it is empty, one view ``"front"`` holding ``image`` (90° field of view)."""
        if self.cameras:
            return self.cameras
        height, width = self.image.shape[:2]
        return {"front": CameraView(CameraSpec("front", int(width), int(height)), (self.image,), (self.time,))}


@dataclass(frozen=True)
class CoTFormat:
    """How a model writes its chain-of-thought.

    ``kind`` is ``"sentence"`` (one free text, like Alpamayo) or ``"slots"`` (one text per named round,
    like ORION's scene / objects / decision). ``max_tokens`` is the longest text the model can take.
    """

    kind: str = "sentence"
    slots: tuple[str, ...] = ()
    max_tokens: int | None = None

    @property
    def is_slotted(self) -> bool:
        return self.kind == "slots"


@dataclass(frozen=True)
class TrajectorySpec:
    """The horizon (s) and rate (Hz) of the trajectories a model returns."""

    horizon_s: float = 3.0
    rate_hz: float = 10.0


@dataclass(frozen=True)
class CoT(_LoggedKeys):
    """A chain-of-thought: its text, its named slots (multi-round formats) and the model's own state.

    ``text`` is the whole CoT as one string (slots joined in order for slotted formats). ``state`` is opaque
    to the benchmark (a KV cache, a hidden state, a dict of internals); it is never compared nor logged.
    ``spliced`` says whether the text was injected rather than generated.
    """

    text: str
    slots: dict[str, str] = field(default_factory=dict)
    state: Any = field(default=None, repr=False, compare=False)
    spliced: bool = False

    @staticmethod
    def join_slots(slots: dict[str, str]) -> str:
        return " ".join(slots[name] for name in slots)


@dataclass(frozen=True, eq=False)
class Trajectory(_LoggedKeys):
    """Timed waypoints in the ego frame at the moment of prediction.

    ``times`` has shape ``(T,)`` strictly increasing and positive (seconds ahead); ``xy`` has shape
    ``(T, 2)``: x forward, y left, with the ego at the origin at time 0.
    """

    times: np.ndarray
    xy: np.ndarray

    def __eq__(self, other: object) -> bool:
        """Equal when both arrays have the same shapes and values (arrays make field-wise ``==`` ambiguous)."""
        if not isinstance(other, Trajectory):
            return NotImplemented
        import numpy as np

        return bool(np.array_equal(self.times, other.times) and np.array_equal(self.xy, other.xy))

    def problems(self) -> str | None:
        """Why this trajectory cannot be used, or ``None`` when it is well formed."""
        import numpy as np

        times, xy = np.asarray(self.times), np.asarray(self.xy)
        if times.ndim != 1 or len(times) == 0:
            return f"times must have shape (T,) with T > 0, got {times.shape}"
        if xy.shape != (len(times), 2):
            return f"xy must have shape ({len(times)}, 2), got {xy.shape}"
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(xy))):
            return "contains NaN or infinite values"
        if times[0] <= 0 or np.any(np.diff(times) <= 0):
            return "times must be positive and strictly increasing"
        return None

    def forward_displacement(self, horizon_s: float) -> float:
        """Forward (ego-x) displacement predicted at ``horizon_s``, linearly interpolated from t = 0."""
        import numpy as np

        t = np.concatenate([[0.0], np.asarray(self.times, dtype=float)])
        x = np.concatenate([[0.0], np.asarray(self.xy, dtype=float)[:, 0]])
        return float(np.interp(horizon_s, t, x))

    def path_length(self, horizon_s: float) -> float:
        """Distance travelled along the waypoints up to ``horizon_s``."""
        import numpy as np

        t = np.concatenate([[0.0], np.asarray(self.times, dtype=float)])
        pts = np.vstack([[0.0, 0.0], np.asarray(self.xy, dtype=float)])
        keep = t <= horizon_s + 1e-9
        seg = np.diff(pts[keep], axis=0)
        return float(np.sum(np.hypot(seg[:, 0], seg[:, 1])))

    def to_json(self) -> dict[str, list]:
        import numpy as np

        return {"times": np.asarray(self.times).tolist(), "xy": np.asarray(self.xy).tolist()}


@dataclass(frozen=True)
class Control(_LoggedKeys):
    """A controller's output for one step.

    PID-style controllers set ``throttle``/``steer``/``brake`` (the simulator integrates them through the
    bicycle model); MPC-style controllers also set ``next_state`` and the simulator places the ego there.
    ``v_des`` is the desired speed commanded for the next step, which action alignment compares with v.
    """

    throttle: float
    steer: float
    brake: float
    v_des: float
    next_state: EgoState | None = None

    @property
    def braking(self) -> bool:
        return self.brake > 0.0


@dataclass(frozen=True)
class LabelInput:
    """One CoT to label, with the ground-truth context the labeler may compare it against.

    ``context`` carries the step's ground truth in JSON form: ``critical_kind``, ``critical_position``
    (ego frame, metres), ``light_state``, ``actors`` (kind + ego-frame position), ``ego_speed``.
    """

    text: str
    slots: dict[str, str] = field(default_factory=dict)
    context: dict[str, Any] = field(default_factory=dict)
    key: str = ""


@dataclass(frozen=True)
class Labels:
    """The labels extracted from one CoT (Section 3.3 of the paper plus contradiction).

    ``stated_action`` is one of :data:`STATED_ACTIONS`; ``target_mentioned`` is ``None`` when the step has
    no critical feature; ``light_colour`` is the colour the CoT states (``None`` if it states none).
    ``unlabelled`` holds a reason when the labeler could not produce labels; then the rest is meaningless.
    """

    stated_action: str = "none"
    target_mentioned: bool | None = None
    mention_slot: str | None = None
    light_colour: str | None = None
    hallucination: bool = False
    contradiction: bool = False
    details: dict[str, Any] = field(default_factory=dict)
    labeler: str = ""
    version: str = ""
    unlabelled: str | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)
