"""The kinematic simulator: a kinematic bicycle ego in a world of scripted road users, seen by a camera.

Each step (dt = 0.1 s):

1. the ego moves under the control (bicycle model of :mod:`vladrivebench.world.bicycle`, or placed at
   ``control.next_state`` for MPC-style controllers);
2. road users whose trigger the ego has reached start moving; each moves unless that would put it inside
   the ego's box (road users do not walk into a car; a collision is always the ego's doing);
3. the ego's box is tested against every road user's box (separating axes): any overlap is a collision
   and ends the episode;
4. the shared :class:`~vladrivebench.world.truth.TruthTracker` computes the ground truth, violations and
   the terminal state; the camera renders the image.

Seeds: the only thing a seed changes is the along-route start position of pedestrians and animals,
shifted uniformly within ±``position_jitter`` metres (default 0.2 m, small enough to keep every crossing
scenario's outcome); cars, lights and signs never move. ``position_jitter=0`` makes every seed identical.
"""

from __future__ import annotations

import numpy as np
from vladrivebench.errors import ScenarioError
from vladrivebench.records import Control, EgoState, Observation
from vladrivebench.rng import episode_rng
from vladrivebench.scenarios import Scenario
from vladrivebench.world import bicycle
from vladrivebench.world.boxes import Box, colliding, overlap
from vladrivebench.world.camera import Camera
from vladrivebench.world.roads import RoadGeometry, build_road
from vladrivebench.world.truth import TruthTracker

from .motion import RoadUser

SUPPORTED_FEATURES = frozenset(
    {f"layout:{name}" for name in ("straight", "t_junction", "four_way")}
    | {f"scenery:{name}" for name in ("plain", "suburban", "urban")}
    | {f"lanes:{n}" for n in (1, 2, 3, 4)}
    | {f"actor:{kind}" for kind in ("pedestrian", "car", "animal")}
    | {f"motion:{kind}" for kind in ("static", "along", "cross")}
    | {f"traffic_light:{colour}" for colour in ("red", "yellow", "green")}
    | {"stop_sign"}
)
"""Every scenario feature (see :meth:`Scenario.features`) this simulator represents."""
JITTERED_KINDS = ("pedestrian", "animal")


class KinematicSimulator:
    """A numpy-only closed-loop world at 10 Hz.

    Options: ``width`` × ``height`` of the camera image (pixels), ``render`` (False returns a blank image,
    for fast runs of models that read only the ground truth), ``hfov_deg``, ``camera_height`` (m),
    ``pitch_deg`` (downward tilt) and ``position_jitter`` (m, see the module docstring).
    """

    dt = bicycle.DT

    def __init__(self, width: int = 160, height: int = 80, render: bool = True, hfov_deg: float = 90.0,
                 camera_height: float = 1.6, pitch_deg: float = 0.0, position_jitter: float = 0.2):
        from vladrivebench.errors import ConfigError

        for name, value, low, high in (("width", width, 8, 4096), ("height", height, 8, 4096)):
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ConfigError(f"simulator 'kinematic': option {name} must be a whole number between "
                                  f"{low} and {high}, got {value!r}")
        if not isinstance(render, bool):
            raise ConfigError(f"simulator 'kinematic': option render must be true or false, got {render!r}")
        checks = (("hfov_deg", hfov_deg, 10.0, 170.0), ("camera_height", camera_height, 0.2, 10.0),
                  ("pitch_deg", pitch_deg, -30.0, 60.0), ("position_jitter", position_jitter, 0.0, 2.0))
        for name, value, low, high in checks:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise ConfigError(f"simulator 'kinematic': option {name} must be a number between "
                                  f"{low:g} and {high:g}, got {value!r}")
        self.render = render
        self.position_jitter = float(position_jitter)
        self.camera = Camera(width, height, hfov_deg, mount_height=camera_height, pitch_deg=pitch_deg)
        self._blank = np.zeros((height, width, 3), dtype=np.uint8)
        self._blank.flags.writeable = False
        self._roads: dict[tuple[str, str], RoadGeometry] = {}
        self.scenario: Scenario | None = None
        self._terminal: str | None = None

    # -- protocol -----------------------------------------------------------------------------------
    def reset(self, scenario: Scenario, seed: int) -> Observation:
        """Start an episode of ``scenario``; ``seed`` only jitters pedestrian/animal start positions."""
        check_supported(scenario)
        self.scenario = scenario
        self.road = self._road(scenario)
        rng = episode_rng(seed, "simulator")
        self.users = []
        for spec in scenario.actors:
            shift = 0.0
            if spec.kind in JITTERED_KINDS and self.position_jitter > 0:
                shift = float(rng.uniform(-self.position_jitter, self.position_jitter))
            self.users.append(RoadUser.start(spec, shift))
        route = self.road.route
        x, y = (float(v) for v in route.position(0.0))
        self.ego = EgoState(x, y, float(route.heading(0.0)), scenario.ego.speed, 0.0,
                            bicycle.EGO_LENGTH, bicycle.EGO_WIDTH)
        crossing = {user.spec.id: user.s for user in self.users if user.spec.motion == "cross"}
        self.truth = TruthTracker(scenario, self.road, crossing)
        self.step_index = 0
        self._terminal = None
        return self._observe(collisions=())

    def step(self, control: Control) -> Observation:
        """Advance one step (see the module docstring for the order of events)."""
        if self.scenario is None:
            raise RuntimeError("KinematicSimulator.step() called before reset()")
        if self._terminal is not None:
            raise RuntimeError(f"the episode has ended ({self._terminal}); call reset() to start another")
        self.ego = bicycle.apply_control(self.ego, control, self.dt)
        self._move_users()
        self.step_index += 1
        collisions = colliding(self.ego, self._actors())
        return self._observe(collisions)

    def close(self) -> None:
        self._roads.clear()

    # -- internals ----------------------------------------------------------------------------------
    def _road(self, scenario: Scenario) -> RoadGeometry:
        key = (scenario.id, repr(scenario.to_json()))
        if key not in self._roads:
            self._roads[key] = build_road(scenario)
        return self._roads[key]

    def _actors(self):
        route = self.road.route
        return tuple(user.actor(route) for user in self.users)

    def _move_users(self) -> None:
        front = self.truth.ego_s(self.ego) + self.ego.length / 2
        ego_box = Box.of_ego(self.ego)
        route = self.road.route
        for user in self.users:
            user.update_trigger(front)
            s, offset, speed = user.proposed(self.dt)
            if (s, offset) == (user.s, user.offset):
                user.speed = 0.0
                continue
            moved = Box.of_actor(user.actor(route, s, offset, speed))
            if overlap(ego_box, moved) and not overlap(ego_box, Box.of_actor(user.actor(route))):
                user.speed = 0.0  # waits for the ego rather than walking into it
                continue
            user.s, user.offset, user.speed = s, offset, speed

    def _observe(self, collisions: tuple[str, ...]) -> Observation:
        actors = self._actors()
        truth = self.truth.observe(self.step_index, self.ego, actors, collisions)
        self._terminal = truth.terminal
        if self.render:
            image = self.camera.render(self.road, self.ego, truth.actors)
        else:
            image = self._blank
        return Observation(
            step=self.step_index,
            time=truth.time,
            image=image,
            ego=self.ego,
            command=self.scenario.command,
            ground_truth=truth,
            scenario_id=self.scenario.id,
        )


def check_supported(scenario: Scenario, simulator: str = "kinematic",
                    supported: frozenset[str] = SUPPORTED_FEATURES) -> None:
    """Raise a one-line :class:`ScenarioError` if the scenario needs a feature the simulator lacks."""
    missing = sorted(scenario.features() - supported)
    if missing:
        where = scenario.source or scenario.id
        raise ScenarioError(
            f"scenario {where}: simulator {simulator!r} cannot represent {missing[0]!r} "
            f"(it supports: {', '.join(sorted(supported))})"
        )
