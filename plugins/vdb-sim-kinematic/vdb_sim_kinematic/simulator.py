"""The kinematic simulator: a kinematic bicycle ego in a world of scripted road users, seen by a camera.

Each step (dt = 0.1 s):

1. the ego moves under the control (bicycle model of :func:`vladrivebench.world.apply_control`, or placed at
   ``control.next_state`` for MPC-style controllers);
2. road users whose trigger the ego has reached start moving; each moves unless that would put it inside
   the ego's box (road users do not walk into a car; a collision is always the ego's doing): the
   scenario's scripts, :mod:`vladrivebench.world._motion`;
3. the ego's box is tested against every road user's box (separating axes): any overlap is a collision
   and ends the episode;
4. the shared :class:`~vladrivebench.world._truth.TruthTracker` computes the ground truth, violations and
   the terminal state; the camera rig renders its images (on the steps of its frame rate) and keeps the
   frame and pose history (:class:`vladrivebench.world.RigRecorder`).

Seeds: the only thing a seed changes is the along-route start position of pedestrians and animals,
shifted uniformly within ±``position_jitter`` metres (default 0.2 m, small enough to keep every crossing
scenario's outcome; :func:`vladrivebench.world._motion.scripted_users`); cars, lights and signs never move.
``position_jitter=0`` makes every seed identical.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

from vladrivebench import Control, Observation, Scenario
from vladrivebench.world import (
    DT,
    WORLD_FEATURES,
    RigRecorder,
    RoadGeometry,
    TruthTracker,
    apply_control,
    build_road,
    check_history_options,
    check_supported,
    colliding,
    ego_at_start,
    rig_from_options,
    route_text,
    scripted_users,
)

SUPPORTED_FEATURES = WORLD_FEATURES
"""Every scenario feature (see :meth:`Scenario.features`) this simulator represents: the shared world's."""

SHARED_ROADS = 32
"""How many road geometries the simulators of one process share (least recently used dropped first)."""
_shared_roads: OrderedDict[tuple[str, str], RoadGeometry] = OrderedDict()
_shared_roads_lock = threading.Lock()  # the pipelined executor steps batch jobs on threads


def shared_road(scenario: Scenario) -> RoadGeometry:
    """The road of ``scenario``, built once per process: a road depends on the scenario alone and is never
    changed, so the simulators of a lockstep batch (one per episode) share it, and with it the camera's
    per-road scenery."""
    key = (scenario.id, repr(scenario.to_json()))
    with _shared_roads_lock:
        road = _shared_roads.pop(key, None) or build_road(scenario)
        _shared_roads[key] = road  # the most recently used last
        while len(_shared_roads) > SHARED_ROADS:
            _shared_roads.popitem(last=False)
        return road


class KinematicSimulator:
    """A numpy-only closed-loop world at 10 Hz.

    Camera options: ``rig`` (``front``, the default single front camera, or ``alpamayo``, four cameras:
    :data:`vladrivebench.world.RIG_PRESETS`), ``cameras`` (some of the rig's cameras, comma-separated),
    ``width`` × ``height`` of every camera image (pixels; default: the rig's own, 160×80 for ``front``),
    ``frames`` (past frames kept per camera, 1–16) taken at ``frame_rate_hz`` (10 Hz divided by a whole
    number), ``poses`` (past ego states kept, 0–100), ``render`` (False returns blank images, for fast
    runs of models that read only the ground truth); for the ``front`` rig ``hfov_deg``,
    ``camera_height`` (m) and ``pitch_deg`` (downward tilt). ``position_jitter`` (m, see the module
    docstring).
    """

    dt = DT

    def __init__(self, width: int | None = None, height: int | None = None, render: bool = True,
                 hfov_deg: float = 90.0, camera_height: float = 1.6, pitch_deg: float = 0.0,
                 position_jitter: float = 0.2, rig: str = "front", cameras: str | None = None, frames: int = 1,
                 frame_rate_hz: float = 10.0, poses: int = 16):
        specs = rig_from_options("kinematic", locals())
        stride = check_history_options("kinematic", locals(), self.dt)
        self.render = render
        self.position_jitter = float(position_jitter)
        self.rig = RigRecorder(specs, frames, stride, poses, render)
        self.camera = self.rig.main
        self.scenario: Scenario | None = None
        self._terminal: str | None = None

    # -- protocol -----------------------------------------------------------------------------------
    def reset(self, scenario: Scenario, seed: int) -> Observation:
        """Start an episode of ``scenario``; ``seed`` only jitters pedestrian/animal start positions."""
        check_supported(scenario, "kinematic", SUPPORTED_FEATURES)
        self.scenario = scenario
        self.road = shared_road(scenario)
        self.users = scripted_users(scenario, seed, self.position_jitter)
        self.ego = ego_at_start(self.road.route, scenario.ego.speed)
        crossing = {user.spec.id: user.s for user in self.users if user.spec.motion == "cross"}
        self.truth = TruthTracker(scenario, self.road, crossing)
        self.step_index = 0
        self._terminal = None
        self.rig.reset()
        return self._observe(collisions=())

    def step(self, control: Control) -> Observation:
        """Advance one step (see the module docstring for the order of events)."""
        if self.scenario is None:
            raise RuntimeError("KinematicSimulator.step() called before reset()")
        if self._terminal is not None:
            raise RuntimeError(f"the episode has ended ({self._terminal}); call reset() to start another")
        self.ego = apply_control(self.ego, control, self.dt)
        self._move_users()
        self.step_index += 1
        actors = self._actors()
        return self._observe(colliding(self.ego, actors), actors)

    def close(self) -> None:
        """Nothing to release: the roads are shared by the process's simulators (:func:`shared_road`)."""

    # -- internals ----------------------------------------------------------------------------------
    def _actors(self):
        route = self.road.route
        return tuple(user.actor(route) for user in self.users)

    def _move_users(self) -> None:
        front = self.truth.ego_s(self.ego) + self.ego.length / 2
        for user in self.users:
            user.check_trigger(front)
            user.advance(self.road.route, self.ego, self.dt)

    def _observe(self, collisions: tuple[str, ...], actors: tuple | None = None) -> Observation:
        """The observation of the current state; ``actors``: the road users as actors, when already made."""
        actors = self._actors() if actors is None else actors
        truth = self.truth.observe(self.step_index, self.ego, actors, collisions)
        self._terminal = truth.terminal
        image, cameras, poses = self.rig.observe(self.step_index, truth.time, self.ego, self.road, truth.actors)
        return Observation(
            step=self.step_index,
            time=truth.time,
            image=image,
            ego=self.ego,
            command=self.scenario.command,
            ground_truth=truth,
            scenario_id=self.scenario.id,
            cameras=cameras,
            pose_history=poses,
            route_text=route_text(self.scenario.command, truth.route_progress, truth.route_length,
                                  self.road.junction_span),
        )
