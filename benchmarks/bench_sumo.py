"""SUMO simulator cost: step cost per scenario (rendering excluded) and episode start-up cost.

    python benchmarks/bench_sumo.py [--steps 200] [--scenarios all] [--traffic 1200]

For every scenario of the suite, the ego cruises at about 6 m/s (a fixed throttle law, no model) for
``--steps`` steps or until the episode ends. Figures printed, per scenario:

- ``cold``: the first reset with an empty network cache (netconvert builds the network, SUMO starts);
- ``reset``: a reset with the network cached (SUMO reloads it in place, the episode is set up);
- ``step``: the whole ``step()`` (render=False): ego, scripted road users, SUMO, collisions, ground truth;
- ``sumo``: the part of a step spent outside the shared ground truth (libsumo: placing the ego and the
  stand-ins, SUMO's own step, reading the road users back, SUMO's collisions) — the target is < 2 ms;
- ``truth``: the shared ground-truth computation (:class:`~vladrivebench.world._truth.TruthTracker`), the
  same code and cost as in the kinematic simulator;
- the same with background traffic (``--traffic`` vehicles and pedestrians per hour) on three scenarios.
Ratios against the 2 ms target are printed; the machine may be shared, so the load average is printed too.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

TARGET_MS = 2.0


def cruise(speed: float):
    from vladrivebench.records import Control

    return Control(throttle=0.5 if speed < 6.0 else 0.0, steer=0.0, brake=0.0, v_des=6.0)


def measure(sim, scenario, steps: int) -> dict[str, float]:
    """Per-step times (ms) of one episode: whole step, ground truth, and the rest."""
    obs = sim.reset(scenario, 0)
    truth_time = [0.0]
    observe = sim.truth.observe

    def timed_observe(*args, **kwargs):
        started = time.perf_counter()
        try:
            return observe(*args, **kwargs)
        finally:
            truth_time[0] += time.perf_counter() - started

    sim.truth.observe = timed_observe
    step_times, truth_times = [], []
    while not obs.ground_truth.terminal and len(step_times) < steps:
        truth_time[0] = 0.0
        started = time.perf_counter()
        obs = sim.step(cruise(obs.ego.speed))
        step_times.append(time.perf_counter() - started)
        truth_times.append(truth_time[0])
    step = statistics.mean(step_times) * 1000
    truth = statistics.mean(truth_times) * 1000
    return {"step": step, "truth": truth, "sumo": step - truth, "steps": len(step_times),
            "actors": len(obs.ground_truth.actors)}


def startup(make, scenario, cache: Path) -> tuple[float, float]:
    """(cold, warm) reset time in ms: with an empty network cache, then with the network cached."""
    shutil.rmtree(cache, ignore_errors=True)
    sim = make(cache)
    started = time.perf_counter()
    sim.reset(scenario, 0)
    cold = time.perf_counter() - started
    warm = []
    for seed in (1, 2, 3):
        started = time.perf_counter()
        sim.reset(scenario, seed)
        warm.append(time.perf_counter() - started)
    sim.close()
    return cold * 1000, statistics.median(warm) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--scenarios", default="all")
    parser.add_argument("--traffic", type=float, default=1200.0)
    args = parser.parse_args()

    from vdb_sim_sumo.plugin import make_simulator
    from vladrivebench._scenarios.spec import resolve_scenarios

    scenarios = resolve_scenarios(args.scenarios)
    work = Path(tempfile.mkdtemp(prefix="vdb-bench-sumo-"))
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; {args.steps} steps per scenario")
    header = f"{'scenario':18s} {'cold ms':>8s} {'reset ms':>9s} {'step ms':>8s} {'sumo ms':>8s} " \
             f"{'truth ms':>9s} {'sumo/target':>12s} {'actors':>7s}"
    try:
        print(header)
        sumo_parts, resets, colds = [], [], []
        for scenario in scenarios:
            cache = work / scenario.id
            cold, warm = startup(lambda c: make_simulator(render=False, cache_dir=str(c)), scenario, cache)
            sim = make_simulator(render=False, cache_dir=str(cache))
            figures = measure(sim, scenario, args.steps)
            sim.close()
            sumo_parts.append(figures["sumo"])
            resets.append(warm)
            colds.append(cold)
            print(f"{scenario.id:18s} {cold:8.1f} {warm:9.1f} {figures['step']:8.2f} {figures['sumo']:8.2f} "
                  f"{figures['truth']:9.2f} {figures['sumo'] / TARGET_MS:12.2f} {figures['actors']:7d}")
        print(f"{'mean':18s} {statistics.mean(colds):8.1f} {statistics.mean(resets):9.1f} {'':8s} "
              f"{statistics.mean(sumo_parts):8.2f} {'':9s} {statistics.mean(sumo_parts) / TARGET_MS:12.2f}")
        print(f"\nwith background traffic: {args.traffic:g} vehicles/h and {args.traffic:g} pedestrians/h, "
              "20 s warm-up")
        print(header)
        for scenario_id in ("C.2", "TL.1-red", "S.3"):
            scenario = resolve_scenarios(scenario_id)[0]
            cache = work / f"traffic-{scenario_id}"

            def make(c):
                return make_simulator(render=False, cache_dir=str(c), background_vehicles_per_hour=args.traffic,
                                      background_pedestrians_per_hour=args.traffic, background_warmup_s=20.0)

            cold, warm = startup(make, scenario, cache)
            sim = make(cache)
            figures = measure(sim, scenario, args.steps)
            sim.close()
            print(f"{scenario.id:18s} {cold:8.1f} {warm:9.1f} {figures['step']:8.2f} {figures['sumo']:8.2f} "
                  f"{figures['truth']:9.2f} {figures['sumo'] / TARGET_MS:12.2f} {figures['actors']:7d}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
