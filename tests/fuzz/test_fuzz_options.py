"""Hypothesis over the option checks the CLI relies on: seeds, controller options, key=value parsing."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._builtins.controllers import MPCController, PIDController
from vladrivebench._engine.options import parse_options
from vladrivebench._engine.sweep import MAX_SEEDS, seed_list
from vladrivebench.errors import ConfigError

QUICK = settings(max_examples=100, derandomize=True, deadline=None, database=None)
ANY = st.one_of(st.none(), st.booleans(), st.integers(-10**15, 10**15), st.floats(allow_nan=True),
                st.text(max_size=5), st.lists(st.floats(allow_nan=True), max_size=3))


@QUICK
@given(count=ANY | st.integers(-5, MAX_SEEDS + 5), offset=ANY | st.integers(-5, 10))
def test_seed_list_is_the_range_or_one_line(count, offset):
    valid = (isinstance(count, int) and not isinstance(count, bool) and 1 <= count <= MAX_SEEDS
             and isinstance(offset, int) and not isinstance(offset, bool) and offset >= 0)
    if valid:
        assert seed_list(count, offset) == tuple(range(offset, offset + count))
    else:
        with pytest.raises(ConfigError, match="--seed"):
            seed_list(count, offset)


@QUICK
@given(value=ANY)
def test_pid_max_speed_is_a_positive_number_or_refused_by_name(value):
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if number and math.isfinite(value) and 0 < value <= 60:
        assert PIDController(max_speed=value).max_speed == float(value)
    else:
        with pytest.raises(ValueError, match="'max_speed'"):
            PIDController(max_speed=value)


@QUICK
@given(window=ANY)
def test_pid_speed_window_is_an_increasing_pair_or_refused_by_name(window):
    ok = (isinstance(window, list) and len(window) == 2 and all(math.isfinite(v) and v >= 0 for v in window)
          and window[0] < window[1])
    if ok:
        assert PIDController(speed_window=window).speed_window == tuple(window)
    else:
        with pytest.raises(ValueError, match="'speed_window"):
            PIDController(speed_window=window)


@QUICK
@given(steps=ANY | st.integers(-3, 1003))
def test_mpc_horizon_is_bounded(steps):
    if isinstance(steps, int) and not isinstance(steps, bool) and 1 <= steps <= 1000:
        assert MPCController(horizon_steps=steps).horizon_steps == steps
    else:
        with pytest.raises(ValueError, match="'horizon_steps'"):
            MPCController(horizon_steps=steps)


@QUICK
@given(pairs=st.lists(st.text(max_size=12), max_size=4))
def test_options_parse_or_name_the_pair(pairs):
    try:
        options = parse_options(pairs, "--model-opt")
    except ConfigError as exc:
        assert "--model-opt" in str(exc) and "\n" not in str(exc)
        return
    assert all("=" in p and p.partition("=")[0].strip() for p in pairs)
    assert len(options) <= len(pairs)
