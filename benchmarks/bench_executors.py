"""Executors: speed-up of the process pool and of Ray over sequential on a 16-episode sweep, and the
per-episode overhead of each executor.

    python benchmarks/bench_executors.py [--workers 2] [--seeds 4] [--render] [--no-ray]

The sweep is the scripted model on the kinematic simulator (PID), scenarios P.1, C.1, TL.1-red, E.1 ×
``--seeds`` seeds (16 episodes by default), camera off unless ``--render``. Every executor writes its own
output directory; the benchmark checks that all of them wrote byte-identical logs.

Figures printed:
- the ceiling: how much faster perfectly parallel CPU work runs on the same number of processes at that
  moment (≈ 2× on 2 free cores; a busy shared machine gives less, and no executor can beat it);
- sweep wall time and speed-up over sequential (target ≥ 1.6× with 2 workers on 2 free cores). For Ray,
  the sweep time includes creating the actors but not starting Ray itself, printed separately;
- per-episode overhead: the wall time per job of dispatching a job that does nothing and returning its
  result (``--overhead-jobs`` jobs), and the executor's start-up (spawning processes / actors).
The machine may be shared: the load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

SCENARIOS = ("P.1", "C.1", "TL.1-red", "E.1")


def noop(job):
    """A job that does nothing: what is left of its wall time is the executor's own cost."""
    return job


def burn(iterations: int) -> float:
    """Pure-Python CPU work; returns its own wall time."""
    started = time.perf_counter()
    total = 0
    for i in range(iterations):
        total += i
    return time.perf_counter() - started


def available_parallelism(workers: int, iterations: int = 4_000_000) -> float:
    """Speed-up of perfectly parallel CPU work on ``workers`` processes right now (the ceiling for any
    executor: on a shared machine it can be far below ``workers``)."""
    import multiprocessing

    started = time.perf_counter()
    for _ in range(workers):
        burn(iterations)
    sequential = time.perf_counter() - started
    with multiprocessing.get_context("spawn").Pool(workers) as pool:
        pool.map(burn, [10] * workers)  # start the processes first
        started = time.perf_counter()
        pool.map(burn, [iterations] * workers)
        parallel = time.perf_counter() - started
    return sequential / parallel


def sweep_config(seeds: int, render: bool):
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._engine.sweep import ComponentSpec, RunConfig
    from vladrivebench._scenarios.spec import resolve_scenarios

    scenarios = resolve_scenarios(list(SCENARIOS), get_registry())
    return RunConfig(ComponentSpec("model", "scripted"), ComponentSpec("simulator", "kinematic", {"render": render}),
                     ComponentSpec("controller", "pid"), tuple(scenarios), tuple(range(seeds)))


def timed_sweep(config, out: Path, executor) -> float:
    from vladrivebench._engine.sweep import run_sweep

    started = time.perf_counter()
    summary = run_sweep(config, out, executor=executor)
    if summary.failures:
        raise SystemExit(f"benchmark sweep failed: {next(iter(summary.failures.values()))['error']}")
    return time.perf_counter() - started


def overhead(executor, jobs: int) -> tuple[float, float]:
    """(start-up seconds, seconds per no-op job) of an executor."""
    started = time.perf_counter()
    stream = executor.run(noop, range(jobs))
    next(stream)
    first = time.perf_counter() - started
    rest_started = time.perf_counter()
    count = 1 + sum(1 for _ in stream)
    assert count == jobs
    return first, (time.perf_counter() - rest_started) / max(1, jobs - 1)


def logs_of(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted((directory / "episodes").glob("*.mcap"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--render", action="store_true", help="render the camera (heavier episodes)")
    parser.add_argument("--no-ray", action="store_true", help="skip Ray (e.g. not installed)")
    parser.add_argument("--overhead-jobs", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=1, help="rounds over all executors; best time kept")
    args = parser.parse_args()

    from vladrivebench._engine.executors import ProcessExecutor, SequentialExecutor

    config = sweep_config(args.seeds, args.render)
    episodes = len(config.scenarios) * len(config.seeds)
    root = Path(tempfile.mkdtemp(prefix="vdb-bench-executors-"))
    print(f"{episodes}-episode sweep (scripted, kinematic{'' if args.render else ' without camera'}, pid), "
          f"{args.workers} workers, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    ceiling = available_parallelism(args.workers)
    print(f"ceiling: perfectly parallel CPU work runs {ceiling:.2f}× faster on {args.workers} processes right now")
    try:
        executors = {"sequential": SequentialExecutor, "process": lambda: ProcessExecutor(workers=args.workers)}
        startups = {}
        if not args.no_ray:
            import ray
            from vdb_executor_ray.executor import RayExecutor

            started = time.perf_counter()
            RayExecutor(workers=args.workers)._connect(ray)
            startups["ray init"] = time.perf_counter() - started
            executors["ray"] = lambda: RayExecutor(workers=args.workers)
        times: dict[str, float] = {}
        for round_index in range(args.repeats):  # interleaved, so a busy spell of a shared machine hits all
            for name, make in executors.items():
                out = root / f"{name}{round_index}"
                times[name] = min(times.get(name, float("inf")), timed_sweep(config, out, make()))
        reference = logs_of(root / "sequential0")
        identical = all(logs_of(path) == reference for path in root.iterdir())
        base = times["sequential"]
        print(f"{'executor':<12}{'sweep (s)':>10}{'per episode':>13}{'speed-up':>10}")
        for name, seconds in times.items():
            print(f"{name:<12}{seconds:>10.2f}{seconds / episodes:>12.3f}s{base / seconds:>9.2f}×")
        print(f"logs byte-identical across executors: {identical}; load average now {os.getloadavg()[0]:.1f}; "
              f"ceiling now {available_parallelism(args.workers):.2f}×")
        print(f"\nper-episode overhead (no-op jobs, {args.overhead_jobs} each):")
        executors = {"sequential": SequentialExecutor(), "process": ProcessExecutor(workers=args.workers)}
        if not args.no_ray:
            executors["ray"] = RayExecutor(workers=args.workers)
        for name, executor in executors.items():
            startup, per_job = overhead(executor, args.overhead_jobs)
            print(f"{name:<12}start-up {startup:7.3f} s   per job {per_job * 1e3:8.3f} ms")
        for name, seconds in startups.items():
            print(f"{name:<12}{seconds:7.2f} s (once per sweep when vdb starts Ray itself)")
        if not args.no_ray:
            ray.shutdown()
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
