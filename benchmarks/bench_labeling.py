"""Labeling and analysis throughput: the lexicon labeler, the label store's relabel cost, metrics and report.

    python benchmarks/bench_labeling.py [--episodes 12] [--steps 300]

Episodes are the scripted model (with error rates, both CoT formats) driven open-loop along an approach
to a pedestrian or a red light — real CoTs and trajectories, without simulator time. Figures printed:

- lexicon labeler: CoTs per second (``label_batch`` on distinct CoTs);
- ``vdb label`` first run vs the same command again: the second makes no labeler call at all (the store is
  keyed by text + context + labeler version), so its time is reading the logs and the store; printed
  against the time to read the logs alone (target: relabel ≤ 1.5 × reading the logs);
- ``vdb metrics`` and ``vdb report --format html`` wall time per 1,000 logged steps.
The machine may be shared: the load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path


def build(directory: Path, episodes: int, steps: int) -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import test_metrics_calibration as cal  # the open-loop driver of the calibration test

    cal.STEPS = steps
    total = 0
    for i in range(episodes):
        fmt = ("sentence", "qa")[i % 2]
        kind = ("pedestrian", "traffic_light")[(i // 2) % 2]
        cal.drive(directory, {"alpha": 0.5, "cot_format": fmt, **cal.RATES}, kind, seed=i)
        total += steps
    return total


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=12)
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args()

    from vdb_labeler_lexicon import plugin as lexicon_plugin
    from vdb_labeler_lexicon.labeler import LexiconLabeler
    from vladrivebench import _builtins as builtins
    from vladrivebench._analysis.dataset import label_items, read_directory
    from vladrivebench._cli.main import main as vdb
    from vladrivebench.testing import isolated_registry

    work = Path(tempfile.mkdtemp(prefix="vdb-bench-label-"))
    try:
        steps = build(work, args.episodes, args.steps)
        episodes, _ = read_directory(work)
        items = {i.text + repr(i.context): i for _, _, i in label_items(episodes)}
        distinct = list(items.values())
        labeler = LexiconLabeler()
        seconds = timed(lambda: labeler.label_batch(distinct))
        print(f"load average {os.getloadavg()[0]:.2f}; {steps} logged steps, {len(distinct)} distinct CoT+context")
        print(f"lexicon labeler: {len(distinct) / seconds:,.0f} CoTs/s")
        reading = timed(lambda: read_directory(work))
        calls = []
        original = LexiconLabeler.label_batch

        def counted(self, batch):
            calls.append(len(batch))
            return original(self, batch)

        LexiconLabeler.label_batch = counted
        with isolated_registry(("core", builtins), ("lexicon", lexicon_plugin)):
            first = timed(lambda: vdb(["label", str(work), "--quiet"]))
            first_calls, calls[:] = sum(calls), []
            again = timed(lambda: vdb(["label", str(work), "--quiet"]))
            metrics = timed(lambda: vdb(["metrics", str(work), "--json"]))
            report = timed(lambda: vdb(["report", str(work), "--format", "html", "--out", str(work / "r.html")]))
        LexiconLabeler.label_batch = original
        print(f"vdb label: first {first:.2f} s ({first_calls} CoTs labelled), again {again:.2f} s "
              f"({sum(calls)} CoTs labelled); reading the logs alone {reading:.2f} s → relabel/read = "
              f"{again / reading:.2f} (target ≤ 1.5)")
        print(f"vdb metrics: {1000 * metrics / steps:.3f} s per 1,000 steps; vdb report (html, plots): "
              f"{1000 * report / steps:.3f} s per 1,000 steps")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
