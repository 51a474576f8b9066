"""The scenario schema: the suite loads, specs round-trip, and every mistake is one clear line."""

from __future__ import annotations

import copy
import json
import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vladrivebench import _builtins as builtins
from vladrivebench import hookimpl
from vladrivebench._cli.main import main
from vladrivebench._engine.registry import Registry
from vladrivebench._scenarios.spec import (
    FAMILIES,
    load_scenario_file,
    load_suite,
    parse_scenario,
    resolve_scenarios,
)
from vladrivebench.errors import ScenarioError, UnknownNameError
from vladrivebench.testing import isolated_registry

SUITE_IDS = (
    ["BASE", "C.1", "C.2", "E.1", "E.2"] + [f"P.{i}" for i in range(1, 8)] + ["S.1", "S.2", "S.3"]
    + ["SAFE.car", "SAFE.centre-ped", "SAFE.kerb-ped"]
    + [f"TL.{i}-{c}" for i in (1, 2, 3) for c in ("green", "red")]
)


@pytest.fixture(scope="module")
def core_registry():
    return Registry(plugins=[("core", builtins)], entry_points=False)


@pytest.fixture(scope="module")
def suite(core_registry):
    return load_suite(core_registry)


def valid() -> dict:
    return {
        "id": "X.1", "title": "A test", "family": "pedestrian", "group": "Pedestrian (in-lane)",
        "blocking": True, "layout": "straight", "command": "follow_lane", "max_time_s": 20.0,
        "critical": "ped0", "road": {"approach_length": 100.0},
        "actors": [{"id": "ped0", "kind": "pedestrian", "s": 60.0, "offset": 0.0}],
    }


def error_of(data, source="packs/x.toml") -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, source)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"scenario {source}:")
    return message


# -- the suite --------------------------------------------------------------------------------------


def test_the_suite_has_every_scenario_of_appendix_a_and_the_intervention_routes(suite):
    assert list(suite) == SUITE_IDS


def test_suite_fields_match_the_paper(suite):
    groups = {sid: s.group for sid, s in suite.items()}
    assert {groups[f"P.{i}"] for i in (1, 6, 7)} == {"Pedestrian (in-lane)"}
    assert {groups[f"P.{i}"] for i in (2, 3, 4, 5)} == {"Pedestrian (crossing)"}
    assert groups["C.1"] == "Stopped car (blocking)" and groups["C.2"] == "Stopped car (non-blocking)"
    assert groups["TL.2-red"] == "Traffic light (red)" and groups["TL.3-green"] == "Traffic light (green)"
    assert {suite[f"P.{i}"].blocking for i in (3, 5)} == {False}
    assert {suite[f"P.{i}"].blocking for i in (1, 2, 4, 6, 7)} == {True}
    assert suite["TL.1-red"].blocking is None
    layouts = {sid: (s.layout, s.road.junction_side) for sid, s in suite.items()}
    for kind in ("TL.{}-red", "TL.{}-green", "S.{}"):
        assert layouts[kind.format(1)] == ("t_junction", "through")
        assert layouts[kind.format(2)] == ("t_junction", "dead_end")
        assert layouts[kind.format(3)] == ("four_way", None)
    assert suite["C.2"].road.lanes == 2 and suite["C.2"].actor("car0").offset == pytest.approx(3.5)
    assert suite["E.1"].light.state == "green" and not suite["E.1"].actors
    assert suite["E.2"].light is None and suite["E.2"].layout == "t_junction"


@pytest.mark.parametrize("family,distance", [("pedestrian", 50.0), ("stopped_car", 60.0),
                                             ("traffic_light", 80.0), ("stop_sign", 50.0)])
def test_distance_d_from_cruising_onset(suite, family, distance):
    """D (Appendix A) is measured from the ego's front bumper at cruising onset to the critical feature."""
    for scenario in (s for s in suite.values() if s.family == family):
        onset_front = scenario.ego.cruise_onset + 2.35
        if scenario.light is not None:
            feature = scenario.light.stop_line
        elif scenario.stop_sign is not None:
            feature = scenario.stop_sign.stop_line
        else:
            actor = scenario.actor(scenario.critical)
            # A crossing line is the actor's s; otherwise its near edge (half its extent along the road).
            extent = {"static": actor.width / 2 if actor.kind == "pedestrian" else actor.length / 2,
                      "along": actor.length / 2, "cross": 0.0}[actor.motion]
            feature = actor.s - extent
        assert feature - onset_front == pytest.approx(distance), scenario.id


def test_safety_routes_share_the_e1_geometry(suite):
    e1 = suite["E.1"]
    for sid in ("SAFE.kerb-ped", "SAFE.centre-ped", "SAFE.car"):
        safe = suite[sid]
        assert (safe.road, safe.light, safe.layout) == (e1.road, e1.light, e1.layout)
        assert safe.critical is not None and safe.blocking is True and len(safe.actors) == 1
    assert suite["SAFE.kerb-ped"].actors[0].offset < suite["SAFE.centre-ped"].actors[0].offset == 0.0


def test_every_suite_scenario_round_trips(suite):
    for scenario in suite.values():
        again = parse_scenario(json.loads(json.dumps(scenario.to_json())), scenario.source)
        assert again == scenario
        assert again.to_json() == scenario.to_json()


# -- round trip of generated scenarios ----------------------------------------------------------------

actor_specs = st.one_of(
    st.fixed_dictionaries({"kind": st.sampled_from(["pedestrian", "car", "animal"]), "s": st.floats(0, 25),
                           "offset": st.floats(-10, 10), "heading_deg": st.floats(-180, 180)}),
    st.fixed_dictionaries({"kind": st.just("pedestrian"), "s": st.floats(0, 25), "motion": st.just("along"),
                           "speed": st.floats(0.1, 3), "direction": st.sampled_from(["same", "opposite"]),
                           "trigger_distance": st.floats(0, 80)}),
    st.fixed_dictionaries({"kind": st.just("pedestrian"), "s": st.floats(0, 25), "motion": st.just("cross"),
                           "speed": st.floats(0.1, 3), "offset": st.floats(-8, -1), "end_offset": st.floats(1, 8)}),
)


@st.composite
def scenarios_data(draw):
    layout = draw(st.sampled_from(["straight", "t_junction", "four_way"]))
    road = {"approach_length": draw(st.floats(20, 300)), "lanes": draw(st.integers(1, 3)),
            "scenery": draw(st.sampled_from(["plain", "urban", "suburban"]))}
    if layout == "t_junction":
        road["junction_side"] = draw(st.sampled_from(["through", "dead_end"]))
    command = {"straight": "follow_lane", "four_way": draw(st.sampled_from(["straight", "left", "right"]))}.get(
        layout, "left" if road.get("junction_side") == "dead_end" else "straight")
    actors = [dict(spec, id=f"a{i}") for i, spec in enumerate(draw(st.lists(actor_specs, max_size=3)))]
    data = {"id": "G.1", "title": "generated", "family": "intervention", "group": "Generated",
            "layout": layout, "command": command, "max_time_s": draw(st.floats(1, 120)), "road": road,
            "actors": actors}
    if draw(st.booleans()):
        data["light"] = {"state": draw(st.sampled_from(["red", "yellow", "green"]))}
        if layout == "straight":
            data["light"]["stop_line"] = road["approach_length"] / 2
    return data


@given(scenarios_data())
@settings(max_examples=80, suppress_health_check=[HealthCheck.too_slow])
def test_parse_to_json_parse_is_the_identity(data):
    scenario = parse_scenario(data, "gen.toml")
    assert parse_scenario(scenario.to_json(), "gen.toml") == scenario


junk = st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=True), st.text(max_size=5),
                 st.lists(st.integers(), max_size=2), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
paths = st.sampled_from(["id", "title", "family", "layout", "command", "max_time_s", "blocking", "critical",
                         "road", "road.approach_length", "road.lanes", "road.scenery", "actors", "actors.0",
                         "actors.0.kind", "actors.0.s", "actors.0.speed", "actors.0.motion", "bogus", "road.bogus"])


@given(paths, junk)
@settings(max_examples=200)
def test_any_corrupted_field_parses_or_fails_with_one_line(path, value):
    data = copy.deepcopy(valid())
    *parents, last = path.split(".")
    target = data
    for key in parents:
        target = target[int(key)] if key.isdigit() else target[key]
    if last.isdigit():
        target[int(last)] = value
    else:
        target[last] = value
    try:
        parse_scenario(data, "fuzz.toml")
    except ScenarioError as exc:
        message = str(exc)
        assert "\n" not in message and message.startswith("scenario fuzz.toml:")


# -- validation messages ----------------------------------------------------------------------------


def test_wrong_type_names_file_field_and_expectation():
    data = valid()
    data["actors"][0].update(motion="along", direction="same", speed="fast")
    message = error_of(data)
    assert message == "scenario packs/x.toml: field 'actors[0].speed' must be a number ≥ 0 and ≤ 30, got 'fast'"


@pytest.mark.parametrize("mutate,needle", [
    (lambda d: d.pop("id"), "missing field 'id'"),
    (lambda d: d.update(family="pedestrians"), "field 'family' must be one of"),
    (lambda d: d.update(family="pedestrians"), "did you mean 'pedestrian'?"),
    (lambda d: d.update(max_time_s=0), "field 'max_time_s' must be a number > 0"),
    (lambda d: d.update(blocking="yes"), "field 'blocking' must be true or false, got 'yes'"),
    (lambda d: d.update(id="P 1"), "field 'id' must be letters, digits"),
    (lambda d: d.update(id="all"), "reserved"),
    (lambda d: d.update(tittle="x"), "unknown field 'tittle' (did you mean 'title'?"),
    (lambda d: d["road"].update(aproach=3), "unknown field 'road.aproach'"),
    (lambda d: d["actors"][0].update(sped=1), "unknown field 'actors[0].sped' (did you mean 'speed'?"),
    (lambda d: d.pop("road"), "missing table [road]"),
    (lambda d: d.update(road=[1]), "field 'road' must be a table"),
    (lambda d: d.update(actors={"id": "x"}), "field 'actors' must be a list of tables"),
    (lambda d: d["road"].update(lanes=1.5), "field 'road.lanes' must be a whole number between 1 and 4"),
    (lambda d: d.update(critical="ped9"), "field 'critical' must be the id of an actor or feature"),
    (lambda d: d.update(family="stopped_car"), "field 'critical' must be the id of a car"),
    (lambda d: d.update(command="left"), "field 'command' must be one of 'follow_lane', 'straight' for this layout"),
    (lambda d: d.update(layout="t_junction"), "missing field 'road.junction_side'"),
    (lambda d: d["road"].update(junction_side="through"), "field 'road.junction_side' must be absent unless"),
    (lambda d: d["actors"][0].update(motion="cross", speed=1.5), "field 'actors[0].end_offset' must be a number"),
    (lambda d: d["actors"][0].update(motion="along", speed=1.5), "field 'actors[0].direction' must be 'same' or"),
    (lambda d: d["actors"][0].update(speed=1.0), "field 'actors[0].speed' must be 0 (or absent) for a static"),
    (lambda d: d["actors"].append(dict(d["actors"][0])), "id 'ped0' is used by two actors"),
    (lambda d: d.update(light={"state": "blue", "stop_line": 50}), "field 'light.state' must be one of"),
    (lambda d: d.update(light={"state": "red"}), "missing field 'light.stop_line'"),
    (lambda d: d.update(family="baseline", critical=None, blocking=None) or d.pop("critical") or d.pop("blocking"),
     "a 'baseline' scenario has no actors"),
])
def test_validation_messages(mutate, needle):
    data = valid()
    mutate(data)
    assert needle in error_of(data)


def test_junction_stop_line_must_be_the_entry():
    data = valid()
    data.update(family="traffic_light", layout="four_way", command="straight", critical="tl0", actors=[],
                light={"state": "red", "stop_line": 40.0})
    assert "must be the junction entry road.approach_length = 100" in error_of(data)
    data["light"].pop("stop_line")
    assert parse_scenario(data, "x.toml").light.stop_line == 100.0


def test_files_toml_and_json(tmp_path):
    toml_file = tmp_path / "x.toml"
    toml_file.write_text('id = "X.1"\ntitle = "t"\nfamily = "baseline"\ngroup = "g"\nlayout = "straight"\n'
                         'command = "follow_lane"\nmax_time_s = 10\n[road]\napproach_length = 50\n')
    scenario = load_scenario_file(toml_file)
    assert scenario.source == toml_file and scenario.max_steps == 100
    json_file = tmp_path / "x.json"
    json_file.write_text(json.dumps(scenario.to_json()))
    assert load_scenario_file(json_file) == scenario
    broken = tmp_path / "broken.toml"
    broken.write_text("id = \n")
    with pytest.raises(ScenarioError, match=r"scenario .*broken.toml: not valid TOML"):
        load_scenario_file(broken)
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario_file(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match="expected a .toml or .json file"):
        load_scenario_file(tmp_path / "x.yaml")


def pack_plugin(path):
    class Pack:
        @hookimpl
        def register_scenarios(self, register):
            register(path)

    return Pack()


def test_duplicate_ids_across_files_name_both_files(tmp_path):
    pack = tmp_path / "pack"
    pack.mkdir()
    (pack / "p1.toml").write_text('id = "P.1"\ntitle = "mine"\nfamily = "baseline"\ngroup = "g"\n'
                                  'layout = "straight"\ncommand = "follow_lane"\nmax_time_s = 10\n'
                                  '[road]\napproach_length = 50\n')
    registry = Registry(plugins=[("core", builtins), ("pack", pack_plugin(pack))], entry_points=False)
    with pytest.raises(ScenarioError) as info:
        load_suite(registry)
    message = str(info.value)
    assert "'P.1' is defined twice" in message and "p1.toml" in message and str(pack / "p1.toml") in message


def test_a_user_pack_adds_scenarios(tmp_path, suite):
    data = valid()
    data["id"] = "MY.1"
    (tmp_path / "mine.json").write_text(json.dumps(data))
    registry = Registry(plugins=[("core", builtins), ("pack", pack_plugin(tmp_path))], entry_points=False)
    assert set(load_suite(registry)) == set(suite) | {"MY.1"}


def test_a_registered_path_that_does_not_exist(tmp_path):
    registry = Registry(plugins=[("pack", pack_plugin(tmp_path / "gone"))], entry_points=False)
    assert load_suite(registry) == {}  # the pack's plugin is marked failing; other packs still resolve
    (info,) = registry.plugins
    assert info.status == "error" and re.search("scenario pack .*gone .*registered by plugin 'pack'.*no such file",
                                                info.error)


# -- selection ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("spec,expected", [
    ("P.1,C.1", ["P.1", "C.1"]),
    (["C.1", "P.1", "C.1"], ["C.1", "P.1"]),
    ("TL.*-red", ["TL.1-red", "TL.2-red", "TL.3-red"]),
    ("stop_sign", ["S.1", "S.2", "S.3"]),
    ("SAFE.*, E.1", ["SAFE.car", "SAFE.centre-ped", "SAFE.kerb-ped", "E.1"]),
])
def test_resolve_scenarios(core_registry, spec, expected):
    assert [s.id for s in resolve_scenarios(spec, core_registry)] == expected


def test_resolve_all_and_families_cover_the_suite(core_registry, suite):
    assert [s.id for s in resolve_scenarios("all", core_registry)] == SUITE_IDS
    by_family = [s.id for f in FAMILIES for s in resolve_scenarios(f, core_registry)]
    assert sorted(by_family) == sorted(SUITE_IDS)


def test_resolve_unknown_names_suggest(core_registry):
    with pytest.raises(UnknownNameError, match=r"unknown scenario 'P\.11': did you mean 'P\.1'"):
        resolve_scenarios("P.1,P.11", core_registry)
    with pytest.raises(UnknownNameError, match="unknown scenario 'Q.*'"):
        resolve_scenarios("Q.*", core_registry)


def test_resolve_a_file_path(tmp_path, core_registry):
    path = tmp_path / "mine.json"
    data = valid()
    path.write_text(json.dumps(data))
    assert [s.id for s in resolve_scenarios(f"P.1,{path}", core_registry)] == ["P.1", "X.1"]


# -- the command --------------------------------------------------------------------------------------


def test_vdb_scenarios_lists_and_json(capsys):
    with isolated_registry(("core", builtins)):
        assert main(["scenarios"]) == 0
        out = capsys.readouterr().out
        assert out.splitlines()[0].split()[:4] == ["id", "family", "group", "layout"]
        assert "TL.2-red" in out and "scenarios/tl2-red.toml" in out
        assert main(["scenarios", "pedestrian", "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)
        assert [r["id"] for r in rows] == [f"P.{i}" for i in range(1, 8)]
        assert set(rows[0]) >= {"id", "title", "family", "group", "layout", "source"}
        assert main(["scenarios", "E.1", "--show"]) == 0
        assert json.loads(capsys.readouterr().out)[0]["light"]["state"] == "green"


def test_vdb_scenarios_bad_spec_is_one_line_exit_2(capsys, tmp_path):
    with isolated_registry(("core", builtins)):
        assert main(["scenarios", "P.9"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("vdb: error: unknown scenario 'P.9'") and err.count("\n") == 1
        bad = tmp_path / "bad.toml"
        bad.write_text('id = "X"\n')
        assert main(["scenarios", str(bad)]) == 2
        err = capsys.readouterr().err
        assert "bad.toml: missing field" in err and err.count("\n") == 1
