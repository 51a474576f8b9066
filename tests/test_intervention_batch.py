"""`vdb intervene --batch B`: an intervention's planned episodes advance in lockstep through one model.

On fakes (a keyword model with exact batched forms): the same logs as unbatched, the same bytes run after run
and after an interruption, baseline and selfsplice always in the same batch, the unbatched fallback for a
paradigm or model without the capability, one-line errors. On the `kv` reference model (few steps): the
selfsplice gate holds bit for bit within a batch, closed and open loop.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import intervention_fakes as fakes
import pytest
from vladrivebench import _builtins as core_plugin
from vladrivebench import hookimpl
from vladrivebench._builtins.paradigms.open_loop import OpenLoopParadigm
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec
from vladrivebench._intervention.runs import InterventionConfig, InterventionRun
from vladrivebench._logs.episodes import find_episodes, read_episode
from vladrivebench._scenarios.spec import resolve_scenarios
from vladrivebench.errors import ConfigError, VdbError
from vladrivebench.protocols import BatchedParadigm, Paradigm


class BatchedKeywordModel(fakes.KeywordModel):
    """The keyword model with batched forms computing each row exactly as alone; records every call's rows."""

    CALLS: list[tuple[str, tuple]] = []

    def generate_cot_batch(self, observations, rngs):
        self.CALLS.append(("generate", tuple((o.scenario_id, o.step, o.ego.x) for o in observations)))
        return [self.generate_cot(o, r) for o, r in zip(observations, rngs, strict=True)]

    def splice_cot_batch(self, observations, texts, rngs):
        self.CALLS.append(("splice", tuple((o.scenario_id, o.step) for o in observations)))
        return [self.splice_cot(o, t, r) for o, t, r in zip(observations, texts, rngs, strict=True)]

    def decode_action_batch(self, observations, cots, rngs):
        self.CALLS.append(("decode", tuple((o.scenario_id, o.step) for o in observations)))
        return [self.decode_action(o, c, r) for o, c, r in zip(observations, cots, rngs, strict=True)]


class UnbatchedOpenLoop:
    """The open-loop paradigm without the batched capability (what a third-party paradigm is by default)."""

    name, default_conditions = "plain-open-loop", OpenLoopParadigm.default_conditions

    def __init__(self):
        self.inner = OpenLoopParadigm()

    def check(self, config):
        self.inner.check(config)

    def plan(self, config):
        return self.inner.plan(config)

    def policy(self, episode, context):
        return self.inner.policy(episode, context)

    def analyse(self, config, episodes, gate):
        return self.inner.analyse(config, episodes, gate)

    def tables(self, results):
        return self.inner.tables(results)


class ProbePolicy:
    """A third party's step policy: the own CoT drives; extras hold the gate and the own displacement."""

    def __init__(self, splicer):
        self.splicer = splicer

    def __call__(self, model, obs, seed):
        from vladrivebench.intervention import own_step

        own, trajectory = own_step(model, obs, seed)
        spliced = self.splicer.splice(obs, "selfsplice", self.splicer.injection(self.splicer.resolver(own),
                                                                                "selfsplice"), seed)
        return self.outcome(model, obs, seed, own, trajectory, spliced, self.splicer.decode(obs, spliced, seed))

    def outcome(self, model, obs, seed, own, trajectory, spliced, spliced_trajectory):
        from vladrivebench.intervention import gate_record

        gate = gate_record(model, own, trajectory, spliced, spliced_trajectory, obs, seed)
        return own, trajectory, {"intervention": {"role": "probe", "gate": gate,
                                                  "ahead": trajectory.forward_displacement(2.0)}}


class BatchedProbe:
    """A third party's batched paradigm, written from CONTRIBUTING.md with the public API only."""

    name, default_conditions = "probe", ("selfsplice",)

    def check(self, config):
        pass

    def plan(self, config):
        from vladrivebench.intervention import PlannedEpisode

        return [PlannedEpisode(route, seed, "probe") for route in config.routes for seed in config.seeds]

    def policy(self, episode, context):
        return ProbePolicy(context.splicer)

    def step_batch(self, model, lanes, context):
        from vladrivebench.intervention import selfsplice_many

        sp = context.splicer
        observations, seeds = [lane.obs for lane in lanes], [lane.seed for lane in lanes]
        owns, trajectories = sp.own_many(observations, seeds)
        spliced, spliced_trajectories = selfsplice_many(sp, observations, owns, seeds)
        return [lane.policy.outcome(model, lane.obs, lane.seed, *parts) for lane, parts in
                zip(lanes, zip(owns, trajectories, spliced, spliced_trajectories, strict=True), strict=True)]

    def lockstep_group(self, episode):
        return None

    def analyse(self, config, episodes, gate):
        ahead = {}
        for route in config["routes"]:
            for seed in config["seeds"]:
                episode = episodes.require(route, seed, "probe")
                gate.add_episode(episode, route, seed, "probe")
                ahead[f"{route}/{seed}"] = [s.extras["intervention"]["ahead"] for s in episode.steps]
        return {"probe": ahead}

    def tables(self, results):
        return []


class Plugin:
    @hookimpl
    def register_models(self, register):
        register("keyword-batched", BatchedKeywordModel)

    @hookimpl
    def register_paradigms(self, register):
        register("plain-open-loop", UnbatchedOpenLoop)
        register("probe", BatchedProbe)


@pytest.fixture(scope="module")
def registry():
    return Registry([("core", core_plugin), ("fakes", fakes.Fakes()), ("batched", Plugin())], entry_points=False)


def config(registry, mode="closed-loop", routes=("E.1",), conditions=("selfsplice", "accel", "car"), seeds=3,
           model="keyword-batched", batch=1, max_time_s=2.5, **kw):
    scenarios = tuple(dataclasses.replace(s, max_time_s=max_time_s) for s in resolve_scenarios(list(routes), registry))
    return InterventionConfig(
        mode=mode, model=ComponentSpec("model", model, {}), simulator=ComponentSpec("simulator", "line", {}),
        controller=ComponentSpec("controller", "speed", {}), routes=scenarios, conditions=tuple(conditions),
        seeds=tuple(range(seeds)), batch=batch, **kw)


def run(registry, cfg, out, **kw):
    BatchedKeywordModel.CALLS.clear()
    return InterventionRun(cfg, out, registry=registry, **kw).run()


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


def logged_steps(out: Path) -> dict[str, list]:
    """Every episode's steps (CoT, trajectory, control, extras), without the configuration record."""
    return {p.name: [(s.step, s.cot["text"], s.trajectory["xy"], s.control, s.extras) for s in read_episode(p).steps]
            for p in find_episodes(out)}


def without_batch(results: dict) -> dict:
    return {k: v for k, v in results.items() if k != "batch"}


# -- the paradigm capability ----------------------------------------------------------------------------
def test_the_built_in_paradigms_batch_and_a_plain_paradigm_stays_a_paradigm():
    from vladrivebench._builtins.paradigms.closed_loop import ClosedLoopParadigm
    from vladrivebench._builtins.paradigms.safety import SafetyParadigm

    assert all(isinstance(p(), BatchedParadigm) for p in (OpenLoopParadigm, ClosedLoopParadigm, SafetyParadigm))
    assert isinstance(UnbatchedOpenLoop(), Paradigm) and not isinstance(UnbatchedOpenLoop(), BatchedParadigm)


# -- same logs, same bytes ------------------------------------------------------------------------------
def test_batch_one_is_the_unbatched_run_byte_for_byte(registry, tmp_path):
    cfg = config(registry, seeds=2)
    assert "batch" not in cfg.to_json() and dataclasses.replace(cfg, batch=4).to_json()["batch"] == 4
    run(registry, cfg, tmp_path / "one")
    assert not BatchedKeywordModel.CALLS  # the unbatched path: no batched call at all
    kw = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if f.name != "batch"}
    run(registry, InterventionConfig(**kw), tmp_path / "default")
    assert snapshot(tmp_path / "one") == snapshot(tmp_path / "default")


@pytest.mark.parametrize("mode,conditions,routes", [
    ("closed-loop", ("selfsplice", "accel", "car"), ("E.1",)),
    ("safety", ("accel",), ("SAFE.kerb-ped",)),
    ("open-loop", ("selfsplice", "accel", "pedestrian"), ("E.1", "P.1")),
])
@pytest.mark.parametrize("batch", [2, 5])
def test_lockstep_logs_what_the_unbatched_run_logs_in_batched_calls(registry, tmp_path, mode, conditions, routes,
                                                                      batch):
    unbatched = run(registry, config(registry, mode, routes, conditions, seeds=3), tmp_path / "one")
    batched = run(registry, config(registry, mode, routes, conditions, seeds=3, batch=batch), tmp_path / "b")
    widest = max(len(rows) for _, rows in BatchedKeywordModel.CALLS)
    assert 1 < widest <= batch  # one call serves several episodes, never more than the batch
    assert logged_steps(tmp_path / "b") == logged_steps(tmp_path / "one")
    assert without_batch(batched) == without_batch(unbatched) and batched["valid"]


def test_same_batch_same_bytes_and_an_interrupted_run_resumes_to_the_same_bytes(registry, tmp_path):
    cfg = config(registry, seeds=4, batch=3)
    run(registry, cfg, tmp_path / "a")
    run(registry, cfg, tmp_path / "b")
    assert snapshot(tmp_path / "a") == snapshot(tmp_path / "b")

    class Interrupted(Exception):
        pass

    def stop_after_five(label, done, total):
        if done == 5:
            raise Interrupted(label)

    with pytest.raises(Interrupted):
        run(registry, cfg, tmp_path / "c", progress=stop_after_five)
    partial = {p.name for p in find_episodes(tmp_path / "c")}
    assert 0 < len(partial) < 16  # some episodes done, none half-written left behind as complete
    stale = tmp_path / "c" / "episodes" / "keyword-batched__E.1__s3__car.mcap.999999.partial"
    stale.write_bytes(b"left by a killed run")
    run(registry, cfg, tmp_path / "c")
    assert not stale.exists()
    assert snapshot(tmp_path / "c") == snapshot(tmp_path / "a")


def test_progress_counts_every_planned_episode_once(registry, tmp_path):
    seen = []
    run(registry, config(registry, seeds=2, batch=3), tmp_path, progress=lambda *a: seen.append(a))
    assert [d for _, d, _ in seen] == list(range(1, 9)) and {t for _, _, t in seen} == {8}
    assert len({label for label, _, _ in seen}) == 8


def test_baseline_and_selfsplice_of_a_seed_are_always_in_the_same_batch(registry, tmp_path):
    """They are compared bit for bit; a model whose batched results depend on the batch needs them together."""
    seen = []
    cfg = config(registry, conditions=("accel", "car", "selfsplice"), seeds=3, batch=2)
    InterventionRun(cfg, tmp_path, registry=registry, progress=lambda *a: seen.append(a[0])).run()
    order = [label.rsplit(" ", 1)[1] for label in seen]
    # with a batch of 2, the pair runs alone: baseline and selfsplice finish together, before that seed's others
    for k in range(3):
        assert set(order[4 * k:4 * k + 2]) == {"baseline", "selfsplice"}


def test_a_lockstep_group_joins_only_when_it_fits_and_never_exceeds_the_batch():
    import runner_fakes as rf
    from vladrivebench._engine.runner import LockstepEpisode, run_lockstep

    lengths = [3, 5, 2, 2, 4, 1]
    groups = [None, "g", "g", None, "h", "h"]
    scenarios = [rf.FakeScenario(f"r{i}", length=1000.0, max_time_s=n * rf.DT) for i, n in enumerate(lengths)]
    episodes = [LockstepEpisode(i, s, 0, group=g) for i, (s, g) in enumerate(zip(scenarios, groups, strict=True))]
    model, calls = rf.BatchedEchoModel(), []

    def policy(model, lanes, observations):
        calls.append(tuple(e.key for e in lanes))
        from vladrivebench._engine.runner import own_cot_batch_policy

        return own_cot_batch_policy(model, observations, [e.seed for e in lanes])

    run_lockstep(episodes, 2, make_lane=lambda i: (model, rf.LineSimulator(), rf.SpeedController()),
                 done=lambda *a: None, episode_batch_policy=policy)
    first = {key: next(i for i, c in enumerate(calls) if key in c) for key in range(len(lengths))}
    assert first[1] == first[2] and first[4] == first[5]  # a group joins together
    assert first[3] > first[1] and first[4] > first[3]  # and in the plan's order, the later ones waiting
    assert max(len(c) for c in calls) <= 2
    with pytest.raises(VdbError, match="lockstep group of 2 episodes"):
        run_lockstep(episodes, 1, make_lane=lambda i: (model, rf.LineSimulator(), rf.SpeedController()),
                     done=lambda *a: None)


def test_a_harvested_condition_takes_its_text_from_the_batched_baseline(registry, tmp_path):
    kw = {"routes": ("SAFE.car",), "conditions": ("selfsplice", "origbrake"), "seeds": 2, "max_time_s": 8.0}
    line = ComponentSpec("simulator", "line", {"length": 80.0})
    unbatched = run(registry, dataclasses.replace(config(registry, **kw), simulator=line), tmp_path / "one")
    batched = run(registry, dataclasses.replace(config(registry, batch=4, **kw), simulator=line), tmp_path / "b")
    assert batched["harvested"] and without_batch(batched) == without_batch(unbatched)
    assert logged_steps(tmp_path / "b") == logged_steps(tmp_path / "one")


def test_a_third_party_paradigm_batches_with_the_public_api(registry, tmp_path):
    assert isinstance(BatchedProbe(), BatchedParadigm)
    one = run(registry, config(registry, "probe", ("E.1", "P.1"), ("selfsplice",), seeds=3), tmp_path / "one")
    batched = run(registry, config(registry, "probe", ("E.1", "P.1"), ("selfsplice",), seeds=3, batch=4),
                  tmp_path / "b")
    assert max(len(rows) for _, rows in BatchedKeywordModel.CALLS) == 4
    assert without_batch(batched) == without_batch(one) and batched["valid"] and batched["gate"]["steps_checked"]
    assert logged_steps(tmp_path / "b") == logged_steps(tmp_path / "one")


# -- the unbatched fallback ---------------------------------------------------------------------------
def test_a_paradigm_or_model_without_the_capability_runs_as_today(registry, tmp_path):
    cases = [("plain-open-loop", "keyword-batched"), ("closed-loop", "keyword")]
    for mode, model in cases:
        one = run(registry, config(registry, mode, conditions=("selfsplice", "accel"), seeds=2, model=model),
                  tmp_path / f"{mode}-{model}-1")
        four = run(registry, config(registry, mode, conditions=("selfsplice", "accel"), seeds=2, model=model, batch=4),
                   tmp_path / f"{mode}-{model}-4")
        assert all(len(rows) == 1 for _, rows in BatchedKeywordModel.CALLS)
        assert without_batch(four) == without_batch(one)
        assert logged_steps(tmp_path / f"{mode}-{model}-4") == logged_steps(tmp_path / f"{mode}-{model}-1")


def test_a_batch_the_run_cannot_use_is_said_once_on_stderr_and_the_results_are_unchanged(registry, tmp_path):
    import json

    from click.testing import CliRunner
    from vladrivebench._cli.main import cli
    from vladrivebench._engine import registry as plugins

    base = ["intervene", "--sim", "line", "--controller", "speed", "--route", "E.1", "--seeds", "2", "--quiet", "--json"]
    run_one_at_a_time = "episodes run one at a time\n"
    cases = {
        ("closed-loop", "keyword"): f"note: model 'keyword' has no batched forms; its {run_one_at_a_time}",
        ("plain-open-loop", "keyword-batched"):
            f"note: paradigm 'plain-open-loop' has no batched step (BatchedParadigm); its {run_one_at_a_time}",
        ("plain-open-loop", "keyword"): f"note: paradigm 'plain-open-loop' has no batched step (BatchedParadigm) and "
                                        f"model 'keyword' has no batched forms; the {run_one_at_a_time}",
        ("closed-loop", "keyword-batched"): "",  # lockstep: nothing to say
    }
    previous = plugins.set_registry(registry)
    try:
        runner = CliRunner()
        for (mode, model), note in cases.items():
            def invoke(batch, mode=mode, model=model):
                return runner.invoke(cli, [*base, "--mode", mode, "--model", model, "--batch", batch, "--out",
                                           str(tmp_path / f"{mode}-{model}-{batch}")])
            four, one = invoke("4"), invoke("1")
            assert four.exit_code == 0 and one.exit_code == 0, (four.output, one.output)
            assert four.stderr == note and one.stderr == ""
            assert without_batch(json.loads(four.stdout)) == without_batch(json.loads(one.stdout))
    finally:
        plugins.set_registry(previous)


# -- errors ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [0, -1, True, 2.5, "4"])
def test_a_bad_batch_in_the_configuration_is_one_line(registry, value):
    with pytest.raises(ConfigError, match="--batch must be a whole number"):
        config(registry, batch=value)


@pytest.mark.parametrize("value", ["0", "-1", "x", "1.5", ""])
def test_a_bad_batch_on_the_command_line_is_one_line_and_writes_nothing(capsys, tmp_path, value):
    code, _, err = fakes.vdb(capsys, "intervene", "--model", "scripted", "--route", "E.1", "--mode", "closed-loop",
                             "--seeds", "1", "--batch", value, "--out", tmp_path / "out")
    fakes.one_line_error(code, err, "--batch must be a whole number")
    assert not (tmp_path / "out").exists()


def test_a_batch_larger_than_the_run_is_fine(registry, tmp_path):
    one = run(registry, config(registry, seeds=2), tmp_path / "one")
    huge = run(registry, config(registry, seeds=2, batch=1000), tmp_path / "huge")
    assert without_batch(huge) == without_batch(one)


def test_a_condition_the_model_refuses_in_a_batch_names_the_condition(registry, tmp_path):
    class Refusing(BatchedKeywordModel):
        def splice_cot(self, obs, text, rng):
            if obs.step == 3 and "accelerate" in str(text).lower():
                raise ValueError("no accelerating at step 3")
            return super().splice_cot(obs, text, rng)

    class RefusingPlugin:
        @hookimpl
        def register_models(self, register):
            register("refusing", Refusing)

    reg = Registry([("core", core_plugin), ("fakes", fakes.Fakes()), ("r", RefusingPlugin())], entry_points=False)
    with pytest.raises(VdbError, match="condition 'accel'.*no accelerating at step 3"):
        InterventionRun(config(reg, model="refusing", batch=4), tmp_path, registry=reg).run()
    assert not list(tmp_path.rglob("*.mcap"))  # the batch's half-written logs are removed, none left as if whole


# -- the kv reference model: the gate holds bit for bit within a batch ----------------------------------
@pytest.fixture(scope="module")
def installed():
    pytest.importorskip("vdb_model_neural")
    from vladrivebench._engine.registry import get_registry

    return get_registry()


def kv_config(registry, mode, conditions, batch, seeds=2, max_time_s=0.8):
    routes = tuple(dataclasses.replace(s, max_time_s=max_time_s) for s in resolve_scenarios(["E.1"], registry))
    return InterventionConfig(mode=mode, model=ComponentSpec("model", "kv", {}),
                              simulator=ComponentSpec("simulator", "kinematic", {}),
                              controller=ComponentSpec("controller", "pid", {}), routes=routes,
                              conditions=conditions, seeds=tuple(range(seeds)), batch=batch)


@pytest.mark.parametrize("mode,conditions", [("closed-loop", ("selfsplice", "accel")),
                                             ("open-loop", ("selfsplice", "accel"))])
def test_kv_selfsplice_gate_holds_bit_for_bit_within_a_batch(installed, tmp_path, mode, conditions):
    results = InterventionRun(kv_config(installed, mode, conditions, batch=4), tmp_path / "b",
                              registry=installed).run()
    gate = results["gate"]
    assert results["valid"] and gate["steps_checked"] > 0
    assert gate["digest_mismatches"] == 0 and gate["max_trajectory_diff"] == 0.0 and not gate["episode_mismatches"]
    unbatched = InterventionRun(kv_config(installed, mode, conditions, batch=1), tmp_path / "one",
                                registry=installed).run()
    assert unbatched["valid"]
    worst = max_trajectory_difference(tmp_path / "b", tmp_path / "one")
    assert worst < 1e-3  # batched and unbatched differ in floating point only (measured ~1e-6 m)


def max_trajectory_difference(a: Path, b: Path) -> float:
    """The largest waypoint difference (m) between the same steps of two runs' logs (open-loop: same drive)."""
    import numpy as np

    worst = 0.0
    for pa, pb in zip(find_episodes(a), find_episodes(b), strict=True):
        for sa, sb in zip(read_episode(pa).steps, read_episode(pb).steps, strict=False):
            if sa.step == 0:
                worst = max(worst, float(np.max(np.abs(np.asarray(sa.trajectory["xy"]) - np.asarray(sb.trajectory["xy"])))))
    return worst


def test_the_command_line_batch_is_configuration_and_too_large_is_fine(capsys, tmp_path):
    import json

    from vladrivebench._scenarios.spec import resolve_scenarios as resolve

    spec = {**resolve(["E.1"])[0].to_json(), "id": "E.1-short", "max_time_s": 1.0}
    route = tmp_path / "short.json"
    route.write_text(json.dumps(spec), encoding="utf-8")
    args = ["intervene", "--model", "scripted", "--route", route, "--mode", "closed-loop", "--conditions",
            "selfsplice", "--seeds", "1", "--checkpoints", "0.5", "--quiet"]
    code, _, err = fakes.vdb(capsys, *args, "--batch", "1000", "--out", tmp_path / "huge")
    assert code == 0, err
    assert json.loads((tmp_path / "huge" / "run.json").read_text())["config"]["batch"] == 1000
    code, _, err = fakes.vdb(capsys, *args, "--batch", "1", "--out", tmp_path / "one")
    assert code == 0, err
    assert "batch" not in json.loads((tmp_path / "one" / "run.json").read_text())["config"]
    code, _, err = fakes.vdb(capsys, *args, "--batch", "2", "--out", tmp_path / "huge")  # another configuration
    fakes.one_line_error(code, err, "different configuration")
