"""A camera rig with history: named cameras, a window of past frames per camera, past ego poses, a route text.

A rig is a tuple of :class:`~vladrivebench.records.CameraSpec` (:data:`RIG_PRESETS` names the built-in ones:
``front``, the single front camera every simulator had before rigs, and ``alpamayo``, the four-camera layout
of NVIDIA's Alpamayo models). A simulator builds its rig from its options with :func:`rig_from_options` and
:func:`check_history_options`, keeps a :class:`RigRecorder` and calls :meth:`RigRecorder.observe` once per
step; the recorder renders every camera only on the steps of the frames' rate (a multiple of the step
period, counted from the episode's first step) and reuses the frames in between.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from vladrivebench.errors import ConfigError
from vladrivebench.records import Actor, CameraSpec, CameraView, EgoState, PoseHistory
from vladrivebench.world._bicycle import DT
from vladrivebench.world._camera import Camera
from vladrivebench.world._motion import blank_image, check_view_options, option_error
from vladrivebench.world._roads import RoadGeometry


@dataclass(frozen=True)
class CameraRig:
    """A named set of cameras; the first is the rig's main camera (its newest frame is ``Observation.image``)."""

    name: str
    cameras: tuple[CameraSpec, ...]
    description: str = ""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(spec.name for spec in self.cameras)


FRONT_RIG = CameraRig("front", (CameraSpec("front", 160, 80, 90.0, x=0.8, y=0.0, z=1.6),),
                      "one front camera, 160×80, 90° (the default)")
ALPAMAYO_RIG = CameraRig("alpamayo", (
    CameraSpec("front_wide", 576, 320, 120.0, x=1.7, y=0.0, z=1.5),
    CameraSpec("front_tele", 576, 320, 30.0, x=1.7, y=0.0, z=1.5),
    CameraSpec("cross_left", 576, 320, 120.0, x=2.0, y=0.85, z=1.0, yaw_deg=90.0),
    CameraSpec("cross_right", 576, 320, 120.0, x=2.0, y=-0.85, z=1.0, yaw_deg=-90.0),
), "Alpamayo's four cameras (front wide 120°, front tele 30°, cross left/right 120° looking sideways), "
   "576×320; mounting positions are plausible, not calibrated")
RIG_PRESETS: Mapping[str, CameraRig] = {rig.name: rig for rig in (FRONT_RIG, ALPAMAYO_RIG)}
"""The rigs a simulator knows by name (``--sim-opt rig=NAME``)."""

MAX_FRAMES = 16
MAX_POSES = 100
MAX_STRIDE = 100
FRONT_ONLY_OPTIONS = (("hfov_deg", 90.0), ("camera_height", 1.6), ("pitch_deg", 0.0))
"""Options (and their defaults) that shape the ``front`` rig's camera; other rigs fix their own."""


def rig_from_options(simulator: str, values: Mapping[str, Any]) -> tuple[CameraSpec, ...]:
    """The cameras the options ``rig``, ``cameras``, ``width``, ``height``, ``hfov_deg``, ``camera_height``,
    ``pitch_deg`` (and ``render``, ``position_jitter``, checked too) describe; a :class:`ConfigError` naming
    the first bad option otherwise.

    ``cameras`` (a comma-separated string or a list of names, ``None`` for all) keeps some of the rig's
    cameras, in the order given; ``width``/``height`` (``None``: the rig's own) set every camera's size.
    """
    rig = values["rig"]
    if not isinstance(rig, str) or rig not in RIG_PRESETS:
        raise option_error(simulator, "rig", f"one of {', '.join(sorted(RIG_PRESETS))}", rig)
    preset = RIG_PRESETS[rig]
    specs = _select_cameras(simulator, preset, values["cameras"])
    first = specs[0]
    sized = {"width": first.width if values["width"] is None else values["width"],
             "height": first.height if values["height"] is None else values["height"]}
    check_view_options(simulator, {**values, **sized})
    if rig == "front":
        specs = tuple(replace(spec, hfov_deg=float(values["hfov_deg"]), z=float(values["camera_height"]),
                              pitch_deg=float(values["pitch_deg"])) for spec in specs)
    else:
        for name, default in FRONT_ONLY_OPTIONS:
            if values[name] != default:
                raise ConfigError(f"simulator {simulator!r}: option {name} applies to rig 'front' only, got "
                                  f"{values[name]!r} with rig {rig!r} (its cameras fix their own)")
    width, height = values["width"], values["height"]
    return tuple(replace(spec, width=spec.width if width is None else int(width),
                         height=spec.height if height is None else int(height)) for spec in specs)


def _select_cameras(simulator: str, rig: CameraRig, cameras: Any) -> tuple[CameraSpec, ...]:
    if cameras is None:
        return rig.cameras
    names = cameras.split(",") if isinstance(cameras, str) else cameras
    expected = f"camera names of rig {rig.name!r} ({', '.join(rig.names)}), comma-separated"
    if not isinstance(names, (list, tuple)) or not names:
        raise option_error(simulator, "cameras", expected, cameras)
    by_name = {spec.name: spec for spec in rig.cameras}
    chosen = []
    for name in names:
        if not isinstance(name, str) or name.strip() not in by_name or by_name[name.strip()] in chosen:
            raise option_error(simulator, "cameras", expected + ", each once", name)
        chosen.append(by_name[name.strip()])
    return tuple(chosen)


def check_history_options(simulator: str, values: Mapping[str, Any], dt: float = DT) -> int:
    """Check ``frames`` (1 to 16), ``frame_rate_hz`` (the step rate divided by a whole number) and
    ``poses`` (0 to 100); return the frame stride in steps. A :class:`ConfigError` for the first bad one."""
    frames, rate, poses = values["frames"], values["frame_rate_hz"], values["poses"]
    if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= MAX_FRAMES:
        raise option_error(simulator, "frames", f"a whole number between 1 and {MAX_FRAMES}", frames)
    step_rate = 1.0 / dt
    stride = _stride(rate, dt)
    if stride is None:
        raise option_error(simulator, "frame_rate_hz", f"{step_rate:g} Hz divided by a whole number from 1 to "
                           f"{MAX_STRIDE} (e.g. {step_rate:g}, {step_rate / 2:g}, {step_rate / 5:g})", rate)
    if isinstance(poses, bool) or not isinstance(poses, int) or not 0 <= poses <= MAX_POSES:
        raise option_error(simulator, "poses", f"a whole number between 0 and {MAX_POSES}", poses)
    return stride


def _stride(rate: Any, dt: float) -> int | None:
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
        return None
    steps = 1.0 / (rate * dt)
    stride = round(steps)
    return stride if 1 <= stride <= MAX_STRIDE and abs(steps - stride) < 1e-6 else None


class RigRecorder:
    """Renders a rig and keeps its history for one simulator.

    ``frames`` past frames per camera, one every ``stride`` steps (steps 0, stride, 2·stride, … of the
    episode; the views are reused unchanged on the steps between), and the last ``poses`` ego states
    (one per step, the current included). With ``render`` False every frame is a black image. Frames that
    several steps' observations share (``frames`` > 1 or ``stride`` > 1) are read-only.
    Call :meth:`reset` at the start of each episode and :meth:`observe` once per step.
    """

    def __init__(self, specs: Sequence[CameraSpec], frames: int = 1, stride: int = 1, poses: int = 16,
                 render: bool = True):
        self.specs = tuple(specs)
        self.cameras = {spec.name: Camera.from_spec(spec) for spec in self.specs} if render else {}
        self.blanks = {spec.name: blank_image(spec.width, spec.height) for spec in self.specs}
        self.frames, self.stride, self.render = int(frames), int(stride), bool(render)
        self._windows = {spec.name: deque(maxlen=self.frames) for spec in self.specs}
        self._poses: deque[tuple[float, EgoState]] = deque(maxlen=max(int(poses), 1))
        self._keep_poses = int(poses) > 0
        self._views: dict[str, CameraView] = {}

    @property
    def main(self) -> Camera | None:
        """The main (first) camera, ``None`` when not rendering."""
        return self.cameras.get(self.specs[0].name)

    def reset(self) -> None:
        for window in self._windows.values():
            window.clear()
        self._poses.clear()
        self._views = {}

    def observe(self, step: int, time: float, ego: EgoState, road: RoadGeometry,
                actors: Iterable[Actor]) -> tuple[np.ndarray, dict[str, CameraView], PoseHistory]:
        """The main image, every camera's view and the pose history at ``step`` (rendering if due)."""
        if self._keep_poses:
            self._poses.append((float(time), ego))
        if not self._views or step % self.stride == 0:
            actors = tuple(actors)
            for spec in self.specs:
                image = self._render(spec, ego, road, actors)
                self._windows[spec.name].append((float(time), image))
            self._views = {spec.name: _view(spec, self._windows[spec.name]) for spec in self.specs}
        poses = PoseHistory(tuple(t for t, _ in self._poses), tuple(s for _, s in self._poses)) \
            if self._keep_poses else PoseHistory()
        return self._views[self.specs[0].name].latest, dict(self._views), poses

    def _render(self, spec: CameraSpec, ego: EgoState, road: RoadGeometry, actors: tuple[Actor, ...]):
        if not self.render:
            return self.blanks[spec.name]
        image = self.cameras[spec.name].render(road, ego, actors)
        if self.frames > 1 or self.stride > 1:
            image.flags.writeable = False  # the frame is shared by the observations of several steps
        return image


def _view(spec: CameraSpec, window: deque) -> CameraView:
    return CameraView(spec, tuple(image for _, image in window), tuple(t for t, _ in window))


def route_text(command: str, progress: float, route_length: float,
               junction_span: tuple[float, float] | None = None) -> str:
    """A navigation instruction in words for the ego at ``progress`` metres along its route of
    ``route_length`` m; ``junction_span`` is where the route crosses a junction (``RoadGeometry.junction_span``,
    ``None`` without one), where ``command`` (``left``, ``right``, else straight on) applies."""
    remaining = max(route_length - progress, 0.0)
    if junction_span is not None and progress < junction_span[1]:
        manoeuvre = {"left": "turn left", "right": "turn right"}.get(command, "go straight")
        if progress < junction_span[0]:
            return f"In {junction_span[0] - progress:.0f} m, {manoeuvre} at the junction."
        return f"At the junction: {manoeuvre}."
    return f"Follow the road for {remaining:.0f} m to the end of the route."
