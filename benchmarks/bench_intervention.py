"""Open-loop intervention cost: K conditions per step relative to one baseline step, end to end.

    python benchmarks/bench_intervention.py [--models scripted,kv,qa] [--steps 40] [--repeats 5] [--ks 0,1,2,4]
                                            [--kv-weights DIR] [--part all|open-loop|lockstep]
                                            [--batches 4,8,16] [--lockstep-seeds 4]

For each model, a baseline episode (the model's own CoT drives; simulator + camera rendering + model +
PID controller + MCAP logging) is timed per step, then open-loop episodes of the same steps with the
selfsplice gate and K conditions. Everything that does not depend on the CoT — simulation, rendering, the
model's vision prefix when it caches it per observation — is done once per step, so each extra condition
should only cost a splice and an action decode. Printed per model and splice path:

- ms per step of the baseline and of open-loop with K = 0 (gate only), 1, 2, 4 conditions;
- the cost of each extra condition (least-squares slope over K ≥ 1) relative to a baseline step — the target is
  at most 0.15 for a model that caches its vision prefix (``kv``: batched decoding over the shared prefix,
  ``--batch-conditions``);
- the gate's own cost (K = 0 minus the baseline).

Then (``--part lockstep``, or ``all``) ``vdb intervene --batch B`` on ``kv``: a closed-loop run (E.1, selfsplice,
accel, pedestrian, car), a safety run (SAFE.kerb-ped, accel) and an open-loop run (E.1, the closed-loop
conditions), ``--lockstep-seeds`` seeds each, at B = 1 and
each of ``--batches``; printed per run and B: wall and CPU seconds, the wall-time ratio against B = 1, whether
the selfsplice gate held, and the largest trajectory difference batched vs unbatched — at step 0 (the same
observation: floating point alone) and over every step (closed loop: with the drift it causes).

``kv`` needs weights: the plugin's own, ``--kv-weights DIR``, or (when neither exists) a small bundle
trained for this benchmark in a temporary folder (~20 s; speed does not depend on training quality).
Times are CPU seconds of this process (one thread), the minimum over ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path

CONDITION_POOL = ("pedestrian", "accel", "car", "animal", "red-light", "depicts-3", "depicts-10", "depicts-20")
"""Extra conditions in the order they are added: the paper's one-sentence texts first (similar in length to
a model's own CoT), then short repeated-token probes."""
TARGET = 0.15


def build(registry, kind: str, name: str, options: dict):
    return registry.create(kind, name, options)


def timed_episode(model, sim, controller, route, policy, out: Path) -> tuple[float, int]:
    """CPU seconds (of this process) per step of one episode run with ``policy`` and logged to ``out``.

    CPU time rather than wall time: the machine is shared, and every component here runs on this process's
    one thread (the neural models default to one torch thread), so CPU time is what the step costs.
    """
    from vladrivebench._engine.runner import run_episode
    from vladrivebench._logs.episodes import EpisodeWriter

    started = time.process_time()
    with EpisodeWriter(out, {"episode_id": out.stem, "model": {"name": "bench"}, "scenario": {"id": route.id},
                             "seed": 0}) as writer:
        result = run_episode(model, sim, controller, route, 0, policy=policy, writer=writer)
        writer.finish(result.to_json())
    seconds = time.process_time() - started
    out.unlink()
    return seconds / result.steps, result.steps


def measure(model, sim, controller, route, make_policy, repeats: int, folder: Path) -> float:
    times = [timed_episode(model, sim, controller, route, make_policy(), folder / "bench.mcap")[0]
             for _ in range(repeats)]
    return min(times)


def slope(xs: list[float], ys: list[float]) -> float:
    mx, my = statistics.fmean(xs), statistics.fmean(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sum((x - mx) ** 2 for x in xs)


def kv_weights(explicit: str | None) -> str | None:
    """A weights folder for ``kv``: explicit, the plugin's own (None), or a small bundle trained now."""
    if explicit:
        return explicit
    try:
        from vdb_model_neural.common import WEIGHTS_DIR
    except ImportError:
        return None
    if (WEIGHTS_DIR / "kv.safetensors").exists():
        return None
    from vdb_model_neural.train import train_command

    folder = tempfile.mkdtemp(prefix="bench-kv-")
    print(f"kv: no trained weights installed; training a small bundle for timing into {folder} …",
          file=sys.stderr)
    train_command("kv", seed=0, episodes=4, steps=20, out=Path(folder), threads=1)
    return folder


def bench_model(registry, label: str, name: str, options: dict, batch: bool, args, route, folder: Path) -> dict:
    from vladrivebench._intervention.conditions import build_library
    from vladrivebench._intervention.runs import BaselinePolicy, OpenLoopPolicy, Splicer

    model = build(registry, "model", name, options)
    sim = build(registry, "simulator", "kinematic", {})
    controller = build(registry, "controller", "pid", {})
    splicer = Splicer(model, build_library(registry), {}, name)
    base = measure(model, sim, controller, route, BaselinePolicy, args.repeats, folder)
    per_k = {}
    for k in args.ks:
        conditions = ("selfsplice",) + CONDITION_POOL[:k]
        per_k[k] = measure(model, sim, controller, route,
                           lambda conditions=conditions: OpenLoopPolicy(splicer, conditions, (2.0, 3.0), batch),
                           args.repeats, folder)
    ks = [k for k in sorted(per_k) if k >= 1]  # K = 0 has no condition call at all: it is the gate alone
    extra = slope([float(k) for k in ks], [per_k[k] for k in ks]) if len(ks) >= 2 else float("nan")
    close = getattr(sim, "close", None)
    if callable(close):
        close()
    return {"label": label, "baseline": base, "per_k": per_k, "extra": extra, "ratio": extra / base,
            "gate": per_k.get(0, float("nan")) - base}


LOCKSTEP_RUNS = (("closed-loop", "E.1", ("selfsplice", "accel", "pedestrian", "car")),
                 ("safety", "SAFE.kerb-ped", ("selfsplice", "accel")),
                 ("open-loop", "E.1", ("selfsplice", "accel", "pedestrian", "car")))


def lockstep_run(registry, mode: str, route, conditions, seeds: int, batch: int, options: dict, out: Path
                 ) -> dict:
    """One ``vdb intervene`` run at ``batch``: wall and CPU seconds and its results."""
    from vladrivebench._engine.sweep import ComponentSpec
    from vladrivebench._intervention.runs import InterventionConfig, InterventionRun

    config = InterventionConfig(mode=mode, model=ComponentSpec("model", "kv", options),
                                simulator=ComponentSpec("simulator", "kinematic", {}),
                                controller=ComponentSpec("controller", "pid", {}), routes=(route,),
                                conditions=conditions, seeds=tuple(range(seeds)), batch=batch)
    wall, cpu = time.perf_counter(), time.process_time()
    results = InterventionRun(config, out, registry=registry).run()
    return {"wall": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "valid": results["valid"],
            "out": out}


def trajectory_differences(a: Path, b: Path) -> tuple[float, float]:
    """Largest waypoint difference (m) between two runs' logs of the same episodes: at step 0, and over the
    steps both episodes have."""
    import numpy as np
    from vladrivebench._logs.episodes import find_episodes, read_episode

    first = every = 0.0
    for pa, pb in zip(find_episodes(a), find_episodes(b), strict=True):
        for sa, sb in zip(read_episode(pa).steps, read_episode(pb).steps, strict=False):
            diff = float(np.max(np.abs(np.asarray(sa.trajectory["xy"]) - np.asarray(sb.trajectory["xy"]))))
            every = max(every, diff)
            if sa.step == 0:
                first = max(first, diff)
    return first, every


def bench_lockstep(registry, args, folder: Path) -> None:
    from vladrivebench._scenarios.spec import resolve_scenarios

    weights = kv_weights(args.kv_weights)
    options = {"weights_dir": weights} if weights else {}
    batches = [1] + [b for b in args.batches if b != 1]
    warm_up = build(registry, "model", "kv", options), build(registry, "simulator", "kinematic", {})
    warm_up[1].reset(resolve_scenarios("E.1", registry)[0], 0)  # imports and first-use costs out of the timings
    print(f"\nvdb intervene --batch B on kv: {args.lockstep_seeds} seeds, {args.steps} steps per episode at most, "
          "kinematic simulator with rendering, PID, MCAP logging; wall time of the whole run (shared machine: see the "
          "load average)")
    header = ["run", "B", "episodes", "wall s", "cpu s", "wall ratio vs B=1", "gate", "max Δ step 0 (m)",
              "max Δ any step (m)"]
    lines = [header]
    for mode, route_id, conditions in LOCKSTEP_RUNS:
        route = dataclasses.replace(resolve_scenarios(route_id, registry)[0], max_time_s=args.steps / 10.0)
        episodes = args.lockstep_seeds * (1 if mode == "open-loop" else 1 + len(conditions))
        runs = {b: lockstep_run(registry, mode, route, conditions, args.lockstep_seeds, b, options,
                                folder / f"{mode}-b{b}") for b in batches}
        for b, r in runs.items():
            first, every = trajectory_differences(r["out"], runs[1]["out"])
            lines.append([f"{mode} {route_id}", str(b), str(episodes), f"{r['wall']:.1f}", f"{r['cpu']:.1f}",
                          f"{runs[1]['wall'] / r['wall']:.2f}×", "holds" if r["valid"] else "FAILED",
                          f"{first:.2g}", f"{every:.2g}"])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    for line in lines:
        print("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)))
    import os

    print(f"load average (1, 5, 15 min) at the end: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", default="scripted,kv,qa")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ks", default="0,1,2,4")
    parser.add_argument("--kv-weights")
    parser.add_argument("--part", choices=("all", "open-loop", "lockstep"), default="all")
    parser.add_argument("--batches", default="4,8,16", help="lockstep batch sizes compared with B = 1")
    parser.add_argument("--lockstep-seeds", type=int, default=4)
    args = parser.parse_args(argv)
    args.ks = [int(k) for k in args.ks.split(",")]
    args.batches = [int(b) for b in args.batches.split(",")]
    if max(args.ks) > len(CONDITION_POOL):
        parser.error(f"--ks: at most {len(CONDITION_POOL)} conditions")

    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import resolve_scenarios

    registry = get_registry()
    route = dataclasses.replace(resolve_scenarios("E.1", registry)[0], max_time_s=args.steps / 10.0)
    variants = []
    for name in args.models.split(","):
        if name not in registry.names("model"):
            print(f"{name}: not installed, skipped", file=sys.stderr)
            continue
        if name == "kv":
            weights = kv_weights(args.kv_weights)
            options = {"weights_dir": weights} if weights else {}
            variants += [("kv sequential splice (bit-exact), one by one", name, {**options, "splice_mode": "sequential"},
                          False),
                         ("kv batched over the shared vision prefix", name, {**options, "splice_mode": "sequential"},
                          True)]
        elif name == "qa":
            variants.append(("qa (three QA rounds) sequential splice, one by one", name, {}, False))
        elif name == "scripted":
            variants.append(("scripted (alpha=1, no vision encoder)", name, {"alpha": 1.0}, False))
        else:
            variants.append((name, name, {}, False))
    if args.part == "lockstep":
        variants = []
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, name, options, batch in variants:
            rows.append(bench_model(registry, label, name, options, batch, args, route, Path(tmp)))
        if args.part != "open-loop" and "kv" in registry.names("model"):
            bench_lockstep(registry, args, Path(tmp))
    if not rows:
        return 0
    print(f"Open-loop intervention cost on E.1, {args.steps} steps, kinematic simulator with rendering, PID, "
          f"MCAP logging; CPU ms per step, min of {args.repeats} runs")
    header = ["model / splice path", "baseline ms/step"] + [f"K={k}" for k in args.ks] + \
        ["ms per extra condition", "ratio to baseline", f"≤ {TARGET:g}?", "gate ms"]
    lines = [header]
    for r in rows:
        lines.append([r["label"], f"{r['baseline'] * 1e3:.2f}"] + [f"{r['per_k'][k] * 1e3:.2f}" for k in args.ks]
                     + [f"{r['extra'] * 1e3:.2f}", f"{r['ratio']:.3f}", "yes" if r["ratio"] <= TARGET else "no",
                        f"{r['gate'] * 1e3:.2f}"])
    widths = [max(len(line[i]) for line in lines) for i in range(len(header))]
    for line in lines:
        print("  ".join(cell.ljust(w) for cell, w in zip(line, widths, strict=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
