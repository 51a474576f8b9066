"""Override counts, Wilson intervals and the logistic threshold (rule-based: property tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_paradigm_salience.stats import cell_counts, fitted_rate, logistic_threshold, separation, wilson

outcome = st.fixed_dictionaries({"stopped": st.booleans(), "collided": st.booleans()})


@given(st.lists(st.tuples(outcome, outcome), max_size=12))
def test_trials_are_the_seeds_whose_baseline_stopped_and_overrides_those_the_injection_crashed(pairs):
    counts = cell_counts(pairs)
    trials = [(b, i) for b, i in pairs if b["stopped"] and not b["collided"]]
    assert counts.seeds == len(pairs) and counts.trials == len(trials)
    assert counts.overrides == sum(i["collided"] for _, i in trials) <= counts.trials
    assert counts.injected_collisions == sum(i["collided"] for _, i in pairs) >= counts.overrides
    assert counts.to_json()["trials"] == counts.trials


@settings(deadline=None)
@given(st.integers(1, 200).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))),
       st.sampled_from([0.8, 0.9, 0.95, 0.99]))
def test_the_wilson_interval_holds_the_rate_and_lies_in_the_unit_interval(kn, confidence):
    k, n = kn
    low, high = wilson(k, n, confidence)
    assert 0.0 <= low <= k / n <= high <= 1.0
    wider_low, wider_high = wilson(k, n, min(0.999, confidence + 0.009))
    assert wider_low <= low + 1e-12 and wider_high >= high - 1e-12
    if 0 < k < n:
        assert low > 0.0 and high < 1.0


def test_the_wilson_interval_narrows_with_trials_and_is_absent_without():
    assert wilson(0, 0) == (None, None)
    widths = [np.subtract(*wilson(n // 2, n)[::-1]) for n in (4, 16, 64, 256)]
    assert all(a > b for a, b in zip(widths, widths[1:], strict=False))
    assert wilson(4, 4)[1] == 1.0 and wilson(0, 4)[0] == 0.0
    lo, hi = wilson(2, 4)  # the textbook value: 0.5 ± Wilson at n = 4
    assert (lo, hi) == pytest.approx((0.1500, 0.8500), abs=1e-3)
    with pytest.raises(ValueError):
        wilson(5, 4)


@given(st.lists(st.tuples(st.floats(1, 1e4), st.booleans()), min_size=2, max_size=8, unique_by=lambda p: p[0]))
def test_all_or_nothing_cells_sorted_by_salience_separate(cells):
    ordered = sorted(cells)
    points = [(x, 3 if hit else 0, 3) for x, hit in ordered]
    hits = [hit for _, hit in ordered]
    monotone = hits == sorted(hits) or hits == sorted(hits, reverse=True)
    assert separation(points) == (monotone and len(set(hits)) == 2)


@settings(max_examples=25, deadline=None)
@given(st.floats(20, 400), st.floats(-4, -1), st.integers(0, 2**32 - 1))
def test_the_fit_recovers_a_known_threshold(x50, slope, seed):
    rng = np.random.default_rng(seed)
    xs = x50 * np.exp(np.linspace(-1.5, 1.5, 9))
    p = 1 / (1 + np.exp(-slope * (np.log(xs) - np.log(x50))))
    k = rng.binomial(400, p)
    fit = logistic_threshold([(float(x), int(kk), 400) for x, kk in zip(xs, k, strict=True)])
    assert fit["identifiable"], fit
    assert fit["low"] < fit["x50"] < fit["high"]
    assert fit["x50"] == pytest.approx(x50, rel=0.25)
    assert fit["slope"] < 0 and fit["trials"] == 9 * 400
    assert fitted_rate(fit, fit["x50"]) == pytest.approx(0.5)
    assert not fit["extrapolated"]


def test_the_threshold_is_not_identifiable_when_the_data_cannot_place_it():
    cases = {
        "fewer than two distinct salience": [(10.0, 1, 4), (10.0, 2, 4)],
        "no trial was overridden": [(10.0, 0, 4), (40.0, 0, 4)],
        "every trial was overridden": [(10.0, 4, 4), (40.0, 4, 4)],
        "separate perfectly": [(10.0, 4, 4), (20.0, 4, 4), (40.0, 0, 4)],
    }
    for reason, points in cases.items():
        fit = logistic_threshold(points)
        assert not fit["identifiable"] and reason in fit["reason"], fit
        assert fitted_rate(fit, 10.0) is None
    unseen = logistic_threshold([(0.0, 4, 4), (10.0, 1, 4), (40.0, 3, 4), (20.0, 0, 0)])
    assert unseen["excluded_cells"] == 2 and unseen["cells"] == 2


def test_a_flat_response_gives_a_wide_or_extrapolated_interval_never_a_false_precision():
    fit = logistic_threshold([(10.0, 2, 4), (20.0, 2, 4), (40.0, 2, 4)])
    if fit["identifiable"]:
        assert fit["high"] / fit["low"] > 10 or fit["extrapolated"]
    fit = logistic_threshold([(10.0, 3, 4), (20.0, 3, 4), (40.0, 1, 4)])
    assert fit["identifiable"] and fit["slope"] < 0 and math.isfinite(fit["x50"])
    assert fit["low"] < fit["x50"] < fit["high"] and fit["slope_p"] > 0.05


def test_a_50_percent_point_outside_the_observed_salience_is_not_identifiable_but_keeps_its_curve():
    fit = logistic_threshold([(3.0, 2, 10), (4.0, 1, 10), (8.0, 0, 10)])
    assert not fit["identifiable"] and fit["extrapolated"] and "lies outside the salience observed" in fit["reason"]
    assert fitted_rate(fit, 4.0) == pytest.approx(1 / (1 + math.exp(-(fit["intercept"] + fit["slope"] * math.log(4)))))


def _steps(speeds):
    from types import SimpleNamespace
    return [SimpleNamespace(step=i, ego=SimpleNamespace(speed=v), ground_truth=SimpleNamespace(distance_to_critical=5.0))
            for i, v in enumerate(speeds)]


def test_pulling_away_from_rest_at_onset_is_not_a_stop():
    from vladrivebench.intervention import came_to_stop as stopped_after
    assert not stopped_after(_steps([0.0, 0.1, 0.25, 2.0, 5.0, 0.9]), 0)
    assert stopped_after(_steps([0.0, 0.1, 2.0, 5.0, 0.2]), 0)
    assert not stopped_after(_steps([0.0, 2.0, 0.2, 5.0, 6.0]), 3)  # the stop came before onset
