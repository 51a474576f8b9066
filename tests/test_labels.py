"""Label contexts, keys, the label store, JSONL in/out and Cohen's κ."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from statsmodels.stats.inter_rater import cohens_kappa
from vladrivebench._analysis.labels import (
    NO_GROUP,
    LabelStore,
    agreement,
    agreement_by,
    category,
    cohen_kappa,
    content_key,
    context_from_step,
    label_input,
    label_key,
    labels_from_json,
    load_label_source,
    read_jsonl,
    source_agreement,
    write_jsonl,
)
from vladrivebench.errors import ConfigError, LogError
from vladrivebench.records import LabelInput, Labels


def ego(x=0.0, y=0.0, yaw=0.0, speed=5.0):
    return {"x": x, "y": y, "yaw": yaw, "speed": speed}


def truth(actors=(), critical=None, **extra):
    base = {"actors": list(actors), "critical_id": critical, "critical_kind": None, "distance_to_critical": None,
            "blocking": False, "light_state": None, "lead_gap": None, "lead_speed": None}
    base.update(extra)
    return base


def actor(actor_id, kind, x, y, speed=0.0, state=None):
    return {"actor_id": actor_id, "kind": kind, "x": x, "y": y, "speed": speed, "state": state}


# -- context --------------------------------------------------------------------------------------------
def test_context_puts_actors_in_the_ego_frame():
    context = context_from_step(ego(10.0, 5.0, math.pi / 2, 3.0),
                                truth([actor("p", "pedestrian", 10.0, 25.0)], "p", critical_kind="pedestrian"))
    assert context["critical_position"] == [20.0, 0.0]
    assert context["actors"][0]["position"] == [20.0, 0.0] and context["ego_speed"] == 3.0


@settings(max_examples=100)
@given(x=st.floats(-500, 500), y=st.floats(-500, 500), yaw=st.floats(-math.pi, math.pi),
       forward=st.floats(-80, 80), left=st.floats(-20, 20))
def test_context_is_invariant_to_where_the_scene_is_in_the_world(x, y, yaw, forward, left):
    wx = x + math.cos(yaw) * forward - math.sin(yaw) * left
    wy = y + math.sin(yaw) * forward + math.cos(yaw) * left
    context = context_from_step(ego(x, y, yaw), truth([actor("c", "car", wx, wy)], "c", critical_kind="car"))
    got = context["critical_position"]
    assert abs(got[0] - forward) <= 0.011 and abs(got[1] - left) <= 0.011


def test_context_without_pose_is_a_log_error():
    with pytest.raises(LogError, match="pose"):
        context_from_step({"speed": 1.0}, truth())


def test_label_input_joins_slots_when_the_log_has_no_text():
    item = label_input({"slots": {"scene": "A.", "decision": "Stop."}}, {})
    assert item.text == "A. Stop." and item.slots == {"scene": "A.", "decision": "Stop."}


# -- keys -----------------------------------------------------------------------------------------------------
@settings(max_examples=50)
@given(text=st.text(max_size=40), speed=st.floats(0, 10), version=st.text(min_size=1, max_size=5))
def test_keys_depend_on_text_context_labeler_and_version(text, speed, version):
    item = LabelInput(text=text, context={"ego_speed": speed})
    key = label_key(item, "lexicon", version)
    assert key == label_key(LabelInput(text=text, context={"ego_speed": speed}), "lexicon", version)
    assert key != label_key(item, "lexicon", version + "x")
    assert key != label_key(item, "other", version)
    assert key != label_key(LabelInput(text=text + " ", context={"ego_speed": speed}), "lexicon", version)
    assert content_key(item) != content_key(LabelInput(text=text, context={"ego_speed": speed + 1.0}))


# -- store -----------------------------------------------------------------------------------------------------
def test_store_appends_reloads_and_finds_latest_by_content(tmp_path):
    store = LabelStore(tmp_path, "fake")
    item = LabelInput(text="Stop.", context={"critical_kind": None})
    store.add([(item, label_key(item, "fake", "1"), Labels("decelerating"))], "1")
    store.add([(item, label_key(item, "fake", "2"), Labels("maintaining"))], "2")
    again = LabelStore(tmp_path, "fake")
    assert len(again) == 2 and again.latest(content_key(item)).version == "2"
    assert again.get(label_key(item, "fake", "1")).stated_action == "decelerating"


def test_store_survives_a_torn_last_line(tmp_path):
    store = LabelStore(tmp_path, "fake")
    first, second = LabelInput(text="a"), LabelInput(text="b")
    store.add([(first, label_key(first, "fake", "1"), Labels())], "1")
    with store.path.open("a") as fh:
        fh.write('{"key": "torn')  # a writer killed mid-line
    reloaded = LabelStore(tmp_path, "fake")
    assert len(reloaded) == 1 and reloaded.skipped_lines == 1
    reloaded.add([(second, label_key(second, "fake", "1"), Labels())], "1")
    lines = reloaded.path.read_text().splitlines()
    assert len(lines) == 2 and all(json.loads(line) for line in lines)


# -- labels json --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("data", "message"), [
    ({"stated_action": "hover"}, "stated_action 'hover'"),
    ({"light_colour": "blue"}, "light_colour 'blue'"),
    ({"hallucination": "yes"}, "hallucination must be true or false"),
    ({"target_mentioned": 1.5}, "target_mentioned"),
    ({"colour": "red"}, "unknown label field 'colour'"),
])
def test_bad_labels_are_one_line_errors(data, message):
    with pytest.raises(ConfigError, match=message):
        labels_from_json(data, "f.jsonl:3")


# -- JSONL --------------------------------------------------------------------------------------------------------
def test_jsonl_round_trip(tmp_path):
    src = tmp_path / "in.jsonl"
    src.write_text('{"id": "a", "text": "Stop.", "context": {"critical_kind": null}}\n'
                   '{"id": 2, "slots": {"scene": "Clear.", "decision": "Go."}, "note": "mine"}\n')
    items = read_jsonl(src)
    assert [i.id for i in items] == ["a", "2"] and items[1].item.text == "Clear. Go."
    out = tmp_path / "out.jsonl"
    write_jsonl(out, items, [Labels("decelerating"), Labels("maintaining")])
    back = read_jsonl(out, need_labels=True)
    assert back[1].labels.stated_action == "maintaining" and back[1].extra == {"note": "mine"}
    assert back[1].item.slots == {"scene": "Clear.", "decision": "Go."}


@pytest.mark.parametrize(("content", "message"), [
    ("not json\n", r"f\.jsonl:1: not valid JSON"),
    ('[1, 2]\n', "expected a JSON object"),
    ('{"id": "a"}\n', 'needs "text"'),
    ('{"text": 3}\n', "text must be a string"),
    ('{"text": "a", "slots": ["x"]}\n', "slots must be an object"),
    ('{"text": "a", "context": {"ego_speed": "fast"}}\n', r"context\.ego_speed has the wrong type"),
    ('{"id": 1, "text": "a"}\n{"id": 1, "text": "b"}\n', "duplicate id '1'"),
    ("\n\n", "no CoTs"),
])
def test_bad_jsonl_is_one_line_naming_file_and_line(tmp_path, content, message):
    path = tmp_path / "f.jsonl"
    path.write_text(content)
    with pytest.raises(ConfigError, match=message) as info:
        read_jsonl(path)
    assert "\n" not in str(info.value)


def test_label_file_needs_labels_on_every_line(tmp_path):
    path = tmp_path / "f.jsonl"
    path.write_text('{"id": 1, "text": "a", "labels": {}}\n{"id": 2, "text": "b"}\n')
    with pytest.raises(ConfigError, match=r"f\.jsonl:2: no \"labels\""):
        read_jsonl(path, need_labels=True)


# -- agreement --------------------------------------------------------------------------------------------------------
cats = st.sampled_from(["decelerating", "maintaining", "accelerating", "none"])


@settings(max_examples=100)
@given(pairs=st.lists(st.tuples(cats, cats), min_size=2, max_size=60))
def test_kappa_matches_statsmodels_on_the_confusion_table(pairs):
    result = cohen_kappa(pairs)
    assert sum(map(sum, result.confusion)) == len(pairs)
    assert result.agreement == pytest.approx(sum(a == b for a, b in pairs) / len(pairs))
    if len(result.categories) > 1:
        expected = cohens_kappa([list(r) for r in result.confusion], return_results=False)
        if math.isfinite(expected):
            assert result.kappa == pytest.approx(expected)


def test_kappa_by_hand():
    # 20 items: 8 yes/yes, 2 yes/no, 1 no/yes, 9 no/no → po = 0.85, pe = 0.5·0.45 + 0.5·0.55 = 0.5
    pairs = [("yes", "yes")] * 8 + [("yes", "no")] * 2 + [("no", "yes")] * 1 + [("no", "no")] * 9
    assert cohen_kappa(pairs).kappa == pytest.approx((0.85 - 0.5) / 0.5)


def test_agreement_reports_missing_and_unlabelled_items():
    a = {"1": Labels("decelerating", hallucination=True), "2": Labels("maintaining"), "3": Labels(), "4": Labels()}
    b = {"1": Labels("decelerating", hallucination=True), "2": Labels("accelerating"),
         "3": Labels(unlabelled="timeout"), "5": Labels()}
    report = agreement(a, b)
    assert report.compared == 2 and report.only_in_a == ("4",) and report.only_in_b == ("5",)
    assert report.unlabelled == ("3",)
    action = next(p for p in report.properties if p.prop == "stated_action")
    assert action.n == 2 and action.agreement == 0.5
    single = next(p for p in report.properties if p.prop == "contradiction")
    assert single.kappa is None and "one category" in single.note


def test_category_names():
    assert category("target_mentioned", Labels(target_mentioned=None)) == "n/a"
    assert category("hallucination", Labels(hallucination=True)) == "yes"
    assert category("light_colour", Labels()) == "none"


# -- missing labels and agreement per group --------------------------------------------------------------------------
FULL = {"stated_action": "decelerating", "target_mentioned": True, "mention_slot": None, "light_colour": None,
        "hallucination": False, "contradiction": False}


def write_label_file(path, rows):
    path.write_text("".join(json.dumps(row) + "\n" for row in rows), encoding="utf-8")
    return path


def label_rows(n, labels, **fields):
    return [{"id": f"i{i}", "text": "Stop for the pedestrian.", "labels": dict(labels), **fields} for i in range(n)]


def test_empty_labels_are_missing_never_none_or_false(tmp_path):
    gold = load_label_source(write_label_file(tmp_path / "gold.jsonl", label_rows(8, FULL)))
    empty = load_label_source(write_label_file(tmp_path / "empty.jsonl", label_rows(8, {})))
    report = source_agreement(gold, empty)
    assert report.compared == 8
    for prop in report.properties:
        assert prop.n == 0 and prop.agreement is None and prop.kappa is None
        assert prop.missing_a == 0 and prop.missing_b == 8 and "missing" in prop.note


def test_one_missing_property_leaves_only_that_property_out(tmp_path):
    partial = dict(FULL)
    del partial["hallucination"]
    rows = label_rows(6, FULL)
    rows[2]["labels"] = partial
    gold = load_label_source(write_label_file(tmp_path / "gold.jsonl", label_rows(6, FULL)))
    other = load_label_source(write_label_file(tmp_path / "other.jsonl", rows))
    by_prop = {p.prop: p for p in source_agreement(gold, other).properties}
    assert by_prop["hallucination"].n == 5 and by_prop["hallucination"].missing_b == 1
    assert by_prop["stated_action"].n == 6 and by_prop["stated_action"].missing_b == 0
    assert by_prop["hallucination"].agreement == 1.0  # the missing one is not counted as "no"


@settings(max_examples=50, deadline=None)
@given(styles=st.lists(st.sampled_from(["alpamayo", "orion", "narration"]), min_size=1, max_size=20),
       actions=st.lists(st.sampled_from(["decelerating", "maintaining"]), min_size=20, max_size=20))
def test_agreement_by_group_is_agreement_on_the_group(tmp_path_factory, styles, actions):
    folder = tmp_path_factory.mktemp("by")
    gold_rows = [{"id": f"i{i}", "text": "x", "style": s, "labels": {**FULL, "stated_action": "decelerating"}}
                 for i, s in enumerate(styles)]
    other_rows = [{"id": f"i{i}", "text": "x", "labels": {**FULL, "stated_action": actions[i]}}
                  for i in range(len(styles))]
    gold = load_label_source(write_label_file(folder / "gold.jsonl", gold_rows))
    other = load_label_source(write_label_file(folder / "other.jsonl", other_rows))
    groups = agreement_by(gold, other, "style")
    assert set(groups) == set(styles)
    for style, report in groups.items():
        ids = [f"i{i}" for i, s in enumerate(styles) if s == style]
        expected = agreement({k: gold.labels[k] for k in ids}, {k: other.labels[k] for k in ids})
        assert report.compared == len(ids)
        assert [p.to_json() for p in report.properties] == [p.to_json() for p in expected.properties]


def test_items_without_the_field_form_their_own_group(tmp_path):
    rows = label_rows(3, FULL)
    rows[0]["style"] = "orion"
    a = load_label_source(write_label_file(tmp_path / "a.jsonl", rows))
    assert set(agreement_by(a, a, "style")) == {"orion", NO_GROUP}


def test_a_field_no_item_has_is_a_config_error(tmp_path):
    a = load_label_source(write_label_file(tmp_path / "a.jsonl", label_rows(3, FULL, style="orion")))
    with pytest.raises(ConfigError, match="--by colour: no item in common has a field 'colour'.*style"):
        agreement_by(a, a, "colour")


def run_agree(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "vladrivebench._cli.main", "labels", "agree", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_cli_agree_by_prints_each_group_and_a_bad_field_is_one_line(tmp_path):
    gold = write_label_file(tmp_path / "gold.jsonl", label_rows(4, FULL, style="alpamayo") +
                            [{"id": "o", "text": "x", "style": "orion", "labels": FULL}])
    result = run_agree(gold, gold, "--by", "style")
    assert result.returncode == 0, result.stderr
    assert "by style" in result.stdout and "alpamayo [4]" in result.stdout and "orion [1]" in result.stdout
    data = json.loads(run_agree(gold, gold, "--by", "style", "--json").stdout)
    assert set(data["groups"]) == {"alpamayo", "orion"} and data["by"] == "style"
    for bad in (["--by", "nope"], ["--by", " "]):
        result = run_agree(gold, gold, *bad)
        assert result.returncode == 2 and result.stdout == ""
        assert result.stderr.startswith("vdb: error: --by") and result.stderr.count("\n") == 1
        assert "Traceback" not in result.stderr


def test_cli_agree_with_every_labels_empty_is_an_error_not_75_percent(tmp_path):
    gold = write_label_file(tmp_path / "gold.jsonl", label_rows(4, FULL))
    empty = write_label_file(tmp_path / "empty.jsonl", label_rows(4, {}))
    result = run_agree(gold, empty)
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == f"vdb: error: {empty}: no compared item states any label (every \"labels\" object " \
                            "lacks stated_action, target_mentioned, …); nothing to compare\n"
