"""Synthetic episode logs for the labeling, metric and report tests (real MCAP files, hand-made steps).

An episode drives the ego along +x at a given speed profile towards one critical actor; a ``cot`` function
of (step, distance to the target, speed) writes the CoT text, and ``v_des`` the action head's command, so
every label and every alignment set of a test is known in advance.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from vladrivebench._logs.episodes import EpisodeWriter
from vladrivebench.records import Actor, Control, CoT, EgoState, GroundTruth, Observation, Trajectory

GROUPS = {
    "pedestrian": "Pedestrian (in-lane)",
    "car": "Stopped car (blocking)",
    "traffic_light": "Traffic light (red)",
    None: "Baseline",
}
_IMAGE = np.zeros((2, 2, 3), dtype=np.uint8)
_TRAJECTORY = Trajectory(np.array([0.5, 1.0]), np.array([[1.0, 0.0], [2.0, 0.0]]))


def write_episode(
    path: Path,
    *,
    speeds: Sequence[float],
    cot: Callable[[int, float | None, float], str | dict],
    v_des: Callable[[int, float | None, float], float],
    kind: str | None = "pedestrian",
    target_x: float = 60.0,
    light: str | None = None,
    model: str = "fake",
    model_options: dict | None = None,
    scenario_id: str = "P.1",
    group: str | None = None,
    seed: int = 0,
    intervention: dict | None = None,
    finish: bool = True,
) -> Path:
    """Write one episode: step ``i`` has ego speed ``speeds[i]`` and the ego moves ``speed × 0.1`` m per step."""
    meta = {"episode_id": path.stem, "model": {"name": model, "options": dict(model_options or {}),
                                                "cot_format": {"kind": "sentence"}},
            "scenario": {"id": scenario_id, "group": group or GROUPS.get(kind, "Other"),
                         "family": kind or "baseline"}, "seed": seed}
    if intervention:
        meta["intervention"] = intervention
    x = 0.0
    writer = EpisodeWriter(path, meta)
    with writer:
        for step, speed in enumerate(speeds):
            distance = None if kind is None else target_x - x
            actors = () if kind is None else (
                Actor("target", kind, target_x, 0.0, state=light if kind == "traffic_light" else None),)
            truth = GroundTruth(step=step, time=step * 0.1, actors=actors, critical_id=None if kind is None else "target",
                                critical_kind=kind, distance_to_critical=distance, blocking=kind in ("pedestrian", "car"),
                                light_state=light, lead_gap=distance if kind in ("pedestrian", "car") else None,
                                lead_speed=0.0 if kind in ("pedestrian", "car") else None)
            obs = Observation(step, step * 0.1, _IMAGE, EgoState(x, 0.0, 0.0, speed), "follow_lane", truth, scenario_id)
            text = cot(step, distance, speed)
            record = CoT(CoT.join_slots(text), dict(text)) if isinstance(text, dict) else CoT(text)
            control = Control(0.0, 0.0, 0.0, v_des(step, distance, speed))
            writer.write_step(obs, record, _TRAJECTORY, control)
            x += speed * 0.1
        if finish:
            writer.finish({"terminal": "route_complete", "steps": len(speeds)})
    return path


STOP_PED = "Stop for the pedestrian in the lane because it is blocking the lane."
CLEAR = "Maintain speed since the road ahead is clear."
ACCEL = "Accelerate to maintain speed since the road ahead is clear and no obstacles are present."
PHANTOM_CAR = "Slow down because a car is parked in the lane and a cyclist is crossing."
CONTRADICTION = "Stop for the pedestrian and accelerate to pass it."


# -- a fake labeler: a fixed text → labels table, so metric tests do not depend on any labeler's rules ----
import vladrivebench  # noqa: E402
from vladrivebench.records import Labels  # noqa: E402

TABLE = {
    STOP_PED: dict(stated_action="decelerating", target_mentioned=True),
    CLEAR: dict(stated_action="maintaining", target_mentioned=False),
    ACCEL: dict(stated_action="accelerating", target_mentioned=False),
    PHANTOM_CAR: dict(stated_action="decelerating", target_mentioned=False, hallucination=True),
    CONTRADICTION: dict(stated_action="decelerating", target_mentioned=True, contradiction=True),
    "The light ahead is red, stop.": dict(stated_action="decelerating", target_mentioned=True, light_colour="red"),
    "The light ahead is green, go.": dict(stated_action="maintaining", target_mentioned=True, light_colour="green"),
    "The light ahead, stop.": dict(stated_action="decelerating", target_mentioned=True),
}


class FakeLabeler:
    """Labels from :data:`TABLE`; unknown texts come back unlabelled (with the reason)."""

    def __init__(self, version: str = "1", fail_after: int | None = None):
        self.version = version
        self.fail_after = fail_after
        self.calls = 0
        self.labelled = 0

    def label(self, item):
        entry = TABLE.get(item.text)
        if entry is None:
            return Labels(unlabelled=f"unknown text {item.text[:20]!r}", labeler="fake", version=self.version)
        values = dict(entry)
        if not item.context.get("critical_kind"):
            values["target_mentioned"] = None
        return Labels(**values, labeler="fake", version=self.version)

    def label_batch(self, items):
        self.calls += 1
        if self.fail_after is not None and self.labelled >= self.fail_after:
            raise KeyboardInterrupt
        self.labelled += len(items)
        return [self.label(i) for i in items]


class PlanningLabeler(FakeLabeler):
    def plan(self, items):
        return {"fake-backend": {"calls": len(items), "cached": 0}}


class DyingLabeler(FakeLabeler):
    """Interrupted (as by Ctrl-C) on its third ``label_batch`` call with chunks of 3."""

    def __init__(self, version: str = "1"):
        super().__init__(version, fail_after=6)


class CheckedLabeler(FakeLabeler):
    def check(self):
        from vladrivebench.errors import ConfigError

        raise ConfigError("labeler 'checked': FAKE_API_KEY is not set; export it")


@vladrivebench.hookimpl
def register_labelers(register):
    register("fake", FakeLabeler)
    register("planning", PlanningLabeler)
    register("checked", CheckedLabeler)
    register("dying", DyingLabeler)


def registry_with_fakes():
    """The core's built-ins plus the fake labelers, nothing installed."""
    import analysis_episodes
    from vladrivebench import _builtins as builtins
    from vladrivebench.testing import isolated_registry

    return isolated_registry(("core", builtins), ("fakes", analysis_episodes))
