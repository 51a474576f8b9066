"""The conformance kit: every check passes on a well-behaved fake and FAILS, naming the plugin and what
broke, on a deliberately broken one; the pytest plugin's fixtures are light, isolated and realistic."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench import (
    Actor,
    ConfigError,
    CoT,
    CoTFormat,
    EgoState,
    GroundTruth,
    LabelInput,
    Labels,
    Observation,
    Trajectory,
    TrajectorySpec,
    hookimpl,
)
from vladrivebench.metrics import Cell, Plot, Row, Series, Table
from vladrivebench.testing import (
    KeywordLabeler,
    check_bad_options,
    check_labeler,
    check_metric,
    check_model,
    check_simulator,
    observations,
    sample_label_items,
    synthetic_observation,
)


# -- a well-behaved fake model and its broken variants ----------------------------------------------------
class WordModel:
    """Its CoT says stop or go from the ground truth; its state is the text; its action follows the state."""

    cot_format = CoTFormat("sentence", max_tokens=20)
    trajectory_spec = TrajectorySpec(1.0, 10.0)

    def reset(self, seed):
        pass

    def generate_cot(self, obs, rng):
        near = (obs.ground_truth.distance_to_critical or 99.0) < 30.0
        text = "Stop for the pedestrian." if near else "Go ahead."
        return CoT(text, state={"text": text})

    def splice_cot(self, obs, text, rng):
        return CoT(text, state={"text": text})

    def decode_action(self, obs, cot, rng):
        speed = 0.5 if "Stop" in cot.state["text"] else 5.0
        times = np.arange(1, 11) / 10.0
        noise = rng.normal(0.0, 0.01, 10)
        return Trajectory(times, np.stack([speed * times + noise, np.zeros(10)], axis=1))

    def state_digest(self, cot):
        return hashlib.sha256(cot.state["text"].encode()).hexdigest()


class SpliceAddsASpace(WordModel):
    def splice_cot(self, obs, text, rng):
        return CoT(text, state={"text": text + " "})


class SpliceKeepsDigestButNotAction(WordModel):
    def splice_cot(self, obs, text, rng):
        return CoT(text, state={"text": text}, spliced=True)

    def decode_action(self, obs, cot, rng):
        trajectory = super().decode_action(obs, cot, rng)
        return Trajectory(trajectory.times, trajectory.xy * (1.1 if cot.spliced else 1.0))


class UnseededModel(WordModel):
    counter = itertools.count()

    def decode_action(self, obs, cot, rng):
        return super().decode_action(obs, cot, np.random.default_rng(next(self.counter)))


class Chatterbox(WordModel):
    cot_format = CoTFormat("sentence", max_tokens=3)


class BackwardsTrajectory(WordModel):
    def decode_action(self, obs, cot, rng):
        trajectory = super().decode_action(obs, cot, rng)
        return Trajectory(trajectory.times[::-1], trajectory.xy)


class BellRinger(WordModel):
    def generate_cot(self, obs, rng):
        return CoT("Go ahead.\x07", state={"text": "Go ahead.\x07"})


class NoDigest:
    cot_format = CoTFormat()
    trajectory_spec = TrajectorySpec()

    def reset(self, seed): ...
    def generate_cot(self, obs, rng): ...
    def splice_cot(self, obs, text, rng): ...
    def decode_action(self, obs, cot, rng): ...


class LyingTokenCounter(WordModel):
    def count_tokens(self, text):
        return -1


@pytest.fixture(scope="module")
def three_observations():
    return observations(3, render=False)


def test_check_model_passes_on_a_conforming_model(three_observations):
    check_model(WordModel(), three_observations, name="word")


@pytest.mark.parametrize("model,needle", [
    (SpliceAddsASpace(), "selfsplice changed the state digest"),
    (SpliceKeepsDigestButNotAction(), "selfsplice changed the trajectory"),
    (UnseededModel(), "decode_action is not deterministic"),
    (Chatterbox(), "more than cot_format.max_tokens = 3"),
    (BackwardsTrajectory(), "malformed trajectory: times must be positive and strictly increasing"),
    (NoDigest(), "does not implement the VLAModel protocol"),
    (BellRinger(), "cannot be injected back (the intervention protocol would refuse it): the CoT contains the "
                   "control or unassigned character U+0007"),
    (LyingTokenCounter(), "count_tokens('Stop for the pedestrian.') must return a non-negative int"),
])
def test_check_model_fails_on_a_broken_model(three_observations, model, needle):
    with pytest.raises(AssertionError, match="model 'broken'") as info:
        check_model(model, three_observations, name="broken")
    assert needle in str(info.value)


def test_check_model_needs_observations():
    with pytest.raises(AssertionError, match="at least one observation"):
        check_model(WordModel(), [], name="word")


# -- bad options --------------------------------------------------------------------------------------------
def make_word_model(coupling: float = 1.0):
    if not 0.0 <= coupling <= 1.0:
        raise ConfigError(f"model 'word': option 'coupling' must be in [0, 1], got {coupling}")
    return WordModel()


def test_check_bad_options_passes_on_one_line_errors():
    check_bad_options(lambda options: _create(make_word_model, options), [{"coupling": 2.0}, {"coupling": -1}],
                      name="word")


def _create(factory, options):
    from vladrivebench.testing import check_options

    check_options("model", "word", factory, options)
    return factory(**options)


def accepts_anything(coupling: float = 1.0):
    return WordModel()


def raises_value_error(coupling: float = 1.0):
    raise ValueError("bad coupling")


def two_lines(coupling: float = 1.0):
    raise ConfigError("model 'word': option 'coupling' is wrong\nexpected a number")


def says_nothing_useful(coupling: float = 1.0):
    raise ConfigError("something is wrong")


@pytest.mark.parametrize("factory,needle", [
    (accepts_anything, "were accepted"),
    (raises_value_error, "raised ValueError: bad coupling"),
    (two_lines, "must be one non-empty line"),
    (says_nothing_useful, "names neither the option nor its value"),
])
def test_check_bad_options_fails_when_a_bad_option_is_not_a_one_line_error(factory, needle):
    with pytest.raises(AssertionError, match="'word'") as info:
        check_bad_options(lambda options: _create(factory, options), [{"coupling": 2.0}], name="word")
    assert needle in str(info.value)


def test_check_bad_options_tries_an_unknown_option_too():
    with pytest.raises(AssertionError, match="no_such_option_vdb"):
        check_bad_options(lambda options: WordModel(), [], name="word")


# -- a well-behaved fake simulator and its broken variants ---------------------------------------------------
class LineWorld:
    """A 1-D road with a pedestrian at 40 m; the episode times out after ``steps`` steps."""

    dt = 0.1
    steps = 15

    def reset(self, scenario, seed):
        self.rng = np.random.default_rng(seed)
        self.offset = float(self.rng.uniform(0.0, 1.0))
        self.step_index, self.x, self.speed = 0, 0.0, 3.0
        return self.observe()

    def step(self, control):
        self.step_index += 1
        self.speed = max(self.speed + (control.throttle * 2.0 - control.brake * 5.0) * self.dt, 0.0)
        self.x += self.speed * self.dt
        return self.observe()

    def truth(self):
        terminal = "timeout" if self.step_index == self.steps else None
        actor = Actor("ped", "pedestrian", 40.0 + self.offset, 0.0)
        return GroundTruth(self.step_index, round(self.step_index * self.dt, 10), (actor,), "ped", "pedestrian",
                           40.0 + self.offset - self.x, True, terminal=terminal)

    def observe(self):
        truth = self.truth()
        image = np.full((24, 32, 3), int(self.x * 10) % 256, np.uint8)
        return Observation(truth.step, truth.time, image, EgoState(self.x, 0.0, 0.0, self.speed), "follow_lane", truth)

    def close(self):
        pass


class RandomStart(LineWorld):
    def reset(self, scenario, seed):
        obs = super().reset(scenario, seed)
        self.x = float(np.random.default_rng().uniform(0.0, 1.0))  # not from the seed
        return obs


class LeakyReset(LineWorld):
    episodes = 0

    def reset(self, scenario, seed):
        obs = super().reset(scenario, seed + LeakyReset.episodes)
        LeakyReset.episodes += 1
        return obs


class TerminalFlag(LineWorld):
    def truth(self):
        truth = super().truth()
        return dataclasses.replace(truth, terminal=True) if self.step_index == 3 else truth


class NoClock(LineWorld):
    def truth(self):
        return dataclasses.replace(super().truth(), time=0.0)


class SkipsSteps(LineWorld):
    def truth(self):
        return dataclasses.replace(super().truth(), step=self.step_index * 2)


class Bicycles(LineWorld):
    def truth(self):
        truth = super().truth()
        return dataclasses.replace(truth, actors=(dataclasses.replace(truth.actors[0], kind="bicycle"),),
                                   critical_kind="bicycle")


class WrongCriticalKind(LineWorld):
    def truth(self):
        return dataclasses.replace(super().truth(), critical_kind="car")


class LostDistance(LineWorld):
    def truth(self):
        return dataclasses.replace(super().truth(), distance_to_critical=float("nan"))


class FloatImage(LineWorld):
    def observe(self):
        obs = super().observe()
        return dataclasses.replace(obs, image=obs.image.astype(np.float32))


def test_check_simulator_passes_on_a_conforming_simulator():
    check_simulator(LineWorld, None, name="line")


@pytest.mark.parametrize("make,needle", [
    (RandomStart, "not deterministic after reset: the same scenario and seed gave different ego at step 1"),
    (LeakyReset, "not deterministic after reset"),
    (TerminalFlag, "at step 3: terminal must be None or a non-empty reason, got True"),
    (NoClock, "at step 1: time 0.0 (ground truth 0.0) should be step × dt = 0.1"),
    (SkipsSteps, "steps count from 0 by one"),
    (Bicycles, "has kind 'bicycle'"),
    (WrongCriticalKind, "critical_kind 'car' but the critical actor is a 'pedestrian'"),
    (LostDistance, "distance_to_critical must be a finite number"),
    (FloatImage, "image dtype must be uint8, got float32"),
])
def test_check_simulator_fails_on_a_broken_simulator(make, needle):
    with pytest.raises(AssertionError, match="simulator 'broken'") as info:
        check_simulator(make, None, name="broken")
    assert needle in str(info.value)


def test_check_simulator_asks_for_large_images_when_told():
    with pytest.raises(AssertionError, match="has a side below 224 pixels"):
        check_simulator(LineWorld, None, name="line", min_image_side=224)


# -- labelers ---------------------------------------------------------------------------------------------
class InventsActions(KeywordLabeler):
    def label(self, item):
        return dataclasses.replace(super().label(item), stated_action="braking")


class ReversedBatch(KeywordLabeler):
    def label_batch(self, items):
        return [self.label(item) for item in reversed(items)]


class Unversioned(KeywordLabeler):
    version = ""


class MentionsNothingAsTarget(KeywordLabeler):
    def label(self, item):
        return dataclasses.replace(super().label(item), target_mentioned=False)


class PurpleLights(KeywordLabeler):
    def label(self, item):
        return dataclasses.replace(super().label(item), light_colour="purple")


class NumbersForFlags(KeywordLabeler):
    def label(self, item):
        return Labels(stated_action="none", hallucination=0, labeler="n", version="1")


def test_check_labeler_passes_on_the_keyword_labeler():
    check_labeler(KeywordLabeler(), sample_label_items(), name="keyword")


@pytest.mark.parametrize("labeler,needle", [
    (InventsActions(), "stated_action 'braking' is not one of"),
    (ReversedBatch(), "label_batch differs from label at item 0"),
    (Unversioned(), "version must be a non-empty string"),
    (MentionsNothingAsTarget(), "on a step without a critical feature (it must be None)"),
    (PurpleLights(), "light_colour 'purple'"),
    (NumbersForFlags(), "hallucination must be a bool, got 0"),
])
def test_check_labeler_fails_on_a_broken_labeler(labeler, needle):
    with pytest.raises(AssertionError, match="labeler 'broken'") as info:
        check_labeler(labeler, sample_label_items(), name="broken")
    assert needle in str(info.value)


def test_sample_label_items_cover_slots_lights_and_steps_without_a_target():
    items = sample_label_items()
    assert any(item.slots for item in items) and any(not item.context["critical_kind"] for item in items)
    assert {item.context["light_state"] for item in items} >= {"red", "green", None}
    assert all(isinstance(item, LabelInput) for item in items)


# -- metrics ----------------------------------------------------------------------------------------------
class StepCount:
    """A conforming metric: the number of logged steps per scenario."""

    name = "step_count"

    def cells(self, dataset):
        by_scenario = {}
        for episode in dataset.episodes:
            by_scenario.setdefault(episode.meta["scenario"]["id"], []).append(len(episode.steps))
        return [(scenario, Cell(str(sum(counts)), len(counts), float(sum(counts))))
                for scenario, counts in sorted(by_scenario.items())]

    def compute(self, dataset):
        rows = tuple(Row((scenario,), (cell,)) for scenario, cell in self.cells(dataset))
        return [Table("step_count", "Logged steps", ("Scenario",), ("steps",), rows, metric=self.name)]


class CountlessCell(StepCount):
    def cells(self, dataset):
        return [(scenario, dataclasses.replace(cell, count=None)) for scenario, cell in super().cells(dataset)]


class ValueOnNothing(StepCount):
    def cells(self, dataset):
        return [(scenario, dataclasses.replace(cell, count=0)) for scenario, cell in super().cells(dataset)]


class CountlessSeries(StepCount):
    def compute(self, dataset):
        return [Plot("steps_plot", "Steps", (("all", (Series("m", (1.0, 2.0), (3.0, 4.0)),)),))]


class ReturnsADict(StepCount):
    def compute(self, dataset):
        return {"steps": super().compute(dataset)}


class ReturnsNothing(StepCount):
    def compute(self, dataset):
        return []


class Drifting(StepCount):
    calls = itertools.count()

    def cells(self, dataset):
        return [(s, dataclasses.replace(c, value=c.value + next(self.calls))) for s, c in super().cells(dataset)]


def test_check_metric_passes_on_a_conforming_metric(vdb_dataset):
    (table,) = check_metric(StepCount(), vdb_dataset)
    assert [row.cells[0].count for row in table.rows] == [4, 4]  # two models × two seeds per scenario


@pytest.mark.parametrize("metric,needle", [
    (CountlessCell(), "column 'steps': has no count (count = None"),
    (ValueOnNothing(), "resting on a count of 0"),
    (CountlessSeries(), "has 0 counts for 2 points"),
    (ReturnsADict(), "compute must return a list, got dict"),
    (ReturnsNothing(), "compute returned no table nor plot"),
    (Drifting(), "compute is not deterministic"),
])
def test_check_metric_fails_on_a_broken_metric(vdb_dataset, metric, needle):
    with pytest.raises(AssertionError, match="metric 'broken'") as info:
        check_metric(metric, vdb_dataset, name="broken")
    assert needle in str(info.value)


def test_check_metric_passes_every_built_in_metric_that_applies(vdb_dataset):
    from vladrivebench.testing import Registry, core_plugin

    registry = Registry([core_plugin()], entry_points=False)
    computed = {}
    for component in registry.components("metric"):
        metric = registry.create("metric", component.name)
        computed[component.name] = check_metric(metric, vdb_dataset, name=component.name, allow_empty=True)
    assert {"mention_rate", "tl_accuracy", "alignment_distance"} <= {name for name, r in computed.items() if r}


# -- the fixtures -----------------------------------------------------------------------------------------
def test_the_pytest_plugin_imports_nothing_heavy():
    code = ("import sys, vladrivebench.testing.pytest_plugin; "
            "heavy = [m for m in ('numpy', 'torch', 'transformers', 'libsumo', 'matplotlib', 'mcap') if m in sys.modules]; "
            "print(heavy)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_the_pytest_plugin_is_registered_through_pytest11(pytestconfig):
    from pathlib import Path

    from vladrivebench import load_toml

    declared = load_toml(Path(__file__).resolve().parents[1] / "pyproject.toml")["project"]["entry-points"]
    assert declared["pytest11"] == {"vladrivebench": "vladrivebench.testing.pytest_plugin"}
    plugin = pytestconfig.pluginmanager.get_plugin("vladrivebench")
    assert plugin is not None and plugin.__name__ == "vladrivebench.testing.pytest_plugin"


def test_vdb_observation_is_large_enough_for_a_vision_encoder(vdb_observation, vdb_observations):
    from vladrivebench.testing import Registry

    assert vdb_observation.image.dtype == np.uint8 and min(vdb_observation.image.shape[:2]) >= 224
    if Registry().default_declarations("simulator"):  # rendered by the installed default simulator
        assert vdb_observation.scenario_id == "P.1"
    frames = vdb_observations(4, height=256, width=512)
    assert [f.step for f in frames] == [0, 1, 2, 3] and frames[0].image.shape == (256, 512, 3)
    assert frames[0].ground_truth.critical_kind is not None


def test_synthetic_observations_are_deterministic_and_show_the_pedestrian():
    a, b = synthetic_observation(5, seed=3), synthetic_observation(5, seed=3)
    assert np.array_equal(a.image, b.image) and not np.array_equal(a.image, synthetic_observation(5, seed=4).image)
    assert a.image.shape == (224, 448, 3) and a.image.std() > 10  # a scene, not a flat colour
    near, far = synthetic_observation(40), synthetic_observation(0)
    dark = lambda obs: int((obs.image.sum(axis=2) < 200).sum())  # noqa: E731 - the pedestrian's pixels
    assert dark(near) > dark(far) > 0


def test_observations_fall_back_to_synthesis_when_the_simulator_is_missing():
    frames = observations(2, simulator="no-such-simulator")
    assert frames[0].scenario_id == "synthetic" and np.array_equal(frames[1].image, synthetic_observation(1).image)


def test_vdb_episode_dir_is_labelled(vdb_episode_dir, vdb_dataset):
    assert len(list(vdb_episode_dir.glob("*.mcap"))) == 8
    assert vdb_dataset.labeler == "keyword" and not vdb_dataset.notes
    assert len(vdb_dataset.labels) == sum(len(e.steps) for e in vdb_dataset.episodes) == 8 * 60


@hookimpl
def register_models(register):
    register("word", make_word_model)


def test_vdb_registry_is_isolated_and_restored(vdb_registry):
    from vladrivebench.testing import get_registry

    before = get_registry()
    registry = vdb_registry(sys.modules[__name__], core=True)
    assert get_registry() is registry and registry.names("model") == ["word"]
    assert "pid" in registry.names("controller")
    inner = vdb_registry(("other", sys.modules[__name__]))
    assert get_registry() is inner and inner.names("controller") == []
    assert before is not registry


class Exploding:
    """A simulator plugin that is installed but cannot render."""

    @staticmethod
    @hookimpl
    def register_simulators(register):
        def make(width: int = 8, height: int = 8):
            raise RuntimeError("no GPU")
        register("exploding", make)


def test_observations_fall_back_with_a_warning_when_the_simulator_breaks(monkeypatch):
    from vladrivebench._engine import registry as engine_registry

    real = engine_registry.Registry

    def with_exploding(*args, **kwargs):
        made = real(*args, **kwargs)
        made.add_plugin("exploding", Exploding)
        return made

    monkeypatch.setattr(engine_registry, "Registry", with_exploding)
    with pytest.warns(UserWarning, match="simulator 'exploding' could not render .*RuntimeError: no GPU"):
        frames = observations(1, simulator="exploding")
    assert frames[0].scenario_id == "synthetic"


# -- properties -------------------------------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(step=st.integers(0, 80), height=st.integers(8, 300), width=st.integers(8, 300), seed=st.integers(0, 2**32 - 1))
def test_synthetic_observations_are_well_formed_and_reproducible(step, height, width, seed):
    obs = synthetic_observation(step, height=height, width=width, seed=seed)
    assert obs.image.shape == (height, width, 3) and obs.image.dtype == np.uint8
    assert np.array_equal(obs.image, synthetic_observation(step, height=height, width=width, seed=seed).image)
    truth = obs.ground_truth
    assert truth.step == obs.step == step and truth.critical().kind == truth.critical_kind == "pedestrian"


words = st.sampled_from(["stop", "Brake", "maintain", "accelerate", "pedestrian", "light", "red", "green", "car",
                         "keep a safe distance", "the", "ahead", "", "stop sign", "vehicle", "yield"])
contexts = st.sampled_from([None, "pedestrian", "car", "traffic_light", "stop_sign", "animal"])


@settings(max_examples=60, deadline=None)
@given(texts=st.lists(st.lists(words, max_size=8).map(" ".join), min_size=1, max_size=6),
       kinds=st.lists(contexts, min_size=6, max_size=6))
def test_the_keyword_labeler_conforms_on_any_text(texts, kinds):
    items = [LabelInput(text=text, context={"critical_kind": kind}) for text, kind in zip(texts, kinds, strict=False)]
    check_labeler(KeywordLabeler(), items, name="keyword")
    for item, labels in zip(items, KeywordLabeler().label_batch(items), strict=True):
        lowered = item.text.lower()
        stops = any(w in lowered for w in ("stop", "brake", "slow", "decelerat", "yield"))
        assert (labels.stated_action == "decelerating") == (stops and "keep a safe distance" not in lowered)
