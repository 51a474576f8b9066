"""Training data from the kinematic simulator: the expert drives randomised variants of the scenario suite
closed-loop (through the benchmark's own runner and controllers), and every visited step becomes a sample.

Variants randomise what the families leave open: where the critical actor stands (distance, lateral
offset: kerbside or in the lane), the light colour, the scenery, the ego's initial speed, the speed the
driving expert cruises at, in half of the episodes a late reaction to stops (the car drives on until
a random distance before the stop point), and in half of them short bursts of wandering steering (the car
veers off the lane centre) — so the models see the states a model that brakes late or steers badly ends up
in. The *labels* of a sample are always the expert's decision and plan for the visited state, so a model
learns to recover (DAgger-style).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from vladrivebench import CoT, CoTFormat, LightSpec, Observation, Trajectory, TrajectorySpec

from .common import IMAGE_HEIGHT, IMAGE_WIDTH, image_batch
from .expert import (
    ExpertDriver,
    counterfactual,
    cruise_for,
    rollout_controls,
    sentence_cot,
    slot_cot,
    vision_vetoes,
)
from .kv_model import rollout

TRAIN_FAMILIES = ("pedestrian", "stopped_car", "traffic_light", "stop_sign", "baseline")
"""Families the models learn from; the intervention routes (E.1, E.2, SAFE.*) are held out for evaluation."""
FAMILY_WEIGHTS = {"traffic_light": 2, "stopped_car": 3}
"""How many times a family's scenarios enter the episode rotation: a lit lamp is one pixel and a blocking
car the one obstacle the safety override must respect, so both get more episodes than their file count."""
MOVING_WEIGHT = 2
"""Scenarios with a walking pedestrian (crossing, along the lane) enter the rotation twice: when to yield to a
walker near the path is learnt from the few metres where it matters."""
WAIT_STEPS = 15
WALKER_WAIT_STEPS = 45
"""Steps an expert episode waits at a stop before it ends (longer with a walking pedestrian, who may walk up
to the stopped ego and stand at its bumper: a model that creeps there hits it)."""
SCENERIES = ("plain", "suburban", "urban")
GREEN_BEYOND_SHARE = 0.3
"""Share of obstacle variants on a straight road that get a green light beyond the obstacle (as on the
safety-override routes, which are held out): a lit lamp in view must not hide the pedestrian."""
SLOW_SPEED = 1.5
LATE_SHARE = 0.5
"""Share of episodes whose driving reacts late to a stop (the labels are always the expert's decision)."""
FAST_SPEEDS = (4.0, 9.0)
FAST_SHARE = 0.5
"""Share of the slow steps near a salient obstacle that are also recorded as if the ego drove at a speed drawn
from ``FAST_SPEEDS`` (the image does not show speed): the expert brakes hard there, whatever the CoT says."""
WANDER_SHARE = 0.5
"""Share of episodes whose driving veers off the lane centre now and then. Without it every sample is
centred in its lane and heading along it, and a model whose steering errs a little never learnt to steer
back (``qa`` drifted 3.4 m across into the next lane on a straight road)."""
WANDER_RATE = 0.04
"""Chance per step (10 Hz) that a wandering burst begins."""
WANDER_STEPS = (5, 20)
WANDER_CURVATURE = (0.003, 0.012)
"""Burst length (steps) and the magnitude of the constant curvature (1/m) driven during it, left or right."""


@dataclass
class Dataset:
    """Arrays of samples (N of each): camera images at the encoder's size, ego speed and command, the
    expert's sentence CoT, three answers, controls (acceleration, curvature) and waypoints, and one
    counterfactual (sentence + controls) per sample."""

    images: np.ndarray  # (N, H, W, 3) uint8
    speeds: np.ndarray  # (N,)
    commands: list[str]
    sentences: list[str]
    slots: list[dict[str, str]]
    controls: np.ndarray  # (N, 30, 2) the expert's plan (the qa model's target when it goes)
    sentence_controls: np.ndarray  # (N, 30, 2) the plan the sentence commits to (kv's target; qa's for a stop)
    waypoints: np.ndarray  # (N, 30, 2)
    cf_sentences: list[str]
    cf_controls: np.ndarray  # (N, 30, 2)
    cf_vetoed: np.ndarray  # (N,) bool: the counterfactual is a "clear road" CoT that vision overrides
    perception: np.ndarray  # (N, 5) auxiliary targets for the vision encoder (see perception_targets)
    decisions: list[str]
    scenario_ids: list[str]

    def __len__(self) -> int:
        return len(self.speeds)

    def save(self, path) -> None:
        """Write the dataset as one ``.npz`` (arrays, and the texts as JSON; no pickle)."""
        import json

        texts = {k: getattr(self, k) for k in ("commands", "sentences", "slots", "cf_sentences", "decisions",
                                               "scenario_ids")}
        arrays = {k: getattr(self, k) for k in ("images", "speeds", "controls", "sentence_controls",
                                                "waypoints", "cf_controls", "cf_vetoed", "perception")}
        path = Path(path)
        tmp = path.with_name(path.stem + ".partial.npz")
        np.savez(tmp, texts=np.array(json.dumps(texts)), **arrays)
        tmp.replace(path)  # appears complete or not at all

    @classmethod
    def load(cls, path) -> Dataset:
        import json

        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files if k != "texts"}
            texts = json.loads(str(data["texts"]))
        return cls(**arrays, **texts)

    def corpus(self) -> list[str]:
        """Every text of the dataset (for training the tokenizer)."""
        texts = list(self.sentences) + list(self.cf_sentences)
        for slots in self.slots:
            texts.extend(slots.values())
        return texts


class EnoughWaiting(Exception):
    """Raised by the expert to end an episode once it has waited long enough at a stop."""


class ExpertModel:
    """The expert as a VLAModel, so the benchmark's runner and controllers drive it like any model.

    It reads the privileged ground truth (perfect perception). ``exec_cruise`` is the speed it actually
    cruises at; ``record`` is called with every step's sample before the action is returned.
    """

    cot_format = CoTFormat("sentence")
    trajectory_spec = TrajectorySpec(3.0, 10.0)

    def __init__(self, rng: np.random.Generator, exec_cruise: float, record: Callable[[dict], None],
                 max_wait_steps: int = 15, late_reaction: float | None = None, wander: bool = False):
        self.rng, self.exec_cruise, self.record = rng, exec_cruise, record
        self.driver = ExpertDriver()
        self.max_wait_steps, self.waited = max_wait_steps, 0
        self.late_reaction = late_reaction
        self.wander = wander
        self.wander_steps_left, self.wander_curvature = 0, 0.0

    def reset(self, seed: int) -> None:
        self.driver.reset()

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        decision = self.driver.decide(obs)
        # Standing still in front of an obstacle or a red light for ever teaches nothing new and would
        # swamp the data with "remain stopped": end the episode after a short wait.
        self.waited = self.waited + 1 if decision.action == "stop" and obs.ego.speed < 0.2 else 0
        if self.waited > self.max_wait_steps:
            raise EnoughWaiting()
        if decision.action == "go" and 0.0 < obs.ego.speed < SLOW_SPEED:
            # The same scene seen at rest: starting up is otherwise a handful of steps per episode.
            self._sample(dataclasses.replace(obs, ego=dataclasses.replace(obs.ego, speed=0.0)), decision)
        if vision_vetoes(obs, decision) and obs.ego.speed < FAST_SPEEDS[0] and self.rng.random() < FAST_SHARE:
            # The expert stops early, so it is rarely fast this close to an obstacle — but a model that
            # brakes late (or is told the road is clear) is, and must still brake for what it sees.
            fast = float(self.rng.uniform(*FAST_SPEEDS))
            self._sample(dataclasses.replace(obs, ego=dataclasses.replace(obs.ego, speed=fast)), decision)
        cot = self._sample(obs, decision, keep=not ran_a_light(obs, decision))
        return self._wandering(cot) if self.wander else cot

    def _wandering(self, cot: CoT) -> CoT:
        """``cot`` with its executed plan replaced by a constant-curvature arc while a burst lasts (the
        recorded sample keeps the expert's plan: that is the way back)."""
        if self.wander_steps_left == 0 and self.rng.random() < WANDER_RATE:
            self.wander_steps_left = int(self.rng.integers(WANDER_STEPS[0], WANDER_STEPS[1] + 1))
            self.wander_curvature = float(self.rng.choice([-1.0, 1.0]) * self.rng.uniform(*WANDER_CURVATURE))
        if self.wander_steps_left == 0:
            return cot
        self.wander_steps_left -= 1
        executed = cot.state.copy()
        executed[:, 1] = self.wander_curvature
        return dataclasses.replace(cot, state=executed)

    def _sample(self, obs: Observation, decision, keep: bool = True) -> CoT:
        controls = self.driver.plan(obs, decision)
        _, cf_text, cf_controls = counterfactual(obs, decision, self.driver.cruise_speed, self.rng)
        sentence = sentence_cot(decision, obs.ego.speed, self.rng)
        # The plan the sentence commits to (the kv target): "accelerate" → a little faster; "stop" → brake now.
        if decision.action == "go":
            sentence_controls = rollout_controls(obs.ego.speed, obs.ground_truth, None,
                                                 cruise_for(sentence, self.driver.cruise_speed))
        else:
            sentence_controls = rollout_controls(obs.ego.speed, obs.ground_truth, decision.stop_distance,
                                                 self.driver.cruise_speed, brake_now=True)
        sample = {
            "image": obs.image, "speed": obs.ego.speed, "command": obs.command, "sentence": sentence,
            "sentence_controls": sentence_controls,
            "slots": slot_cot(obs, decision, self.rng), "controls": controls,
            "cf_sentence": cf_text, "cf_controls": cf_controls, "cf_vetoed": vision_vetoes(obs, decision),
            "decision": decision.action,
            "scenario_id": obs.scenario_id, "perception": perception_targets(obs, decision),
        }
        if keep:
            self.record(sample)
        stop_at = decision.stop_distance
        if self.late_reaction is not None and stop_at is not None and stop_at > self.late_reaction:
            stop_at = None  # drive on: the late reactions put the data where a model that brakes late ends up
        executed = rollout_controls(obs.ego.speed, obs.ground_truth, stop_at, self.exec_cruise)
        return CoT(text=sample["sentence"], state=executed)

    def splice_cot(self, obs, text, rng):  # pragma: no cover - the expert is never intervened on
        raise NotImplementedError("the expert driver does not take spliced CoTs")

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        return rollout(cot.state[:, 0], cot.state[:, 1], obs.ego.speed, 0.1)

    def state_digest(self, cot: CoT) -> str:  # pragma: no cover
        return ""


def ran_a_light(obs: Observation, decision) -> bool:
    """Whether a late-reacting episode has just driven past a light that is not green: the lamp is still in
    view, and "the road is clear" there would contradict "red light" on the same pixels — such steps are
    driven but not learnt from."""
    return decision.reason == "passed" and decision.kind == "traffic_light" \
        and obs.ground_truth.light_state in ("red", "yellow")


PERCEIVED_KINDS = ("none", "pedestrian", "car", "animal", "traffic_light", "stop_sign")
PERCEIVED_LIGHTS = ("none", "red", "yellow", "green")
PERCEPTION_RANGE = 150.0


def perception_targets(obs: Observation, decision) -> np.ndarray:
    """What the camera should tell the vision encoder (auxiliary training targets, from the ground truth):
    stop?, critical kind, blocking?, distance / PERCEPTION_RANGE, light colour."""
    gt = obs.ground_truth
    kind, distance = "none", PERCEPTION_RANGE
    if gt.critical_kind is not None and gt.distance_to_critical is not None \
            and -1.0 <= gt.distance_to_critical <= PERCEPTION_RANGE:
        kind, distance = gt.critical_kind, max(0.0, gt.distance_to_critical)
    light = gt.light_state if kind == "traffic_light" and gt.light_state in PERCEIVED_LIGHTS else "none"
    return np.array([float(decision.action == "stop"), PERCEIVED_KINDS.index(kind), float(gt.blocking and kind != "none"),
                     distance / PERCEPTION_RANGE, PERCEIVED_LIGHTS.index(light)], dtype=np.float32)


def variant(scenario, rng: np.random.Generator):
    """A randomised variant of a suite scenario (same family and layout, different details)."""
    road = dataclasses.replace(scenario.road, scenery=str(rng.choice(SCENERIES)))
    ego = dataclasses.replace(scenario.ego, speed=float(rng.choice([0.0, 0.0, rng.uniform(2.0, 8.0)])))
    actors = []
    for actor in scenario.actors:
        changes = {"s": max(15.0, actor.s + float(rng.uniform(-15.0, 15.0)))}
        if actor.motion == "static" and actor.kind in ("pedestrian", "animal"):
            # In the lane, in the opposite lane (near the path: the expert yields, as one frame cannot show
            # whether it is about to cross), or on either sidewalk (passed).
            changes["offset"] = float(rng.choice([actor.offset, rng.uniform(-1.2, 1.2), rng.uniform(1.8, 5.0),
                                                  rng.uniform(-4.6, -3.2), rng.uniform(5.6, 7.5)]))
        if actor.motion == "static" and actor.kind == "car":
            # In the ego lane or in the next one, on either stopped-car road: "blocking" is then a matter of
            # where the car is in the image, not of which road or scenery it stands on.
            changes["offset"] = float(rng.choice([actor.offset, rng.uniform(-0.4, 0.4), rng.uniform(3.0, 3.8)]))
        if actor.trigger_distance is not None:
            changes["trigger_distance"] = max(5.0, actor.trigger_distance + float(rng.uniform(-5.0, 5.0)))
        actors.append(dataclasses.replace(actor, **changes))
    light = scenario.light
    if light is not None:
        light = dataclasses.replace(light, state=str(rng.choice(["red", "red", "green", "green", "yellow"])))
    elif scenario.layout == "straight" and actors and rng.random() < GREEN_BEYOND_SHARE:
        # A green light beyond the obstacle: the obstacle is still what matters, whatever the lamp says.
        nearest = min(actor.s for actor in actors)
        light = LightSpec(state="green", stop_line=float(rng.uniform(nearest + 10.0,
                                                                      max(nearest + 12.0, road.approach_length))))
    return dataclasses.replace(scenario, road=road, ego=ego, actors=tuple(actors), light=light,
                               id=f"{scenario.id}~v{int(rng.integers(1 << 30))}")


def generate(seed: int, episodes: int, every: int = 2, scenarios: Iterable | None = None,
             progress: Callable[[str], None] | None = None, max_time_s: float = 22.0,
             workers: int = 1) -> Dataset:
    """Drive ``episodes`` randomised episodes with the expert and keep every ``every``-th step.

    Episode ``i`` draws everything from its own stream ``(seed, i)``, so the dataset is the same whatever
    the number of ``workers`` (processes that each drive a share of the episodes)."""
    base = list(scenarios) if scenarios is not None else _training_scenarios()
    if not base:
        raise RuntimeError("no scenarios to train on: the scenario suite is empty")
    jobs = [(seed, episode, base[episode % len(base)], every, max_time_s) for episode in range(episodes)]
    rows: list[dict] = []
    started = time.perf_counter()
    for done, kept in enumerate(_drive_all(jobs, workers), start=1):
        rows.extend(kept)
        if progress and done % 10 == 0:
            progress(f"  {done}/{episodes} episodes, {len(rows)} samples, {time.perf_counter() - started:.0f} s")
    return _to_dataset(rows)


def _training_scenarios() -> list:
    from vladrivebench.world import load_suite

    return [s for s in load_suite().values() if s.family in TRAIN_FAMILIES
            for _ in range(FAMILY_WEIGHTS.get(s.family, 1) * (MOVING_WEIGHT if _has_walker(s) else 1))]


def _has_walker(scenario) -> bool:
    return any(a.motion != "static" and a.kind in ("pedestrian", "animal") for a in scenario.actors)


def _drive_all(jobs: list[tuple], workers: int) -> Iterable[list[dict]]:
    """Each job's kept samples, in job order."""
    if workers <= 1:
        yield from map(_drive_episode, jobs)
        return
    import multiprocessing

    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        yield from pool.imap(_drive_episode, jobs, chunksize=2)


_SIMULATOR = None


def _drive_episode(job: tuple) -> list[dict]:
    """One expert episode of a randomised variant; returns the samples kept."""
    from vladrivebench.episodes import build_component
    from vladrivebench.testing import EpisodeFailure, get_registry, run_episode

    global _SIMULATOR
    seed, episode, scenario, every, max_time_s = job
    if _SIMULATOR is None:  # one simulator per process, reused across its episodes
        _SIMULATOR = get_registry().create("simulator", "kinematic", {"width": IMAGE_WIDTH, "height": IMAGE_HEIGHT})
    rng = np.random.default_rng([seed, 0xDA7A, episode])
    scenario = variant(scenario, rng)
    scenario = dataclasses.replace(scenario, max_time_s=min(scenario.max_time_s, max_time_s))
    kept: list[dict] = []
    offset = int(rng.integers(every))
    late = float(rng.uniform(2.0, 25.0)) if rng.random() < LATE_SHARE else None
    wander = bool(rng.random() < WANDER_SHARE)
    # A walker comes up to a stopped ego (P.7's walks right up to its bumper): wait long enough to learn that.
    wait = WALKER_WAIT_STEPS if _has_walker(scenario) else WAIT_STEPS
    expert = ExpertModel(rng, float(rng.uniform(5.5, 9.5)), kept.append, max_wait_steps=wait, late_reaction=late,
                         wander=wander)
    controller = build_component("controller", "mpc") if episode % 2 else build_component("controller", "pid")
    try:
        run_episode(expert, _SIMULATOR, controller, scenario, int(rng.integers(1 << 30)))
    except EpisodeFailure as failure:
        if not isinstance(failure.__cause__, EnoughWaiting):
            raise
    # Every step near standstill is kept: starting up (or not) from rest is rare but decisive.
    return [k for i, k in enumerate(kept) if i % every == offset or k["speed"] < SLOW_SPEED]


def _encoder_sized(image: np.ndarray) -> np.ndarray:
    if image.shape[:2] == (IMAGE_HEIGHT, IMAGE_WIDTH):
        return np.asarray(image, dtype=np.uint8)
    resized = image_batch([image])[0].permute(1, 2, 0).numpy()
    return (resized * 255.0 + 0.5).astype(np.uint8)


def _to_dataset(rows: list[dict]) -> Dataset:
    images_u8 = np.stack([_encoder_sized(r["image"]) for r in rows])
    controls = np.stack([r["controls"] for r in rows])
    speeds = np.array([r["speed"] for r in rows], dtype=np.float64)
    waypoints = np.stack([
        rollout(c[:, 0], c[:, 1], v, 0.1).xy for c, v in zip(controls, speeds, strict=True)
    ])
    return Dataset(
        images=images_u8, speeds=speeds, commands=[r["command"] for r in rows],
        sentences=[r["sentence"] for r in rows], slots=[r["slots"] for r in rows], controls=controls,
        sentence_controls=np.stack([r["sentence_controls"] for r in rows]),
        waypoints=waypoints, cf_sentences=[r["cf_sentence"] for r in rows],
        cf_controls=np.stack([r["cf_controls"] for r in rows]), decisions=[r["decision"] for r in rows],
        cf_vetoed=np.array([r["cf_vetoed"] for r in rows], dtype=bool),
        perception=np.stack([r["perception"] for r in rows]),
        scenario_ids=[r["scenario_id"] for r in rows],
    )
