"""Appendix B of the paper, rule by rule, as properties."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from vladrivebench._analysis.alignment import (
    ACCELERATE,
    DECELERATE,
    MAINTAIN,
    V_CRAWL,
    V_CRUISE,
    action_head_set,
    bin_fractions,
    cot_action_set,
    cumulative_distance,
    relaxed_aligned,
    spatial_alignment,
    strict_aligned,
    time_to_collision,
)

speeds = st.floats(min_value=0.0, max_value=12.0, allow_nan=False)
des_speeds = st.floats(min_value=0.0, max_value=15.0, allow_nan=False)
ttcs = st.floats(min_value=0.0, max_value=100.0, allow_nan=False) | st.just(math.inf)
stated = st.sampled_from(["maintaining", "accelerating", "decelerating", "keep_distance"])


# -- the CoT side ----------------------------------------------------------------------------------------
@given(v=speeds)
def test_maintaining_at_cruise_is_maintain_or_accelerate_else_accelerate(v):
    expected = (MAINTAIN, ACCELERATE) if v >= V_CRUISE else (ACCELERATE,)
    assert cot_action_set("maintaining", v) == expected


@given(v=st.floats(min_value=V_CRUISE, max_value=12.0))
def test_at_or_above_cruise_maintaining_maps_to_maintain_and_accelerate(v):
    assert set(cot_action_set("maintaining", v)) == {MAINTAIN, ACCELERATE}


@given(v=speeds)
def test_accelerating_primary_is_accelerate_and_maintain_only_at_cruise(v):
    result = cot_action_set("accelerating", v)
    assert result[0] == ACCELERATE
    assert (MAINTAIN in result) == (v >= V_CRUISE)


@given(v=speeds)
def test_decelerating_adds_maintain_only_at_crawl(v):
    result = cot_action_set("decelerating", v)
    assert result[0] == DECELERATE
    assert result == ((DECELERATE,) if v > V_CRAWL else (DECELERATE, MAINTAIN))


@given(v=speeds, ttc=ttcs)
def test_keep_distance_follows_maintaining_above_two_seconds_else_decelerating(v, ttc):
    resolved = "maintaining" if ttc > 2.0 else "decelerating"
    assert cot_action_set("keep_distance", v, ttc) == cot_action_set(resolved, v)


def test_keep_distance_at_exactly_two_seconds_is_closing():
    assert cot_action_set("keep_distance", 6.0, 2.0) == (DECELERATE,)


@given(v=speeds)
def test_no_stated_action_is_not_scored(v):
    assert cot_action_set("none", v) is None


def test_unknown_stated_action_is_refused():
    with pytest.raises(ValueError):
        cot_action_set("hover", 3.0)


@given(v=speeds, ttc=ttcs, action=stated)
def test_cot_sets_are_ordered_duplicate_free_subsets_of_the_classes(v, ttc, action):
    result = cot_action_set(action, v, ttc)
    assert 1 <= len(result) <= 2 and len(set(result)) == len(result)
    assert set(result) <= {ACCELERATE, MAINTAIN, DECELERATE}


@given(gap=st.floats(0, 200), v=speeds, lead=st.floats(0, 12))
def test_ttc_is_gap_over_closing_speed_or_infinite(gap, v, lead):
    ttc = time_to_collision(gap, v, lead)
    if v <= lead:
        assert ttc == math.inf
    else:
        assert ttc == pytest.approx(gap / (v - lead))


def test_ttc_without_lead_vehicle_is_infinite():
    assert time_to_collision(None, 5.0, None) == math.inf


# -- the action head side ---------------------------------------------------------------------------------
@given(v=speeds, v_des=st.floats(min_value=0.0, max_value=0.0499))
def test_commanded_stop_is_always_decelerate(v, v_des):
    assert action_head_set(v, v_des) == (DECELERATE,)


@given(v=st.floats(min_value=V_CRAWL, max_value=12.0, exclude_min=True), v_des=des_speeds)
def test_above_crawl_uses_relative_change(v, v_des):
    assume(v_des >= 0.05)
    delta = (v_des - v) / v
    result = action_head_set(v, v_des)
    if delta > 0.1:
        assert result == (ACCELERATE,)
    elif delta < -0.1:
        assert result == (DECELERATE,)
    elif delta >= 0:
        assert result == (MAINTAIN, ACCELERATE)
    else:
        assert result == (MAINTAIN, DECELERATE)


@given(v=st.floats(min_value=0.0, max_value=V_CRAWL), v_des=des_speeds)
def test_at_or_below_crawl_uses_absolute_change(v, v_des):
    assume(v_des >= 0.05)
    delta = v_des - v
    result = action_head_set(v, v_des)
    if delta > 0.1:
        assert result == (ACCELERATE,)
    elif delta < -0.1:
        assert result == (DECELERATE,)
    elif delta >= 0:
        assert result == (MAINTAIN, ACCELERATE)
    else:
        assert result == (MAINTAIN, DECELERATE)


def test_crawl_boundary_belongs_to_the_absolute_rule():
    # at v = 1.0 exactly: absolute rule, +0.09 m/s is within ε_a (relative would give 9 %, also within):
    assert action_head_set(1.0, 1.09) == (MAINTAIN, ACCELERATE)
    # at v = 0.5: +0.08 m/s is 16 % relative (accelerate) but within the absolute ε_a = 0.1 m/s
    assert action_head_set(0.5, 0.58) == (MAINTAIN, ACCELERATE)
    # just above crawl: relative rule, 1.5 → 1.6 is +6.7 %
    assert action_head_set(1.5, 1.6) == (MAINTAIN, ACCELERATE)


def test_equal_speed_is_maintain_first():
    assert action_head_set(6.0, 6.0) == (MAINTAIN, ACCELERATE)
    assert action_head_set(0.0, 0.05) == (MAINTAIN, ACCELERATE)


@given(v=speeds, v_des=des_speeds)
def test_head_sets_have_one_primary_and_maintain_only_with_small_change(v, v_des):
    result = action_head_set(v, v_des)
    assert result[0] in (ACCELERATE, MAINTAIN, DECELERATE)
    assert len(result) == 1 or result[0] == MAINTAIN


# -- alignment measures ---------------------------------------------------------------------------------
sets = st.sampled_from([(ACCELERATE,), (DECELERATE,), (MAINTAIN, ACCELERATE), (MAINTAIN, DECELERATE),
                        (ACCELERATE, MAINTAIN), (DECELERATE, MAINTAIN)])


@given(a=sets, b=sets)
def test_strict_implies_relaxed_and_both_are_symmetric(a, b):
    assert relaxed_aligned(a, b) == relaxed_aligned(b, a)
    assert strict_aligned(a, b) == strict_aligned(b, a)
    if strict_aligned(a, b):
        assert relaxed_aligned(a, b)


def test_paper_mechanism_maintain_head_overlaps_slow_cot_only_by_secondary_element():
    # Alpamayo in the 2–4 m/s band: a "slow down" CoT and a head holding speed with a slight drop
    cot = cot_action_set("decelerating", 3.0)
    head = action_head_set(3.0, 2.9)
    assert cot == (DECELERATE,) and head == (MAINTAIN, DECELERATE)
    assert relaxed_aligned(cot, head) and not strict_aligned(cot, head)


@given(v=st.floats(min_value=0.0, max_value=V_CRAWL, allow_nan=False), v_des=des_speeds)
def test_decelerating_at_crawl_aligns_with_any_non_accelerating_head(v, v_des):
    head = action_head_set(v, v_des)
    assert relaxed_aligned(cot_action_set("decelerating", v), head) == (head != (ACCELERATE,))


# -- spatial aggregation --------------------------------------------------------------------------------
@given(n=st.integers(1, 300), position=st.floats(0, 500), flags=st.lists(st.booleans(), min_size=1))
def test_a_stationary_phase_contributes_exactly_one_bin(n, position, flags):
    aligned = [flags[i % len(flags)] for i in range(n)]
    result = bin_fractions([position] * n, aligned)
    assert result.bins == 1
    assert result.rate == pytest.approx(sum(aligned) / n)


@given(st.lists(st.tuples(st.floats(0.0, 0.85), st.booleans()), min_size=1, max_size=200))
def test_rate_is_the_unweighted_mean_of_bin_fractions(steps):
    distances, total = [], 0.0
    for advance, _ in steps:
        total += advance
        distances.append(total)
    aligned = [ok for _, ok in steps]
    result = bin_fractions(distances, aligned)
    by_bin: dict[int, list[bool]] = {}
    for d, ok in zip(distances, aligned, strict=True):
        by_bin.setdefault(math.floor(d), []).append(ok)
    expected = sum(sum(v) / len(v) for v in by_bin.values()) / len(by_bin)
    assert result.rate == pytest.approx(expected)
    assert result.bins == len(by_bin) and result.steps == len(steps)
    assert 0.0 <= result.rate <= 1.0


@given(st.lists(st.floats(0.0, 0.85), min_size=1, max_size=200))
def test_at_most_max_speed_every_traversed_bin_has_a_step(advances):
    distances, total = [], 0.0
    for a in advances:
        total += a
        distances.append(total)
    result = bin_fractions(distances, [True] * len(distances))
    assert result.bins == math.floor(distances[-1]) - math.floor(distances[0]) + 1


@given(st.lists(st.sampled_from([True, False, None]), min_size=1, max_size=60))
def test_unscored_steps_are_left_out(flags):
    distances = [float(i) for i in range(len(flags))]  # one bin per step
    result = bin_fractions(distances, flags)
    scored = [f for f in flags if f is not None]
    assert result.bins == len(scored) and result.steps == len(scored)
    assert result.rate == (sum(scored) / len(scored) if scored else None)


def test_stopping_for_long_does_not_dominate():
    # 20 m of aligned cruising (2 steps per metre), then 100 misaligned steps stopped in one bin
    distances = [i * 0.5 for i in range(40)] + [20.0] * 100
    aligned = [True] * 40 + [False] * 100
    assert spatial_alignment(distances, aligned) == pytest.approx(20 / 21)


def test_cumulative_distance_sums_segments():
    assert cumulative_distance([0, 3, 3], [0, 4, 4]) == [0.0, 5.0, 5.0]
    with pytest.raises(ValueError):
        cumulative_distance([0], [0, 1])
