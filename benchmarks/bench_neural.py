"""Neural reference models on CPU: splice cost, step cost and shared-prefix batching, printed as ratios.

    python benchmarks/bench_neural.py [--repeats 5]

1. Sequential vs prefill splice of CoTs of 3 … 150 tokens (``kv``'s decoder, one shared vision prefix):
   the price of bit-identity.
2. A closed-loop model step (generate the CoT + decode the action) of ``kv`` and ``qa``.
3. K spliced conditions decoded in one batch over the shared prefix (``decode_batch``) vs one by one
   (``splice_cot`` + ``decode_action`` each): the cost of each extra condition relative to a baseline
   step — the target is at most 15 %.

Times are medians of ``--repeats`` runs on one thread (the models' default); the machine may be shared,
so read the ratios rather than the absolute numbers.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def observation():
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import load_suite

    registry = get_registry()
    simulator = registry.create("simulator", "kinematic")
    scenario = load_suite(registry)["E.1"]
    obs = simulator.reset(scenario, 0)
    simulator.close()
    return obs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    from vdb_adapter_transformers import toolkit
    from vladrivebench._engine.registry import get_registry

    registry = get_registry()
    kv = registry.create("model", "kv")
    qa = registry.create("model", "qa")
    obs = observation()
    rng = np.random.default_rng(0)
    ids = kv.codec.ids
    lm = kv.network.lm
    word = kv.codec.encode(" lane")[0]

    print("1. splice cost, kv decoder (ms): tokens, sequential, prefill, ratio")
    for n in (3, 10, 30, 60, 100, 150):
        tokens = [word] * n

        def splice(mode, tokens=tokens):
            toolkit.splice_tokens(lm, kv.prefix_state(obs), tokens, ids["<cot>"], ids["</cot>"], mode=mode)

        seq = median_time(lambda: splice("sequential"), args.repeats)
        pre = median_time(lambda: splice("prefill"), args.repeats)
        print(f"   {n:4d}  {seq * 1e3:8.1f}  {pre * 1e3:7.1f}  {seq / pre:6.1f}x")

    print("2. closed-loop step on CPU (ms): model, generate_cot, decode_action, total, CoT tokens")
    for name, model in (("kv", kv), ("qa", qa)):
        model.reset(0)
        cot = model.generate_cot(obs, rng)
        gen = median_time(lambda model=model: model.generate_cot(obs, rng), args.repeats)
        dec = median_time(lambda model=model, cot=cot: model.decode_action(obs, cot, np.random.default_rng(1)),
                          args.repeats)
        n_tokens = sum(len(v) for v in cot.state.token_ids.values()) if name == "qa" else len(cot.state.token_ids)
        print(f"   {name}  {gen * 1e3:8.1f}  {dec * 1e3:8.1f}  {(gen + dec) * 1e3:8.1f}  {n_tokens}")

    print("3. K conditions over the shared prefix, kv (ms): K, batched, one by one, extra condition / baseline step")
    texts = [
        "Accelerate to maintain speed since the road ahead is clear and no obstacles are present.",
        "Stop for the pedestrian in the lane because it is blocking the lane.",
        "Stop for the stationary car in the lane because it is blocking the lane.",
        "Stop for the red traffic light ahead because it requires the vehicle to stop.",
        "Slow down and stop because an animal is standing in the lane ahead.",
        "Maintain speed and keep the lane since the road ahead is clear.",
        "Decelerate to a stop since the car ahead is stopped in the lane.",
        "Keep the current speed because no obstacles are present in the lane.",
    ]
    baseline = median_time(lambda: kv.decode_action(obs, kv.generate_cot(obs, rng), np.random.default_rng(1)),
                           args.repeats)
    one = median_time(lambda: kv.decode_batch(obs, texts[:1], np.random.default_rng(1)), args.repeats)
    for k in (2, 4, 8):
        batched = median_time(lambda k=k: kv.decode_batch(obs, texts[:k], np.random.default_rng(1)), args.repeats)

        def one_by_one(k=k):
            for text in texts[:k]:
                kv.decode_action(obs, kv.splice_cot(obs, text, rng), np.random.default_rng(1))

        single = median_time(one_by_one, args.repeats)
        extra = (batched - one) / (k - 1)
        print(f"   {k}  {batched * 1e3:8.1f}  {single * 1e3:8.1f}  {extra / baseline:6.1%}"
              f"  (baseline step {baseline * 1e3:.1f} ms; target <= 15%)")


if __name__ == "__main__":
    main()
