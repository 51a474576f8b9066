"""The foundation's figures: simulator + rendering cost relative to a scripted-model step, closed-loop steps
per second, and `vdb list-plugins` wall time.

    python benchmarks/bench_foundation.py [--steps 300] [--repeats 3]

Times of steps are CPU times of this process (best of ``--repeats``): the machine may be shared, so wall
time would measure other processes' load. `vdb list-plugins` is timed as wall time of a fresh
interpreter (that is what a user waits for), median of 5; target under 0.5 s.
"""

from __future__ import annotations

import argparse
import math
import statistics
import subprocess
import sys
import time

SCENARIO = "P.2"


def closed_loop_costs(steps: int, repeats: int) -> dict[str, float]:
    """CPU seconds per step of the simulator (with camera), the scripted model and the PID controller."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.rng import step_rng
    from vladrivebench._scenarios.spec import resolve_scenarios

    registry = get_registry()
    (scenario,) = resolve_scenarios(SCENARIO)
    sim = registry.create("simulator", "kinematic", {})
    model = registry.create("model", "scripted", {})
    controller = registry.create("controller", "pid", {})
    best = {"simulator": math.inf, "model": math.inf, "controller": math.inf}
    for _ in range(repeats):
        spent = dict.fromkeys(best, 0.0)
        obs, seed = sim.reset(scenario, 0), 0
        model.reset(seed)
        controller.reset()
        for _ in range(steps):
            if obs.ground_truth.terminal:
                seed += 1
                obs = sim.reset(scenario, seed)
                model.reset(seed)
                controller.reset()
            t0 = time.process_time()
            cot = model.generate_cot(obs, step_rng(seed, obs.step, "cot", obs.scenario_id))
            trajectory = model.decode_action(obs, cot, step_rng(seed, obs.step, "action", obs.scenario_id))
            t1 = time.process_time()
            control = controller.control(trajectory, obs.ego, sim.dt)
            t2 = time.process_time()
            obs = sim.step(control)
            t3 = time.process_time()
            spent["model"] += t1 - t0
            spent["controller"] += t2 - t1
            spent["simulator"] += t3 - t2
        best = {k: min(best[k], spent[k] / steps) for k in best}
    return best


def wall_time(args: list[str], runs: int = 5) -> float:
    """Median wall time of a fresh interpreter running ``args``."""
    times = []
    for _ in range(runs):
        started = time.perf_counter()
        subprocess.run([sys.executable, *args], check=True, capture_output=True)
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    costs = closed_loop_costs(args.steps, args.repeats)
    loop = sum(costs.values())
    print(f"closed loop on {SCENARIO} (kinematic, camera 160x80; scripted; pid), CPU ms per step, "
          f"best of {args.repeats} x {args.steps} steps:")
    for name, seconds in costs.items():
        print(f"  {name:<11} {seconds * 1e3:7.3f} ms")
    print(f"  simulator + rendering / scripted-model step = {costs['simulator'] / costs['model']:.2f}")
    print(f"  closed-loop steps per second (CPU) = {1 / loop:.0f}  ({1 / loop / 10:.0f}x real time at 10 Hz)")
    wall = wall_time(["-m", "vladrivebench._cli.main", "list-plugins"])
    bare = wall_time(["-c", "pass"])
    print(f"vdb list-plugins wall time (median of 5 fresh interpreters) = {wall:.3f} s; "
          f"target 0.5 s -> {wall / 0.5:.2f} of the target; a bare interpreter start here takes {bare:.3f} s "
          f"(list-plugins = {wall / bare:.1f}x a bare start)")


if __name__ == "__main__":
    main()
