"""The tiny Alpamayo-architecture model's step on CPU, split into its parts, printed as ratios.

    python plugins/vdb-model-alpamayo/benchmarks/bench_alpamayo.py [--repeats 5] [--frames 1] [--cot 24]
        [--batch-sizes 1,4,16]

Parts of one step (medians of ``--repeats`` runs, one thread): the prompt prefix (Qwen3-VL's vision tower
and one pass over the prompt), generating the CoT, splicing the same CoT sequentially (one pass per token,
bit-identical) and in prefill (one pass), the action expert (10 Euler steps of flow matching over 64 action
tokens), and the fidelity check (Qwen3-VL's own forward pass over prefix + CoT and a second expert run),
which the intervention gate runs at every gated step. A *step* is what a plain episode pays: prefix +
generate + expert. Then lockstep batches: a step of B episodes (``generate_cot_batch`` +
``decode_action_batch`` on B different observations) against B unbatched steps, per episode-step, with the
selfsplice of the batch's own CoTs checked bit for bit. The machine may be shared: read the ratios, not the
absolute times.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from vladrivebench.testing import synthetic_observation


def median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=1)
    parser.add_argument("--cot", type=int, default=24, help="CoT tokens to generate and splice")
    parser.add_argument("--batch-sizes", default="1,4,16", help="lockstep batch sizes to time")
    args = parser.parse_args()

    from vdb_model_alpamayo.plugin import make_alpamayo

    model = make_alpamayo(frames=args.frames, max_cot_tokens=args.cot)
    model.banned = [*model.banned, model.end_id]  # always write --cot tokens, so every part sees the same text
    obs = synthetic_observation(height=80, width=160)  # the conformance kit's deterministic frame
    rng = lambda: np.random.default_rng(1)  # noqa: E731

    def prefix():
        model.reset(0)
        model.prefix_state(obs)

    own = model.generate_cot(obs, rng())
    text = own.text
    times = {
        "prefix (vision + prompt)": median_time(prefix, args.repeats),
        "generate CoT": median_time(lambda: model.generate_cot(obs, rng()), args.repeats),
        "splice, sequential": median_time(lambda: model.splice_cot(obs, text, rng()), args.repeats),
        "expert (10 Euler steps)": median_time(lambda: model.decode_action(obs, own, rng()), args.repeats),
        "fidelity check": median_time(lambda: model.fidelity_check(obs, own, rng()), args.repeats),
    }
    model.splice_mode = "prefill"
    times["splice, prefill"] = median_time(lambda: model.splice_cot(obs, text, rng()), args.repeats)
    step = times["prefix (vision + prompt)"] + times["generate CoT"] + times["expert (10 Euler steps)"]
    tokens = len(own.state.decoder.tokens) - 3
    print(f"tiny Alpamayo on CPU: {len(model.cameras)} cameras × {args.frames} frames at "
          f"{model.resolution[0]}x{model.resolution[1]}, prefix {own.state.decoder.length - tokens - 3} positions, "
          f"CoT {tokens} tokens, {args.repeats} repeats")
    print(f"{'part':28s} {'ms':>9s} {'of a step':>10s}")
    for name, seconds in times.items():
        print(f"{name:28s} {1000 * seconds:9.1f} {seconds / step:9.1%}")
    print(f"step = prefix + generate + expert: {1000 * step:.1f} ms")
    print(f"sequential / prefill splice: {times['splice, sequential'] / times['splice, prefill']:.2f}x")
    print(f"fidelity check / step: {times['fidelity check'] / step:.2f} (it runs at every gated step)")
    batches(model, [int(b) for b in args.batch_sizes.split(",")], args.repeats)


def batches(model, sizes: list[int], repeats: int) -> None:
    """Model time per episode-step of a lockstep step of B episodes, against B unbatched steps."""
    print(f"{'B':>4s} {'unbatched ms/ep':>16s} {'batched ms/ep':>14s} {'speed-up':>9s} {'selfsplice':>11s}")
    for size in sizes:
        alone, together, exact = time_batch(model, size, repeats)
        print(f"{size:4d} {1000 * alone / size:16.1f} {1000 * together / size:14.1f} {alone / together:8.2f}x "
              f"{'bit-exact' if exact else 'DIFFERS':>11s}")


def time_batch(model, size: int, repeats: int) -> tuple[float, float, bool]:
    """(B unbatched steps s, one batched step s, selfsplice of the batch's own CoTs bit-exact)."""
    observations = [synthetic_observation(height=80, width=160, seed=i) for i in range(size)]
    rngs = [np.random.default_rng(i) for i in range(size)]

    def unbatched():
        for obs, rng in zip(observations, rngs, strict=True):
            model.reset(0)
            model.decode_action(obs, model.generate_cot(obs, rng), rng)

    def batched():
        model._batch_key = None  # time the prefill, not the memo
        model.decode_action_batch(observations, model.generate_cot_batch(observations, rngs), rngs)

    alone, together = median_time(unbatched, repeats), median_time(batched, repeats)
    own = model.generate_cot_batch(observations, rngs)
    spliced = model.splice_cot_batch(observations, [c.text for c in own], rngs)
    exact = all(model.state_digest(a) == model.state_digest(b) for a, b in zip(own, spliced, strict=True))
    return alone, together, exact


if __name__ == "__main__":
    main()
