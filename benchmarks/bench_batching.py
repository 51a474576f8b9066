"""Lockstep batches (`vdb run --batch B`): closed-loop throughput, the harness's share broken down,
the renderer alone, batched-vs-unbatched difference and the demo's wall time, all measured in one run.

    python benchmarks/bench_batching.py [--steps 20] [--sizes 1,4,16,64] [--repeats 1] [--sweep-seconds 5]
                                        [--skip-sweep] [--skip-demo] [--skip-pipelined] [--pipelined-steps 40]

1. Closed-loop steps per second of ``kv`` and ``qa`` on the kinematic simulator (camera rendered, MPC
   controller, every step logged to MCAP) at B = 1 (today's per-episode path, ``run_episode``) and at
   B = 4, 16, 64 in lockstep (``run_lockstep``, one batched model call per step); the speed-up against B = 1.
2. The harness (everything but the model's calls) as a share of the step's wall time, by part: ``render``
   (the camera), ``sim`` (the rest of the simulator's step: motion, collisions, history), ``control`` (the
   MPC controller), ``truth`` (the ground truth), ``logging`` (MCAP writing) and ``loop`` (the episode
   loop itself: validation, tallies, lockstep bookkeeping).
3. The camera rendering alone, CPU milliseconds per step, front camera and ``alpamayo`` rig.
4. The largest waypoint difference between a sweep run at B = 1 and at B = 16 (the demo's scenarios ×
   4 seeds with ``kv``, each cut to ``--sweep-seconds``), over the steps both runs share, and how many
   CoTs differ.
5. ``vdb demo``'s wall time (its episodes, as the demo declares its batch size).
6. (before 1, per model) the same B = 16 sweep sequentially and on the ``pipelined`` executor (the model in a
   model-server process, two batch jobs' harness on threads here): episode-steps per second of both, the
   pipelined rate over the server's span, the share of that span the model server waited (the harness on
   the model's critical path) and whether the logs are the same bytes.

The machine may be shared: read the ratios of one run rather than absolute numbers.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np


def scenario(name: str, seconds: float):
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import load_suite

    return dataclasses.replace(load_suite(get_registry())[name], max_time_s=seconds)


HARNESS_PARTS = ("render", "sim", "control", "truth", "logging", "loop")
"""The parts of a step outside the model: camera rendering, the rest of the simulator's step, the
controller, the ground truth, MCAP logging and the episode loop itself (validation, tallies, batching)."""


class StepTimer:
    """Seconds spent in each part of the closed loop, by wrapping the calls of one run."""

    def __init__(self):
        self.seconds = dict.fromkeys(("model",) + HARNESS_PARTS, 0.0)

    def wrap(self, part: str, function):
        def timed(*args, **kwargs):
            started = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds[part] += time.perf_counter() - started
        return timed

    @contextlib.contextmanager
    def patched(self, owner, name: str, part: str):
        """Time every call of ``owner.name`` (a class's method) while the block runs."""
        original = getattr(owner, name)
        setattr(owner, name, self.wrap(part, original))
        try:
            yield
        finally:
            setattr(owner, name, original)

    def shares(self, wall: float) -> dict[str, float]:
        """Each harness part's share of the wall time; ``sim`` excludes the rendering and ground truth it
        calls, ``loop`` is what no other part accounts for."""
        parts = dict(self.seconds)
        parts["sim"] -= parts["render"] + parts["truth"]
        parts["loop"] = wall - sum(v for k, v in parts.items() if k != "loop")
        return {k: parts[k] / wall for k in HARNESS_PARTS}


def closed_loop(model_name: str, batch: int, steps: int, out: Path) -> tuple[float, float, dict[str, float]]:
    """(episode steps per second, share of the wall time outside the model, that share by harness part)
    for ``batch`` episodes of ``steps`` steps."""
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.runner import (
        LockstepEpisode,
        own_cot_batch_policy,
        own_cot_policy,
        run_episode,
        run_lockstep,
    )
    from vladrivebench._logs.episodes import EpisodeWriter
    from vladrivebench.world import TruthTracker
    from vladrivebench.world._camera import Camera

    registry = get_registry()
    model = registry.create("model", model_name)
    road = scenario("P.1", steps / 10.0)
    timer = StepTimer()
    lanes = []
    for _ in range(batch):
        simulator, controller = registry.create("simulator", "kinematic"), registry.create("controller", "mpc")
        simulator.step = timer.wrap("sim", simulator.step)
        simulator.reset = timer.wrap("sim", simulator.reset)
        controller.control = timer.wrap("control", controller.control)
        lanes.append((simulator, controller))

    def writer(i: int):
        started = time.perf_counter()
        log = EpisodeWriter(out / f"{model_name}-{batch}-{i}.mcap", {"episode_id": str(i)})
        log.__enter__()
        timer.seconds["logging"] += time.perf_counter() - started
        log.write_step = timer.wrap("logging", log.write_step)
        log.finish = timer.wrap("logging", log.finish)  # the result record, fsync and rename
        return log

    results = []

    def done(episode, result, open_writer):
        open_writer.finish(result.to_json())
        results.append(result)

    with timer.patched(Camera, "render", "render"), timer.patched(TruthTracker, "observe", "truth"):
        started = time.perf_counter()
        if batch == 1:
            w = writer(0)
            result = run_episode(model, *lanes[0], road, 0, policy=timer.wrap("model", own_cot_policy), writer=w)
            w.finish(result.to_json())
            results.append(result)
        else:
            episodes = [LockstepEpisode(i, road, i, (lambda i=i: writer(i))) for i in range(batch)]
            run_lockstep(episodes, batch, make_lane=lambda i: (model, *lanes[i]), done=done,
                         batch_policy=timer.wrap("model", own_cot_batch_policy))
        wall = time.perf_counter() - started
    total_steps = sum(r.steps for r in results)
    return total_steps / wall, 1.0 - timer.seconds["model"] / wall, timer.shares(wall)


def pipelined_sweep(model_name: str, batch: int, steps: int, out: Path) -> dict[str, float]:
    """The same sweep (P.1 × two batch jobs' worth of seeds, ``steps`` steps each) run sequentially and on
    the ``pipelined`` executor: episode-steps per second of each (wall time, the pipelined one including
    its model server's start), the pipelined one's rate over the server's span (first model call to last),
    the share of that span the server was not in a model call (the harness, transfers and turns the model
    waited for), and whether the logs are the same bytes."""
    from vladrivebench._engine.executors import PipelinedExecutor, SequentialExecutor
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.sweep import BATCH_JOB_FACTOR, ComponentSpec, RunConfig, run_sweep

    registry = get_registry()
    seeds = tuple(range(2 * BATCH_JOB_FACTOR * batch))
    config = RunConfig(ComponentSpec("model", model_name), ComponentSpec("simulator", "kinematic"),
                       ComponentSpec("controller", "mpc"), (scenario("P.1", steps / 10.0),), seeds, batch=batch)
    rates, executor = {}, PipelinedExecutor(workers=2)
    for name, chosen in (("sequential", SequentialExecutor()), ("pipelined", executor)):
        started = time.perf_counter()
        summary = run_sweep(config, out / f"{model_name}-{name}", executor=chosen, registry=registry)
        wall = time.perf_counter() - started
        lane_steps = sum(result["steps"] for result in summary.results.values())
        rates[name] = lane_steps / wall
    stats = executor.server_stats
    span = stats["last_call"] - stats["first_call"]
    same = all(path.read_bytes() == (out / f"{model_name}-pipelined" / "episodes" / path.name).read_bytes()
               for path in (out / f"{model_name}-sequential" / "episodes").glob("*.mcap"))
    return {"episodes": len(seeds), "sequential": rates["sequential"], "pipelined": rates["pipelined"],
            "span_rate": lane_steps / span, "waiting": 1.0 - stats["model_seconds"] / span, "same_bytes": same}


def render_milliseconds(frames: int = 30) -> dict[str, float]:
    """CPU milliseconds per step of the camera rendering alone, along P.1 (suburban) and S.3 (urban junction),
    for the default front camera and the four-camera ``alpamayo`` rig."""
    from vdb_sim_kinematic.simulator import KinematicSimulator
    from vladrivebench.records import Control

    out = {}
    for rig in ("front", "alpamayo"):
        jobs = []
        for name in ("P.1", "S.3"):
            simulator = KinematicSimulator(rig=rig)
            obs = simulator.reset(scenario(name, 30.0), 0)
            for _ in range(frames // 2):
                jobs.append((simulator, obs.ego, obs.ground_truth.actors))
                obs = simulator.step(Control(0.0, 0.0, 0.0, 6.0, next_state=dataclasses.replace(
                    obs.ego, x=obs.ego.x + 0.6)))
        started = time.process_time()
        for simulator, ego, actors in jobs:
            for camera in simulator.rig.cameras.values():
                camera.render(simulator.road, ego, actors)
        out[rig] = (time.process_time() - started) / len(jobs) * 1e3
    return out


def sweep_difference(batch: int, seconds_per_episode: float) -> tuple[float, int, int, float, float]:
    """(largest waypoint difference in m, differing CoTs, compared steps, seconds at B=1, at B=batch)."""
    from vladrivebench._engine.executors import SequentialExecutor
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.sweep import ComponentSpec, RunConfig, run_sweep
    from vladrivebench._logs.episodes import read_episode

    registry = get_registry()
    scenarios = tuple(scenario(s, seconds_per_episode) for s in ("P.1", "C.1", "TL.1-red", "E.1"))
    seconds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for b in (1, batch):
            config = RunConfig(ComponentSpec("model", "kv"), ComponentSpec("simulator", "kinematic"),
                               ComponentSpec("controller", "mpc"), scenarios, (0, 1, 2, 3), batch=b)
            started = time.perf_counter()
            run_sweep(config, Path(tmp) / f"b{b}", executor=SequentialExecutor(), registry=registry)
            seconds[b] = time.perf_counter() - started
        worst, differing, compared = 0.0, 0, 0
        for path in sorted((Path(tmp) / "b1" / "episodes").glob("*.mcap")):
            a = read_episode(path).steps
            b = read_episode(Path(tmp) / f"b{batch}" / "episodes" / path.name).steps
            for x, y in zip(a, b, strict=False):
                compared += 1
                differing += x.cot["text"] != y.cot["text"]
                worst = max(worst, float(np.max(np.abs(np.asarray(x.trajectory["xy"]) - np.asarray(y.trajectory["xy"])))))
    return worst, differing, compared, seconds[1], seconds[batch]


def demo_seconds() -> float:
    from vladrivebench._cli.run import run_demo

    with tempfile.TemporaryDirectory() as tmp:
        started = time.perf_counter()
        run_demo(Path(tmp) / "demo", quiet=True)
        return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=20, help="steps per episode in part 1")
    parser.add_argument("--sizes", default="1,4,16,64")
    parser.add_argument("--repeats", type=int, default=1, help="runs of every size in part 1 (the median is shown)")
    parser.add_argument("--skip-sweep", action="store_true")
    parser.add_argument("--sweep-seconds", type=float, default=5.0, help="episode length limit in part 3")
    parser.add_argument("--skip-demo", action="store_true")
    parser.add_argument("--skip-pipelined", action="store_true", help="skip the pipelined-executor sweeps")
    parser.add_argument("--pipelined-steps", type=int, default=40,
                        help="steps per episode of the pipelined-executor sweeps (the server's start is in their time)")
    args = parser.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        for model in ("kv", "qa"):
            pipelined = None if args.skip_pipelined else pipelined_sweep(model, 16, args.pipelined_steps, Path(tmp))
            runs = {batch: [] for batch in sizes}
            for _ in range(args.repeats):  # sizes interleaved, so a change of the machine's load hits them all
                for batch in sizes:
                    runs[batch].append(closed_loop(model, batch, args.steps, Path(tmp)))
            base = model_base = None
            for batch in sizes:
                rate, harness, parts = sorted(runs[batch], key=lambda run: run[0])[len(runs[batch]) // 2]
                model_rate = rate / (1.0 - harness)  # episode-steps per second of model time alone
                base, model_base = base or rate, model_base or model_rate
                breakdown = "  ".join(f"{k} {100 * v:4.1f}" for k, v in parts.items())
                print(f"{model} B={batch:>3}: {rate:7.1f} episode-steps/s  ×{rate / base:5.2f} vs B={sizes[0]}  "
                      f"(model time alone ×{model_rate / model_base:5.2f})  harness {100 * harness:4.1f} % of the "
                      f"step: {breakdown} %", flush=True)
            if pipelined is not None:
                p = pipelined
                print(f"{model} B= 16 sweep, {p['episodes']} episodes of P.1 × {args.pipelined_steps} steps: sequential {p['sequential']:6.1f} "
                      f"episode-steps/s, pipelined {p['pipelined']:6.1f} (×{p['pipelined'] / p['sequential']:4.2f}; "
                      f"×{p['pipelined'] / base:4.2f} vs B={sizes[0]} above), over the model server's span "
                      f"{p['span_rate']:6.1f} (×{p['span_rate'] / base:4.2f}); the server out of a model call "
                      f"{100 * p['waiting']:4.1f} % of its span (harness, transfers and turns on the model's "
                      f"critical path); logs {'the same bytes' if p['same_bytes'] else 'DIFFER'}", flush=True)
    rendering = render_milliseconds()
    print(f"camera rendering alone (CPU): {rendering['front']:.2f} ms per step for the front camera (160×80), "
          f"{rendering['alpamayo']:.2f} ms for the alpamayo rig (4 × 576×320)", flush=True)
    if not args.skip_sweep:
        worst, differing, compared, one, sixteen = sweep_difference(16, args.sweep_seconds)
        print(f"kv sweep (P.1, C.1, TL.1-red, E.1 × 4 seeds, ≤ {args.sweep_seconds:g} s each) B=1 vs B=16: largest waypoint difference "
              f"{worst:.3g} m over {compared} shared steps, {differing} CoTs differ; {one:.1f} s vs {sixteen:.1f} s",
              flush=True)
    if not args.skip_demo:
        print(f"vdb demo (its declared batch): {demo_seconds():.1f} s", flush=True)


if __name__ == "__main__":
    main()
