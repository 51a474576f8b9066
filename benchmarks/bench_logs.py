"""Episode logs: the size and speed cost of message indexes and of the Foxglove channels, per episode.

    python benchmarks/bench_logs.py [--scenarios P.1,C.1,TL.1-red] [--repeats 3] [--no-images]

Runs the scripted model on the kinematic simulator once (``vdb run``, camera logged unless
``--no-images``), then rewrites every step of every episode with four writer configurations and reads each
result back with ``read_episode``:

- ``1.0``: the old layout — own channels only, no message indexes (Foxglove's indexed reader cannot play it);
- ``+index``: own channels with message indexes;
- ``+foxglove``: own channels, message indexes and the Foxglove channels (frames, scene, trajectory, CoT)
  — what ``vdb run`` writes;
- with ``--log-images`` logs, every configuration also carries the camera.

Figures printed per configuration (means over episodes; times are the best of ``--repeats``): bytes per
episode, write and read milliseconds per episode, and every ratio to ``1.0`` measured in this run.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

CONFIGS = {
    "1.0": {"foxglove": False, "message_indexes": False},
    "+index": {"foxglove": False, "message_indexes": True},
    "+foxglove": {"foxglove": True, "message_indexes": True},
}


def record_run(out: Path, scenarios: str, images: bool) -> list[Path]:
    from vladrivebench._cli.main import main

    args = ["run", "--model", "scripted", "--scenarios", scenarios, "--seeds", "1", "--quiet", "--out", str(out)]
    if images:
        args.insert(-2, "--log-images")
    status = main(args)
    if status not in (0, None):
        sys.exit(f"bench_logs: `vdb {' '.join(args)}` exited {status}")
    return sorted((out / "episodes").glob("*.mcap"))


def replay_inputs(path: Path) -> tuple[dict, list[tuple], dict, bool]:
    """What the writer was given for each step of a logged episode."""
    from vladrivebench._engine.runner import observation_from_step
    from vladrivebench._logs.episodes import read_episode

    episode = read_episode(path)
    steps = [(observation_from_step(s, scenario_id=episode.scenario_id), s.cot, s.trajectory, s.control, s.extras)
             for s in episode.steps]
    images = episode.steps[0].image_png is not None
    meta = {k: v for k, v in episode.meta.items() if k != "schema_version"}
    return meta, steps, episode.result or {}, images


def write(path: Path, meta: dict, steps: list[tuple], result: dict, images: bool, options: dict) -> float:
    from vladrivebench._logs.episodes import EpisodeWriter

    start = time.perf_counter()
    with EpisodeWriter(path, meta, log_images=images, **options) as writer:
        for step in steps:
            writer.write_step(*step)
        writer.finish(result)
    return time.perf_counter() - start


def read(path: Path) -> float:
    from vladrivebench._logs.episodes import read_episode

    start = time.perf_counter()
    read_episode(path)
    return time.perf_counter() - start


def measure(episodes: list[Path], work: Path, repeats: int) -> dict[str, dict[str, float]]:
    figures = {name: {"bytes": [], "write": [], "read": []} for name in CONFIGS}
    for index, source in enumerate(episodes):
        meta, steps, result, images = replay_inputs(source)
        for name, options in CONFIGS.items():
            target = work / f"{index}-{name}.mcap"
            figures[name]["write"].append(min(write(target, meta, steps, result, images, options)
                                              for _ in range(repeats)))
            figures[name]["read"].append(min(read(target) for _ in range(repeats)))
            figures[name]["bytes"].append(target.stat().st_size)
    return {name: {k: statistics.fmean(v) for k, v in f.items()} for name, f in figures.items()}


def report(figures: dict[str, dict[str, float]], steps: float, images: bool) -> None:
    base = figures["1.0"]
    print(f"episode logs, mean of the episodes ({steps:.0f} steps each on average), camera "
          f"{'logged' if images else 'not logged'}")
    print(f"{'config':<10} {'bytes/episode':>14} {'size ×':>7} {'write ms':>9} {'write ×':>8} "
          f"{'read ms':>8} {'read ×':>7}")
    for name, f in figures.items():
        print(f"{name:<10} {f['bytes']:>14,.0f} {f['bytes'] / base['bytes']:>7.2f} {f['write'] * 1e3:>9.1f} "
              f"{f['write'] / base['write']:>8.2f} {f['read'] * 1e3:>8.1f} {f['read'] / base['read']:>7.2f}")
    index, full = figures["+index"], figures["+foxglove"]
    print(f"message indexes: +{(index['bytes'] / base['bytes'] - 1) * 100:.1f} % size, "
          f"+{(index['bytes'] - base['bytes']) / steps:.0f} bytes/step")
    print(f"Foxglove channels: +{(full['bytes'] / index['bytes'] - 1) * 100:.1f} % size over +index, "
          f"+{(full['bytes'] - index['bytes']) / steps:.0f} bytes/step, write ×{full['write'] / index['write']:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", default="P.1,C.1,TL.1-red")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-images", action="store_true", help="also measure logs without the camera")
    args = parser.parse_args()
    from vladrivebench._logs.episodes import read_episode

    with tempfile.TemporaryDirectory() as directory:
        work = Path(directory)
        for images in ((False,) if args.no_images else (False, True)):
            episodes = record_run(work / f"run-{images}", args.scenarios, images)
            steps = statistics.fmean(len(read_episode(p).steps) for p in episodes)
            (work / f"bench-{images}").mkdir()
            report(measure(episodes, work / f"bench-{images}", args.repeats), steps, images)
            print()


if __name__ == "__main__":
    main()
