"""Helpers for the SUMO tests: suite scenarios, lockstep episodes and ground-truth comparison."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from vladrivebench import GroundTruth, Observation, Scenario
from vladrivebench.testing import own_cot_policy
from vladrivebench.world import load_scenario_file

SUITE_DIR = Path(__file__).resolve().parents[3] / "scenarios"


def suite() -> list[Scenario]:
    """Every scenario of the suite shipped with the core."""
    return [load_scenario_file(p) for p in sorted(SUITE_DIR.glob("*.toml"))]


def suite_scenario(scenario_id: str) -> Scenario:
    return next(s for s in suite() if s.id == scenario_id)


def lockstep(scenario: Scenario, seed: int, reference, other, model, controller, max_steps: int,
             check: Callable[[Observation, Observation], None] | None = None
             ) -> list[tuple[Observation, Observation]]:
    """Run ``model`` closed-loop on ``reference`` and feed the same controls to ``other``; returns the pairs
    of observations step by step, each passed to ``check`` as it happens (live state can be inspected
    there). While the two agree (which the caller checks), ``other`` sees exactly the episode the model
    would drive on it, so this is the closed loop on both at the cost of one model."""
    obs_a, obs_b = reference.reset(scenario, seed), other.reset(scenario, seed)
    model.reset(seed)
    controller.reset()
    pairs = [(obs_a, obs_b)]
    if check is not None:
        check(obs_a, obs_b)
    while not obs_a.ground_truth.terminal and len(pairs) < max_steps:
        cot, trajectory, _ = own_cot_policy(model, obs_a, seed)
        control = controller.control(trajectory, obs_a.ego, reference.dt)
        obs_a, obs_b = reference.step(control), other.step(control)
        pairs.append((obs_a, obs_b))
        if check is not None:
            check(obs_a, obs_b)
    return pairs


def truth_differences(a: GroundTruth, b: GroundTruth, distance_tol: float) -> list[str]:
    """What the metrics read that differs between two ground truths (distance within ``distance_tol`` m)."""
    out = []
    if (a.distance_to_critical is None) != (b.distance_to_critical is None):
        out.append(f"distance_to_critical {a.distance_to_critical} vs {b.distance_to_critical}")
    elif a.distance_to_critical is not None and abs(a.distance_to_critical - b.distance_to_critical) > distance_tol:
        out.append(f"distance_to_critical {a.distance_to_critical:.6f} vs {b.distance_to_critical:.6f}")
    for name in ("critical_id", "blocking", "light_state", "collisions", "violations", "terminal"):
        if getattr(a, name) != getattr(b, name):
            out.append(f"{name} {getattr(a, name)!r} vs {getattr(b, name)!r}")
    return out


def drive(simulator, scenario: Scenario, seed: int, steps: int, on_step=None) -> list[Observation]:
    """Up to ``steps`` observations of the scripted model (PID) driving ``scenario`` on ``simulator``;
    ``on_step(obs)`` runs at each step while the simulation is live."""
    from vdb_model_scripted.plugin import make_scripted
    from vladrivebench.episodes import build_component

    model, controller = make_scripted(), build_component("controller", "pid")
    obs = simulator.reset(scenario, seed)
    model.reset(seed)
    controller.reset()
    seen = [obs]
    if on_step is not None:
        on_step(obs)
    while not obs.ground_truth.terminal and len(seen) < steps:
        _, trajectory, _ = own_cot_policy(model, obs, seed)
        obs = simulator.step(controller.control(trajectory, obs.ego, simulator.dt))
        seen.append(obs)
        if on_step is not None:
            on_step(obs)
    return seen


def actor_trace(observations: list[Observation]) -> list[tuple]:
    """Everything about the road users, step by step, to compare two episodes exactly."""
    return [(o.step, o.ego.x, o.ego.y, o.ego.speed,
             tuple((a.actor_id, a.kind, a.x, a.y, a.yaw, a.speed) for a in o.ground_truth.actors),
             o.ground_truth.collisions, o.ground_truth.violations) for o in observations]
