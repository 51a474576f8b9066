"""Throughput of the ensemble labeler against a loopback server whose every answer takes ``LATENCY`` s.

Prints ratios: concurrent vs one call at a time, and a rerun on the cache vs the first run. Run it with
``python plugins/vdb-labeler-ensemble/benchmarks/bench_ensemble.py``. Nothing leaves the machine.
Targets: concurrency 8 at least 4x faster than 1; a cached rerun at least 20x faster than the first run.
"""

from __future__ import annotations

import io
import tempfile
import time
from pathlib import Path

from vdb_labeler_ensemble.labeler import EnsembleLabeler
from vdb_labeler_ensemble.testing import ENVIRON, KEYS, LoopbackLLM, Script, answer, backend_specs, item

LATENCY = 0.05
ITEMS = 48


def timed_run(server: LoopbackLLM, cache: Path, concurrency: int, repeats: int = 1) -> float:
    """The best of ``repeats`` timings of one ``label_batch`` of ``ITEMS`` CoTs."""
    labeler = EnsembleLabeler(backend_specs(server), cache=cache, concurrency=concurrency, environ=ENVIRON,
                              progress=False, progress_stream=io.StringIO())
    items = [item(f"b{i}") for i in range(ITEMS)]
    labeler.check()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        results = labeler.label_batch(items)
        best = min(best, time.perf_counter() - start)
        assert all(r.unlabelled is None for r in results)
    labeler.close()
    return best


def main() -> None:
    truth = {f"b{i}": answer() for i in range(ITEMS)}
    server = LoopbackLLM(Script(truth), KEYS, latency=LATENCY).start()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            serial = timed_run(server, Path(tmp) / "serial.sqlite", concurrency=1)
            parallel = timed_run(server, Path(tmp) / "parallel.sqlite", concurrency=8)
            rerun = timed_run(server, Path(tmp) / "parallel.sqlite", concurrency=8, repeats=5)
    finally:
        server.stop()
    calls = 3 * ITEMS
    print(f"{calls} calls, {LATENCY * 1000:.0f} ms each")
    print(f"concurrency 1: {serial:.2f} s, concurrency 8: {parallel:.2f} s, cached rerun (best of 5): {rerun:.3f} s")
    print(f"speedup concurrency 8 / 1: {serial / parallel:.1f}x (target >= 4)")
    print(f"speedup cached rerun / first run: {parallel / rerun:.1f}x (target >= 20)")


if __name__ == "__main__":
    main()
