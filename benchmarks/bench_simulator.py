"""Kinematic simulator throughput: steps per second with and without the camera, printed as ratios.

    python benchmarks/bench_simulator.py [--steps 200] [--repeats 3] [--width 160 --height 80]
        [--rig alpamayo --frames 4 --frame-rate-hz 10]

Each scenario is driven for ``--steps`` steps (restarting when an episode ends) by a fixed lane-keeping
control that reads only the ground truth, so the numbers are the simulator's own cost: physics, road users,
ground truth and (with rendering) the camera image. Times are the best of ``--repeats`` runs; the machine
may be shared, so the CPU time of the process is reported (wall time suffers from other processes'
load) and the ratios matter more than the absolute numbers. Target: a step with rendering at 160×80 in a
few milliseconds. ``--rig`` (with ``--frames``/``--frame-rate-hz``) measures a camera rig instead of the
front camera; ``--width``/``--height`` then default to the rig's own size.
"""

from __future__ import annotations

import argparse
import math
import time

SCENARIOS = ("E.1", "P.2", "TL.3-green", "E.2")


def lane_keeping(obs, speed: float = 6.5):
    """Pure pursuit on ``route_ahead`` at ``speed`` (no model: the benchmark measures the simulator)."""
    from vladrivebench.records import Control
    from vladrivebench.world._bicycle import MAX_WHEEL_ANGLE, WHEELBASE

    x, y = obs.ground_truth.route_ahead[5]
    delta = math.atan2(2.0 * WHEELBASE * math.sin(math.atan2(y, x)), math.hypot(x, y))
    steer = max(-1.0, min(1.0, delta / MAX_WHEEL_ANGLE))
    error = speed - obs.ego.speed
    return Control(min(max(error, 0.0), 0.75), steer, min(max(-error, 0.0), 1.0), speed)


def seconds_per_step(scenario, render: bool, options: dict, steps: int, repeats: int) -> float:
    """Best-of-``repeats`` CPU time of one simulator step (reset excluded)."""
    from vladrivebench._engine.registry import get_registry

    sim = get_registry().create("simulator", "kinematic", {"render": render, **options})
    best = math.inf
    for _ in range(repeats):
        obs = sim.reset(scenario, 0)
        elapsed = 0.0
        for _ in range(steps):
            if obs.ground_truth.terminal is not None:
                obs = sim.reset(scenario, 0)
            control = lane_keeping(obs)
            started = time.process_time()
            obs = sim.step(control)
            elapsed += time.process_time() - started
        best = min(best, elapsed / steps)
    sim.close()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--width", type=int, default=None)
    parser.add_argument("--height", type=int, default=None)
    parser.add_argument("--rig", default=None, help="a camera rig (front, alpamayo); default: the front camera")
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--frame-rate-hz", type=float, default=None)
    args = parser.parse_args()
    given = {"width": args.width, "height": args.height, "rig": args.rig, "frames": args.frames,
             "frame_rate_hz": args.frame_rate_hz}
    options = {name: value for name, value in given.items() if value is not None}

    from vladrivebench._scenarios.spec import resolve_scenarios

    print(f"kinematic simulator, options {options or 'default (front camera, 160x80)'}, {args.steps} steps x "
          f"best of {args.repeats} (CPU time per step)")
    print(f"{'scenario':<12} {'render ms':>10} {'steps/s':>9} {'no-render ms':>13} {'steps/s':>9} {'ratio':>6}")
    for scenario in resolve_scenarios(list(SCENARIOS)):
        with_image = seconds_per_step(scenario, True, options, args.steps, args.repeats)
        without = seconds_per_step(scenario, False, options, args.steps, args.repeats)
        print(f"{scenario.id:<12} {with_image * 1e3:>10.2f} {1 / with_image:>9.0f} {without * 1e3:>13.2f} "
              f"{1 / without:>9.0f} {with_image / without:>6.1f}")
    print("ratio = step time with rendering / without (the camera's share of a simulator step)")


if __name__ == "__main__":
    main()
