"""The scripted model and the controllers: time per 10 Hz step, as a fraction of the step's 100 ms.

    python benchmarks/bench_scripted_controllers.py [--steps 2000]

Figures printed (median of 5 repeats, on hand-built observations covering every decision the scripted
model makes):
- scripted model, ``generate_cot`` + ``decode_action`` per step, sentence and qa formats;
- scripted model, ``splice_cot`` + ``decode_action`` (one intervention condition at one step);
- PID and MPC controllers, ``control`` per step on the model's trajectories.
Each line ends with the ratio to real time (100 ms / time per step). Targets: model ≥ 100× real time,
PID ≥ 500×, MPC ≥ 50× — a sweep must be dominated by the simulator, not by these.
The machine may be shared: the load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
from vdb_model_scripted.model import ScriptedModel
from vdb_model_scripted.testing import make_observation
from vladrivebench._builtins.controllers import MPCController, PIDController

SITUATIONS = [dict(), dict(kind="pedestrian", distance=30.0), dict(kind="car", distance=12.0),
              dict(kind="traffic_light", distance=14.0, light="red"), dict(kind="stop_sign", distance=12.0),
              dict(kind="pedestrian", distance=15.0, actor_speed=1.5)]
TARGETS = {"model": 100.0, "pid": 500.0, "mpc": 50.0}


def timed(fn, steps: int, repeats: int = 5) -> float:
    """Median seconds per call of ``fn(i)`` over ``steps`` calls."""
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        for i in range(steps):
            fn(i)
        runs.append((time.perf_counter() - start) / steps)
    return statistics.median(runs)


def report(name: str, seconds: float, target: float) -> None:
    ratio = 0.1 / seconds
    verdict = "ok" if ratio >= target else "BELOW TARGET"
    print(f"{name:<40} {seconds * 1e3:8.3f} ms/step  {ratio:9.0f}× real time  (target ≥ {target:g}×: {verdict})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    observations = [make_observation(step=i, **SITUATIONS[i % len(SITUATIONS)]) for i in range(len(SITUATIONS) * 4)]
    rng = np.random.default_rng(0)
    print(f"load average: {os.getloadavg()[0]:.2f} (cores: {os.cpu_count()})")
    for fmt in ("sentence", "qa"):
        model = ScriptedModel(alpha=0.5, miss_rate=0.1, hallucination_rate=0.1, contradiction_rate=0.1,
                              cot_format=fmt)

        def own(i, model=model):
            obs = observations[i % len(observations)]
            model.decode_action(obs, model.generate_cot(obs, rng), rng)

        def spliced(i, model=model):
            obs = observations[i % len(observations)]
            model.decode_action(obs, model.splice_cot(obs, "Stop for the pedestrian in the lane.", rng), rng)

        report(f"scripted ({fmt}) generate + decode", timed(own, args.steps), TARGETS["model"])
        report(f"scripted ({fmt}) splice + decode", timed(spliced, args.steps), TARGETS["model"])

    model = ScriptedModel(alpha=0.5)
    pairs = [(obs, model.decode_action(obs, model.generate_cot(obs, rng), rng)) for obs in observations]
    for name, controller in (("pid", PIDController()), ("mpc", MPCController())):
        def control(i, controller=controller):
            obs, trajectory = pairs[i % len(pairs)]
            controller.control(trajectory, obs.ego, 0.1)

        report(f"controller {name}", timed(control, args.steps), TARGETS[name])


if __name__ == "__main__":
    main()
