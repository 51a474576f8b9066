"""Sample inputs for plugin tests: realistic observations, label items, a tiny labelled episode directory.

:func:`observations` renders camera frames with a registered simulator when one is installed (large enough
for a real vision encoder: 224 pixels and more on the short side) and synthesises them deterministically
otherwise; :func:`label_items` gives CoTs with the ground-truth context a labeler reads; and
:func:`write_episode_dir` writes a few short episode logs with :class:`EpisodeWriter`, labelled with the
simple :class:`KeywordLabeler`, ready for :func:`~vladrivebench.testing.load_dataset` and a metric.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from vladrivebench.records import (
    Actor,
    Control,
    CoT,
    EgoState,
    GroundTruth,
    LabelInput,
    Labels,
    Observation,
    Trajectory,
)

__all__ = ["observations", "synthetic_observation", "label_items", "write_episode_dir", "KeywordLabeler",
           "SAMPLE_SCENARIO"]

SAMPLE_SCENARIO = "P.1"
"""The scenario :func:`observations` renders (a pedestrian in the lane); the suite's first one if missing."""

ROUTE = tuple((float(i), 0.0) for i in range(1, 51))
PEDESTRIAN_X = 30.0


# -- observations -----------------------------------------------------------------------------------------
def observations(count: int = 3, *, height: int = 224, width: int = 448, seed: int = 0, render: bool = True,
                 simulator: str | None = None, scenario: str = SAMPLE_SCENARIO) -> list[Observation]:
    """``count`` consecutive observations of an approach to a pedestrian, with ``height × width`` images.

    Rendered (driving at a steady throttle) by the registered simulator ``simulator`` — by default the one
    the installed plugins declare as the default simulator (``register_defaults``) — when it is installed
    and renders; synthesised by :func:`synthetic_observation` otherwise (``render=False`` forces that).
    """
    if count < 1 or height < 1 or width < 1:
        raise ValueError(f"observations needs count, height and width >= 1, got {count}, {height}, {width}")
    rendered = _rendered(count, height, width, seed, simulator, scenario) if render else None
    if rendered is not None:
        return rendered
    return [synthetic_observation(step, height=height, width=width, seed=seed) for step in range(count)]


def _rendered(count: int, height: int, width: int, seed: int, name: str | None,
              scenario_id: str) -> list[Observation] | None:
    """Frames from the registered simulator ``name`` (``None``: the declared default), or ``None`` (with a
    warning if it is installed but fails) so that the caller synthesises them instead."""
    import warnings

    from vladrivebench._engine.registry import Registry
    from vladrivebench.errors import VdbError

    registry = Registry(entry_points=True)
    if name is None:
        try:
            name = registry.default("simulator", "--sim").name
        except VdbError:  # none declared, or a tie: nothing to render with
            return None
    if name not in registry.names("simulator"):
        return None
    try:
        frames = _drive(registry, name, scenario_id, count, height, width, seed)
    except Exception as exc:  # noqa: BLE001 - a broken simulator plugin must not break other plugins' tests
        warnings.warn(f"vladrivebench.testing: simulator {name!r} could not render sample observations "
                      f"({type(exc).__name__}: {exc}); synthesising them instead", stacklevel=3)
        return None
    if len(frames) != count or frames[0].image.shape != (height, width, 3):
        return None
    return frames


def _drive(registry: Any, name: str, scenario_id: str, count: int, height: int, width: int,
           seed: int) -> list[Observation]:
    from vladrivebench._scenarios.spec import load_suite

    suite = load_suite(registry)
    if not suite:
        return []
    scenario = suite.get(scenario_id) or next(iter(suite.values()))
    sim = registry.create("simulator", name, {"width": width, "height": height})
    try:
        obs = sim.reset(scenario, seed)
        frames = [obs]
        while len(frames) < count and obs.ground_truth.terminal is None:
            obs = sim.step(Control(0.3, 0.0, 0.0, 6.0))
            frames.append(obs)
    finally:
        sim.close()
    return frames


def synthetic_observation(step: int = 0, *, height: int = 224, width: int = 448, seed: int = 0,
                          speed: float = 6.0) -> Observation:
    """A deterministic observation: the ego on a straight road, a pedestrian standing in the lane ahead.

    The image is a simple perspective drawing (sky, grass, grey road narrowing to the horizon, lane marks,
    the pedestrian as a dark upright box) plus sensor noise drawn from ``seed``; the same arguments give
    the same pixels.
    """
    x = step * speed * 0.1
    ego = EgoState(x, 0.0, 0.0, speed)
    distance = PEDESTRIAN_X - 0.25 - x - ego.length / 2
    pedestrian = Actor("ped", "pedestrian", PEDESTRIAN_X, 0.0)
    truth = GroundTruth(step=step, time=round(step * 0.1, 10), actors=(pedestrian,), critical_id="ped",
                        critical_kind="pedestrian", distance_to_critical=distance, blocking=True,
                        lead_gap=distance, lead_speed=0.0, route_progress=x, route_length=100.0, route_ahead=ROUTE)
    image = _draw(height, width, PEDESTRIAN_X - x, np.random.default_rng([seed, step]))
    return Observation(step, truth.time, image, ego, "follow_lane", truth, "synthetic")


def _draw(height: int, width: int, ahead: float, rng: np.random.Generator) -> np.ndarray:
    rows = np.arange(height, dtype=float)[:, None]
    cols = np.arange(width, dtype=float)[None, :]
    horizon = height * 0.45
    image = np.empty((height, width, 3), dtype=float)
    image[...] = (110.0, 150.0, 200.0)  # sky
    below = rows > horizon
    depth = np.where(below, (rows - horizon) / max(height - horizon, 1.0), 0.0)  # 0 at horizon → 1 at bottom
    half_road = 0.05 * width + 0.45 * width * depth
    centre = width / 2.0
    on_road = below & (np.abs(cols - centre) < half_road)
    image[np.broadcast_to(below, image.shape[:2])] = (70.0, 120.0, 60.0)  # grass
    image[on_road] = (95.0, 95.0, 95.0)
    marks = on_road & (np.abs(cols - centre) < 1.0 + 3.0 * depth) & (np.sin(40.0 / (depth + 0.05)) > 0)
    image[marks] = (230.0, 230.0, 230.0)
    if ahead > 1.0:
        focal = width / 2.0
        foot = horizon + focal * 1.6 / ahead
        top, half = foot - focal * 1.7 / ahead, max(1.0, focal * 0.25 / ahead)
        person = (rows >= max(top, 0)) & (rows <= min(foot, height - 1)) & (np.abs(cols - centre) <= half)
        image[person] = (40.0, 30.0, 90.0)
    image += rng.normal(0.0, 3.0, image.shape)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


# -- labeler inputs ---------------------------------------------------------------------------------------
def _context(kind: str | None, light: str | None = None, distance: float = 25.0) -> dict[str, Any]:
    actors = [] if kind is None else [{"id": "crit", "kind": kind, "position": [distance, 0.0], "speed": 0.0,
                                      "state": light}]
    return {"critical_kind": kind, "critical_position": None if kind is None else [distance, 0.0],
            "critical_speed": None if kind is None else 0.0, "distance_to_critical": None if kind is None else distance,
            "blocking": kind in ("pedestrian", "car"), "light_state": light, "actors": actors, "ego_speed": 6.0,
            "lead_gap": distance if kind in ("pedestrian", "car") else None,
            "lead_speed": 0.0 if kind in ("pedestrian", "car") else None}


_SENTENCES = (
    ("Stop for the pedestrian in the lane because it is blocking the lane.", "pedestrian", None),
    ("Maintain speed since the road ahead is clear.", None, None),
    ("Accelerate to maintain speed since the road ahead is clear and no obstacles are present.", None, None),
    ("Slow down because a car is parked in the lane and a cyclist is crossing.", "pedestrian", None),
    ("The light ahead is red, stop.", "traffic_light", "red"),
    ("The light ahead is green, keep going.", "traffic_light", "green"),
    ("Stop for the pedestrian and accelerate to pass it.", "pedestrian", None),
    ("Keep a safe distance from the stopped car ahead.", "car", None),
    ("Come to a stop at the stop sign.", "stop_sign", None),
    ("", None, None),
)
_SLOTS = (
    ({"scene": "A straight urban road.", "objects": "A pedestrian stands in the lane ahead.",
      "decision": "Decelerate and stop before the pedestrian."}, "pedestrian", None),
    ({"scene": "A junction with a traffic light.", "objects": "The light is red.", "decision": "Brake to a stop."},
     "traffic_light", "red"),
    ({"scene": "An empty road.", "objects": "Nothing ahead.", "decision": "Maintain speed."}, None, None),
)


def label_items() -> list[LabelInput]:
    """CoTs a labeler meets: sentences and slotted CoTs, with and without a critical feature, lights."""
    items = [LabelInput(text=text, context=_context(kind, light)) for text, kind, light in _SENTENCES]
    items += [LabelInput(text=CoT.join_slots(slots), slots=dict(slots), context=_context(kind, light))
              for slots, kind, light in _SLOTS]
    return items


# -- a tiny episode directory -----------------------------------------------------------------------------
class KeywordLabeler:
    """A deliberately simple labeler for fixtures: stated action and target mention from keywords."""

    version = "1"
    name = "keyword"

    _ACTIONS = (("keep_distance", ("keep a safe distance", "keep distance")),
                ("decelerating", ("stop", "brake", "slow", "decelerat", "yield")),
                ("accelerating", ("accelerat", "speed up")),
                ("maintaining", ("maintain", "keep going", "continue", "cruise")))

    _MENTIONS = {"traffic_light": ("light",), "stop_sign": ("stop sign",), "pedestrian": ("pedestrian", "person"),
                 "car": ("car", "vehicle"), "animal": ("animal", "dog", "deer")}

    def label(self, item: LabelInput) -> Labels:
        """Labels for one CoT, from lowercase keyword matches."""
        text = item.text.lower()
        action = next((a for a, words in self._ACTIONS if any(w in text for w in words)), "none")
        kind = item.context.get("critical_kind")
        mentioned = None if not kind else any(word in text for word in self._MENTIONS.get(kind, (kind,)))
        light = next((c for c in ("red", "yellow", "green") if c in text), None)
        return Labels(stated_action=action, target_mentioned=mentioned, light_colour=light,
                      labeler=self.name, version=self.version)

    def label_batch(self, items: Sequence[LabelInput]) -> list[Labels]:
        """:meth:`label` of each item, in order."""
        return [self.label(item) for item in items]


_SCENES = {
    # scenario id: (group, critical kind, light, CoT once noticed, CoT before)
    "P.1": ("Pedestrian (in-lane)", "pedestrian", None,
            "Stop for the pedestrian in the lane because it is blocking the lane.",
            "Maintain speed since the road ahead is clear."),
    "T.1": ("Traffic light (red)", "traffic_light", "red", "The light ahead is red, stop.",
            "Maintain speed since the road ahead is clear."),
}
_TRAJECTORY = Trajectory(np.array([0.5, 1.0, 1.5]), np.array([[3.0, 0.0], [6.0, 0.0], [9.0, 0.0]]))


def write_episode_dir(directory: Path | str, *, models: Sequence[str] = ("alpha", "beta"), seeds: int = 2,
                      steps: int = 60, label: bool = True) -> Path:
    """Write short episodes of ``models × seeds`` on a pedestrian approach (``P.1``) and a red light
    (``T.1``) into ``directory``, and label them.

    Each model notices the critical feature at a different distance (below it it says "Stop for the
    pedestrian …" / "The light ahead is red, stop." and slows down; above it "Maintain speed …"), so mention
    rates, light accuracy, alignment and distance zones all have data. With ``label`` the steps are
    labelled by :class:`KeywordLabeler` into the directory's label store ``keyword``. Returns ``directory``.
    """
    from vladrivebench._logs.episodes import EpisodeWriter

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for index, model in enumerate(models):
        for seed in range(seeds):
            notice = 12.0 + 8.0 * index + 2.0 * seed
            for scenario in _SCENES:
                path = directory / f"{model}__{scenario}__s{seed}.mcap"
                _write_episode(path, model, scenario, seed, notice, steps, EpisodeWriter)
    if label:
        _label_directory(directory)
    return directory


def _write_episode(path: Path, model: str, scenario: str, seed: int, notice: float, steps: int,
                   writer_class: Any) -> None:
    group, kind, light, noticed, before = _SCENES[scenario]
    meta = {"episode_id": path.stem, "model": {"name": model, "options": {}, "cot_format": {"kind": "sentence"}},
            "scenario": {"id": scenario, "group": group, "family": kind}, "seed": seed}
    image = np.zeros((8, 16, 3), np.uint8)
    feature = Actor("crit", kind, PEDESTRIAN_X, 0.0 if kind == "pedestrian" else -5.0, state=light)
    road_user = kind == "pedestrian"
    x, speed = 0.0, 6.0
    with writer_class(path, meta) as writer:
        for step in range(steps):
            distance = PEDESTRIAN_X - x
            truth = GroundTruth(step, round(step * 0.1, 10), (feature,), "crit", kind, distance, road_user, light,
                                distance if road_user else None, 0.0 if road_user else None, x, 100.0)
            obs = Observation(step, truth.time, image, EgoState(x, 0.0, 0.0, speed), "follow_lane", truth, scenario)
            seen = distance < notice
            v_des = max(speed - 1.0, 0.0) if seen else 6.0
            control = Control(0.0, 0.0, 0.5 if seen else 0.0, v_des)
            writer.write_step(obs, CoT(noticed if seen else before), _TRAJECTORY, control)
            x += speed * 0.1
            speed = v_des
        writer.finish({"terminal": "timeout", "steps": steps})


def _label_directory(directory: Path) -> None:
    from vladrivebench._analysis.dataset import label_items as logged_items
    from vladrivebench._analysis.dataset import read_directory
    from vladrivebench._analysis.labels import LabelStore, label_key

    episodes, _ = read_directory(directory)
    labeler = KeywordLabeler()
    items = [item for _, _, item in logged_items(episodes)]
    store = LabelStore(directory, labeler.name)
    store.add([(item, label_key(item, labeler.name, labeler.version), labels)
               for item, labels in zip(items, labeler.label_batch(items), strict=True)], labeler.version)

