"""The MPC's per-horizon constants (built once, reused): the same plan as building them on every call."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from vladrivebench._builtins.controllers import (
    MPCController,
    MPCWeights,
    _curvature_constants_of,
    _reference_path,
    bounded_least_squares,
)
from vladrivebench.records import EgoState, Trajectory
from vladrivebench.world._bicycle import DT

weights = st.builds(MPCWeights, curvature=st.floats(0.01, 10.0), curvature_rate=st.floats(0.01, 10.0))


@given(st.integers(1, 60), weights)
@settings(max_examples=40, deadline=None)
def test_the_curvature_constants_are_the_plain_matrices(n, w):
    lower, effort = _curvature_constants_of(n, w)
    assert np.array_equal(lower, (np.arange(n)[:, None] >= np.arange(n)[None, :]).astype(float))
    assert np.array_equal(effort, np.vstack([math.sqrt(w.curvature) * np.eye(n),
                                             math.sqrt(w.curvature_rate) * (np.eye(n) - np.eye(n, k=-1))]))


def plain_plan_curvature(controller: MPCController, path, s_ref: np.ndarray, travelled: float) -> float:
    """The curvature plan with every matrix built afresh (the computation before the constants were kept)."""
    step_len = np.maximum(np.diff(np.concatenate([[0.0], s_ref])), controller.min_preview / len(s_ref))
    step_len[0] = travelled
    s_at = path.s0 + np.concatenate([[0.0], np.cumsum(step_len)])[:-1]
    kappa_ref = np.clip(np.interp(s_at, path.vertex_s, path.vertex_kappa), -controller.max_curvature,
                        controller.max_curvature)
    n, w = len(step_len), controller.weights
    lower = (np.arange(n)[:, None] >= np.arange(n)[None, :]).astype(float)
    heading_rows = lower * step_len[None, :]
    heading_offset = path.heading0 - heading_rows @ kappa_ref
    before = np.vstack([np.zeros((1, n)), heading_rows[:-1]])
    before_offset = np.concatenate([[path.heading0], heading_offset[:-1]])
    lateral_rows = (lower * step_len[None, :]) @ before
    lateral_offset = path.lateral0 + (lower * step_len[None, :]) @ before_offset
    rate_target = np.zeros(n)
    rate_target[0] = controller._last_curvature
    matrix = np.vstack([math.sqrt(w.heading) * heading_rows, math.sqrt(w.lateral) * lateral_rows,
                        math.sqrt(w.curvature) * np.eye(n),
                        math.sqrt(w.curvature_rate) * (np.eye(n) - np.eye(n, k=-1))])
    target = np.concatenate([-math.sqrt(w.heading) * heading_offset, -math.sqrt(w.lateral) * lateral_offset,
                             math.sqrt(w.curvature) * kappa_ref, math.sqrt(w.curvature_rate) * rate_target])
    bound = controller.max_curvature
    return float(np.clip(bounded_least_squares(matrix, target, -bound, bound)[0], -bound, bound))


@st.composite
def plans(draw):
    """(waypoints, s_ref, travelled, last curvature) of a wandering path over 1..30 steps."""
    count = draw(st.integers(2, 30))
    speeds = np.array(draw(st.lists(st.floats(0.5, 15.0), min_size=count, max_size=count)))
    turns = np.array(draw(st.lists(st.floats(-0.3, 0.3), min_size=count, max_size=count)))
    headings = np.cumsum(turns)
    steps = np.stack([np.cos(headings), np.sin(headings)], axis=1) * (speeds * DT)[:, None]
    waypoints = np.cumsum(steps, axis=0) + np.array([0.0, draw(st.floats(-2.0, 2.0))])
    s_ref = np.cumsum(speeds[:draw(st.integers(1, count))] * DT)
    return waypoints, s_ref, draw(st.floats(0.0, 1.5)), draw(st.floats(-0.2, 0.2))


@given(st.lists(plans(), min_size=1, max_size=4))
@settings(max_examples=60, deadline=None)
def test_the_kept_constants_plan_what_plain_matrices_plan(sequence):
    """One controller over plans of changing horizons (its constants rebuilt when the horizon changes)."""
    controller = MPCController()
    for waypoints, s_ref, travelled, last in sequence:
        path = _reference_path(waypoints)
        if path is None:
            continue
        controller._last_curvature = last
        assert controller._plan_curvature(path, s_ref, travelled) == plain_plan_curvature(
            controller, path, s_ref, travelled)


def test_controls_over_changing_horizons_match_a_fresh_controller():
    ego = EgoState(0.0, 0.0, 0.0, 5.0)
    kept = MPCController()
    for count in (30, 10, 30, 3, 3, 20):
        times = DT * np.arange(1, count + 1)
        trajectory = Trajectory(times, np.stack([5.0 * times, 0.02 * times**2], axis=1))
        fresh = MPCController()
        fresh._last_accel, fresh._last_curvature = kept._last_accel, kept._last_curvature
        assert kept.control(trajectory, ego, DT) == fresh.control(trajectory, ego, DT)
