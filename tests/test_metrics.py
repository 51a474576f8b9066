"""Built-in metrics on synthetic logs whose every label and alignment set is known in advance."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from statsmodels.stats.proportion import proportion_confint
from vladrivebench._analysis.alignment import action_head_set, cot_action_set, relaxed_aligned
from vladrivebench._analysis.dataset import distance_zone, label_items, load_dataset
from vladrivebench._analysis.labels import LabelStore, label_key
from vladrivebench._analysis.tables import MISSING, Cell, Row, Table, breakdown_text, wilson_interval
from vladrivebench._builtins.metrics import (
    AlignmentByCommand,
    AlignmentByDistance,
    ContradictionRate,
    HallucinationRate,
    LightAccuracy,
    MentionRate,
)
from vladrivebench._logs import episodes as logs
from vladrivebench.errors import ConfigError, LogError


def label_all(directory, fx, fraction=1.0):
    """Label (a leading fraction of) every step with the fake labeler, straight into the store."""
    from vladrivebench._analysis.dataset import read_directory

    episodes, _ = read_directory(directory)
    items = label_items(episodes)
    labeler = fx.FakeLabeler()
    keep = items[: int(len(items) * fraction)]
    store = LabelStore(directory, "fake")
    store.add([(item, label_key(item, "fake", "1"), labeler.label(item)) for _, _, item in keep], "1")


# -- records ------------------------------------------------------------------------------------------------
@settings(max_examples=200)
@given(n=st.integers(1, 5000), frac=st.floats(0, 1))
def test_wilson_interval_matches_statsmodels(n, frac):
    k = round(frac * n)
    low, high = wilson_interval(k, n)
    expected = proportion_confint(k, n, alpha=0.05, method="wilson")
    assert low == pytest.approx(expected[0], abs=1e-12) and high == pytest.approx(expected[1], abs=1e-12)
    assert low <= k / n <= high


@given(n=st.integers(0, 1), k=st.integers(0, 1))
def test_a_cell_with_fewer_than_two_observations_is_a_dash_with_its_count(n, k):
    cell = Cell.rate(min(k, n), n)
    assert cell.display == MISSING and cell.count == n and cell.value is None


def test_table_checks_its_shape():
    with pytest.raises(ValueError, match="expected 1 / 2"):
        Table("t", "T", ("Scenario",), ("a", "b"), (Row(("x",), (Cell.rate(1, 2),)),))
    with pytest.raises(ValueError, match="span 3"):
        Table("t", "T", ("Scenario",), ("a", "b"), (), groups=(("m", 3),))


def test_breakdown_text_like_the_paper():
    assert breakdown_text({"maint": 1357}, 1357) == "maint=1357 (100%)"
    assert breakdown_text({"slow": 181, "maint": 23, "accel": 20}, 224) == "slow=181, maint=23, accel=20"


# -- mention rate by zone ---------------------------------------------------------------------------------------
def approach(fx, directory, name, *, mention_below=30.0, model="fake", seed=0, kind="pedestrian"):
    """5 m/s for 115 steps towards a target at 60 m; the CoT names it once closer than ``mention_below``."""
    return fx.write_episode(
        directory / f"{name}.mcap", speeds=[5.0] * 115, kind=kind, model=model, seed=seed,
        cot=lambda step, d, v: fx.STOP_PED if d is not None and d < mention_below else fx.CLEAR,
        v_des=lambda step, d, v: v)


def test_mention_rate_per_zone_counts_every_labelled_step(tmp_path, fx):
    approach(fx, tmp_path, "a")
    label_all(tmp_path, fx)
    dataset = load_dataset(tmp_path)
    table, plot = MentionRate().compute(dataset)
    distances = [60.0 - 0.5 * i for i in range(115)]
    expected = {}
    for d in distances:
        hit, n = expected.get(distance_zone(d), (0, 0))
        expected[distance_zone(d)] = (hit + (d < 30.0), n + 1)
    for column, zone in enumerate(("far", "med", "near")):
        cell = table.cell("Pedestrian (in-lane)", column)
        assert cell.count == expected[zone][1]
        assert cell.value == pytest.approx(expected[zone][0] / expected[zone][1])
        assert cell.low <= cell.value <= cell.high
    assert table.groups == (("fake", 3),)
    assert plot.panels and plot.to_png().startswith(b"\x89PNG")


def test_models_are_side_by_side_and_options_that_differ_name_them(tmp_path, fx):
    fx.write_episode(tmp_path / "a.mcap", speeds=[5.0] * 40, model="scripted", model_options={"alpha": 0.0},
                     cot=lambda s, d, v: fx.STOP_PED, v_des=lambda s, d, v: v)
    fx.write_episode(tmp_path / "b.mcap", speeds=[5.0] * 40, model="scripted", model_options={"alpha": 1.0},
                     cot=lambda s, d, v: fx.CLEAR, v_des=lambda s, d, v: v)
    label_all(tmp_path, fx)
    table = MentionRate().compute(load_dataset(tmp_path))[0]
    assert table.groups == (("scripted (alpha=0.0)", 3), ("scripted (alpha=1.0)", 3))
    assert table.cell("Pedestrian (in-lane)", 0).value == 1.0 and table.cell("Pedestrian (in-lane)", 3).value == 0.0


# -- hallucination, contradiction, light accuracy -----------------------------------------------------------------
def test_hallucination_and_contradiction_rates(tmp_path, fx):
    texts = [fx.PHANTOM_CAR] * 30 + [fx.CONTRADICTION] * 10 + [fx.STOP_PED] * 60
    fx.write_episode(tmp_path / "a.mcap", speeds=[0.0] * 100, target_x=15.0,
                     cot=lambda s, d, v: texts[s], v_des=lambda s, d, v: 0.0)
    label_all(tmp_path, fx)
    dataset = load_dataset(tmp_path)
    hallucination = HallucinationRate().compute(dataset)[0]
    assert hallucination.cell("Pedestrian (in-lane)", 1).value == pytest.approx(0.3)  # all steps at 15 m: med
    assert hallucination.cell("Pedestrian (in-lane)", 0).display == MISSING
    (contradiction,) = ContradictionRate().compute(dataset)
    cell = contradiction.cell("fake", 1)
    assert cell.value == pytest.approx(0.1) and cell.count == 100
    low, high = proportion_confint(10, 100, method="wilson")
    assert (cell.low, cell.high) == (pytest.approx(low), pytest.approx(high))


def test_light_accuracy_is_conditional_on_a_mentioned_colour(tmp_path, fx):
    texts = ["The light ahead is red, stop."] * 6 + ["The light ahead is green, go."] * 2 + \
        ["The light ahead, stop."] * 2 + [fx.CLEAR] * 10
    fx.write_episode(tmp_path / "a.mcap", speeds=[0.0] * 20, kind="traffic_light", light="red", target_x=30.0,
                     scenario_id="TL.1-red", cot=lambda s, d, v: texts[s], v_des=lambda s, d, v: 0.0)
    label_all(tmp_path, fx)
    (table, _plot) = LightAccuracy().compute(load_dataset(tmp_path))
    cell = table.cell("Traffic light (red)", 0)  # 30 m: far
    assert (cell.value, cell.count) == (pytest.approx(6 / 8), 8)
    assert any("2 steps mention the light without stating a colour" in n for n in table.notes)


# -- alignment ------------------------------------------------------------------------------------------------------
def stop_profile():
    """Cruise at 6 m/s, brake to a standstill about 7 m before a pedestrian at 60 m, wait 50 steps."""
    speeds, x = [], 0.0
    while x < 35.0:
        speeds.append(6.0)
        x += 0.6
    v = 6.0
    while v > 0.0:
        speeds.append(v)
        x += v * 0.1
        v = max(0.0, round(v - 0.1, 10))
    return speeds + [0.0] * 50


def test_alignment_by_distance_is_the_mean_over_pooled_one_metre_bins(tmp_path, fx):
    speeds = stop_profile()

    def cot(step, d, v):
        return fx.STOP_PED if d < 22.0 else fx.CLEAR

    def v_des(step, d, v):  # the head holds speed until 18 m, then commands a stop
        return v if d > 18.0 else 0.0

    fx.write_episode(tmp_path / "a.mcap", speeds=speeds, cot=cot, v_des=v_des)
    label_all(tmp_path, fx)
    tables = AlignmentByDistance().compute(load_dataset(tmp_path))
    relaxed = next(t for t in tables if t.id == "alignment_distance")
    # independent computation: walk the same steps, bin by travelled metre, per zone
    x, per_zone = 0.0, {}
    for step, v in enumerate(speeds):
        d = 60.0 - x
        action = "decelerating" if d < 22.0 else "maintaining"
        ok = relaxed_aligned(cot_action_set(action, v, d / v if v > 0 else math.inf), action_head_set(v, v_des(step, d, v)))
        per_zone.setdefault(distance_zone(d), {}).setdefault(math.floor(x), []).append(ok)
        x += v * 0.1
    for column, zone in enumerate(("far", "med", "near")):
        bins = [sum(b) / len(b) for b in per_zone[zone].values()]
        cell = relaxed.cell("Pedestrian (in-lane)", column)
        assert cell.count == len(bins) >= 2
        assert cell.value == pytest.approx(sum(bins) / len(bins))
    # the 50 stationary steps are one bin, so near-zone alignment is not dominated by them
    assert relaxed.cell("Pedestrian (in-lane)", 2).count < 10
    assert {t.id for t in tables} >= {"alignment_distance", "alignment_distance_strict", "alignment_runs"}


def test_alignment_by_command_in_the_speed_band(tmp_path, fx):
    speeds = [3.0] * 40 + [6.0] * 10
    texts = [fx.ACCEL] * 25 + [fx.STOP_PED] * 15 + [fx.ACCEL] * 10

    def v_des(step, d, v):
        return {0: 3.0, 1: 3.5, 2: 2.0}[step % 3]  # maint/accel, accel, slow

    fx.write_episode(tmp_path / "a.mcap", speeds=speeds, cot=lambda s, d, v: texts[s], v_des=v_des)
    label_all(tmp_path, fx)
    (table,) = AlignmentByCommand().compute(load_dataset(tmp_path))
    heads = {s: action_head_set(3.0, v_des(s, None, 3.0)) for s in range(40)}
    for command, steps, cot in (("accel", range(25), ("accelerate",)), ("slow", range(25, 40), ("decelerate",))):
        row = next(r for r in table.rows if r.labels == ("fake", command))
        assert row.cells[0].count == len(steps)
        assert row.cells[1].value == pytest.approx(sum(relaxed_aligned(cot, heads[s]) for s in steps) / len(steps))
        assert row.cells[3].value == pytest.approx(len(steps) / 40)
    accel = next(r for r in table.rows if r.labels == ("fake", "accel"))
    assert accel.cells[4].display == "maint=9, accel=8, slow=8"


# -- missing data ---------------------------------------------------------------------------------------------------
def test_missing_labels_are_counted_and_left_out(tmp_path, fx):
    approach(fx, tmp_path, "a")
    label_all(tmp_path, fx, fraction=0.6)
    dataset = load_dataset(tmp_path)
    assert any("46 of 115 steps have no fake labels" in n for n in dataset.notes)
    table = MentionRate().compute(dataset)[0]
    assert sum(table.cell("Pedestrian (in-lane)", c).count for c in range(3)) == 69


def test_unlabelled_steps_are_reported_with_their_reason(tmp_path, fx):
    fx.write_episode(tmp_path / "a.mcap", speeds=[5.0] * 10, cot=lambda s, d, v: "gibberish",
                     v_des=lambda s, d, v: v)
    label_all(tmp_path, fx)
    dataset = load_dataset(tmp_path)
    assert any("10 steps are unlabelled by fake" in n and "unknown text" in n for n in dataset.notes)
    assert MentionRate().compute(dataset) == []


def test_no_labels_at_all_says_how_to_get_them(tmp_path, fx):
    approach(fx, tmp_path, "a")
    dataset = load_dataset(tmp_path)
    assert any("vdb label" in n for n in dataset.notes) and MentionRate().compute(dataset) == []


def test_truncated_and_corrupt_logs_are_named_not_silently_used(tmp_path, fx):
    approach(fx, tmp_path, "good")
    cut = approach(fx, tmp_path, "cut")
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    dataset = load_dataset(tmp_path)
    assert len(dataset.episodes) == 2
    assert any(n.startswith("cut.mcap is truncated: its") for n in dataset.notes)
    assert any(n.startswith("left out junk.mcap") for n in dataset.notes)
    with pytest.raises(LogError, match="junk.mcap|cut.mcap"):
        load_dataset(tmp_path, strict=True)


def test_logs_of_an_incompatible_version_are_left_out_with_both_versions(tmp_path, fx, monkeypatch):
    approach(fx, tmp_path, "good")
    monkeypatch.setattr(logs, "SCHEMA_VERSION", "9")
    approach(fx, tmp_path, "future")
    monkeypatch.undo()
    dataset = load_dataset(tmp_path)
    assert any("future.mcap" in n and "version 9" in n for n in dataset.notes)


def test_a_directory_without_logs_is_one_clear_error(tmp_path):
    with pytest.raises(LogError, match="no episode logs"):
        load_dataset(tmp_path)


def test_several_label_stores_need_a_choice(tmp_path, fx):
    approach(fx, tmp_path, "a")
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "x.jsonl").write_text("")
    (tmp_path / "labels" / "y.jsonl").write_text("")
    with pytest.raises(ConfigError, match="several labelers .*--labeler"):
        load_dataset(tmp_path)


def test_intervention_episodes_are_not_observational_data(tmp_path, fx):
    approach(fx, tmp_path, "own")
    fx.write_episode(tmp_path / "inj.mcap", speeds=[5.0] * 115, intervention={"role": "injected"},
                     cot=lambda s, d, v: fx.STOP_PED, v_des=lambda s, d, v: v)
    label_all(tmp_path, fx)
    table = MentionRate().compute(load_dataset(tmp_path))[0]
    assert sum(table.cell("Pedestrian (in-lane)", c).count for c in range(3)) == 115


@given(d=st.floats(-100, 200, allow_nan=False))
def test_distance_zones_partition_the_route(d):
    zone = distance_zone(d)
    assert zone == ("past" if d < 0 else "near" if d < 10 else "med" if d <= 20 else "far")
    assert distance_zone(None) is None and distance_zone(math.inf) is None
