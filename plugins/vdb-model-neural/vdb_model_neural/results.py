"""Regenerate the result tables of this plugin's README with ``vdb`` commands (nothing is typed by hand).

    python -m vdb_model_neural.results --out runs/neural [--quick] [--only kv-open-loop,suite] [--batch 16]
                                       [--streams 2]

Each experiment is one ``vdb`` command (printed before it runs); its stdout is pasted verbatim into the
README between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->``. Output directories are resumed,
so an interrupted regeneration redoes only what is missing. Every ``vdb run`` / ``vdb intervene`` runs its
episodes in lockstep batches of ``--batch`` (the same bytes for the same batch size; see the README).
``--streams N`` regenerates N sections side by side (each section's commands in order, one process each:
on a 2-core machine two streams keep both cores busy); the sections' bytes do not depend on it.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

README = Path(__file__).resolve().parent.parent / "README.md"
OL_CONDITIONS = "selfsplice,accel,pedestrian,car"
DRIVING_SCENARIOS = "C.1,C.2,TL.1-red,TL.2-red,TL.3-red,TL.1-green"
"""Do the models stop for the blocking car and the red lights (and not for the car beside the lane or a
green light)?"""
QA_CONDITIONS = "selfsplice,accel,pedestrian,red-light,origbrake,origbrake-shuffle,depicts-all,depicts-50"


def with_batch(commands: list[list[str]], batch: int) -> list[list[str]]:
    """Append ``--batch B`` to the commands that run episodes (``vdb run``, ``vdb intervene``)."""
    return [command + ["--batch", str(batch)] if command[0] in ("run", "intervene") else command
            for command in commands]


def experiments(seeds: dict[str, int]) -> list[tuple[str, list[list[str]]]]:
    """(README section, the vdb commands whose stdout fills it)."""
    ol, cl, safety, suite = seeds["open"], seeds["closed"], seeds["safety"], seeds["suite"]
    return [
        ("kv-open-loop", [
            ["intervene", "--model", "kv", "--controller", "mpc", "--route", "E.1", "--mode", "open-loop",
             "--conditions", OL_CONDITIONS, "--seeds", str(ol), "--batch-conditions", "--out", "{out}/kv-ol-e1"],
            ["intervene", "--model", "kv", "--controller", "mpc", "--route", "E.2", "--mode", "open-loop",
             "--conditions", OL_CONDITIONS, "--seeds", str(ol), "--batch-conditions", "--out", "{out}/kv-ol-e2"],
        ]),
        ("qa-open-loop", [
            ["intervene", "--model", "qa", "--controller", "pid", "--route", "E.1", "--mode", "open-loop",
             "--conditions", QA_CONDITIONS, "--seeds", str(seeds["qa_open"]), "--out", "{out}/qa-ol-e1"],
        ]),
        ("kv-closed-loop", [
            ["intervene", "--model", "kv", "--controller", "mpc", "--route", "E.1", "--mode", "closed-loop",
             "--conditions", OL_CONDITIONS, "--seeds", str(cl), "--out", "{out}/kv-cl-e1"],
        ]),
        ("kv-safety", [
            ["intervene", "--model", "kv", "--controller", "mpc", "--route", route, "--mode", "safety",
             "--seeds", str(safety), "--out", f"{{out}}/kv-safety-{route.split('.')[1]}"]
            for route in ("SAFE.kerb-ped", "SAFE.centre-ped", "SAFE.car")
        ]),
        ("driving", [
            ["run", "--model", model, "--controller", controller, "--scenarios", DRIVING_SCENARIOS,
             "--seeds", str(seeds["driving"]), "--out", f"{{out}}/driving/{model}", "--quiet"]
            for model, controller in (("kv", "mpc"), ("qa", "pid"))
        ]),
        ("suite", [
            ["run", "--model", model, "--controller", controller, "--scenarios", "all", "--seeds", str(suite),
             "--out", f"{{out}}/suite/{model}", "--quiet"]
            for model, controller in (("kv", "mpc"), ("qa", "pid"), ("scripted", "pid"))
        ] + [["label", "{out}/suite"], ["metrics", "{out}/suite"],
             ["report", "{out}/suite", "--format", "md", "--out", "{out}/suite/report.md"]]),
    ]


def training_table() -> str:
    """What the shipped bundles say about how they were trained (from their config JSON files)."""
    from .common import bundle_paths

    lines = ["| model | seed | expert samples | optimiser steps × batch | training wall time | weights file |",
             "|---|---|---|---|---|---|"]
    for name in ("kv", "qa"):
        paths = bundle_paths(name)
        training = json.loads(paths["config"].read_text())["training"]
        size = paths["weights"].stat().st_size / 1e6
        lines.append(f"| `{name}` | {training['seed']} | {training['samples']} | {training['steps']} × "
                     f"{training['batch']} | {training.get('wall_time_s', '?')} s | {size:.1f} MB |")
    return "\n".join(lines)


def run_vdb(args: list[str]) -> str:
    command = [sys.executable, "-m", "vladrivebench", *args]
    print("$ vdb " + " ".join(args), file=sys.stderr, flush=True)
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    print(f"  ({time.perf_counter() - started:.0f} s, exit {done.returncode})", file=sys.stderr, flush=True)
    if done.returncode not in (0, 3):  # 3: completed but the selfsplice gate failed — shown, not hidden
        raise SystemExit(f"vdb {' '.join(args)} failed: {done.stderr.strip().splitlines()[-1:]}")
    return done.stdout.rstrip() + ("\n" + done.stderr.strip().splitlines()[-1] if done.returncode == 3 else "")


def fill(readme: str, name: str, body: str) -> str:
    pattern = re.compile(rf"(<!-- results:{re.escape(name)} -->\n).*?(<!-- /results:{re.escape(name)} -->)", re.S)
    if not pattern.search(readme):
        raise SystemExit(f"{README}: no <!-- results:{name} --> … <!-- /results:{name} --> block")
    return pattern.sub(lambda m: m.group(1) + body + "\n" + m.group(2), readme)


def update_readme(name: str, body: str) -> None:
    """Replace one section, under a lock: several ``--only`` runs may regenerate sections side by side."""
    import fcntl

    with open(README.with_name(".results.lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        README.write_text(fill(README.read_text(), name, body))


def regenerate(name: str, commands: list[list[str]], out: Path, batch: int) -> None:
    """Run one section's commands in order and paste their stdout into the README."""
    outputs = []
    for command in with_batch(commands, batch):
        argv = [a.replace("{out}", str(out)) for a in command]
        text = run_vdb(argv)
        shown = " ".join(a.replace(str(out), "OUT") for a in argv)
        outputs.append(f"$ vdb {shown}\n{text.replace(str(out), 'OUT')}")
    update_readme(name, "```text\n" + "\n\n".join(outputs) + "\n```")
    print(f"README section {name} updated", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--only", help="Comma-separated sections to regenerate (default: all).")
    parser.add_argument("--quick", action="store_true", help="Fewer seeds (a smoke run; tables are noisier).")
    parser.add_argument("--batch", type=int, default=16,
                        help="Episodes advanced in lockstep per model call (default 16; 1 = unbatched).")
    parser.add_argument("--streams", type=int, default=2,
                        help="Sections regenerated side by side (default 2, one per core of the reference machine).")
    args = parser.parse_args()
    if args.batch < 1:
        parser.error(f"--batch must be a positive integer, got {args.batch}")
    if args.streams < 1:
        parser.error(f"--streams must be a positive integer, got {args.streams}")
    seeds = ({"open": 3, "qa_open": 2, "closed": 3, "safety": 2, "driving": 2, "suite": 1} if args.quick
             else {"open": 7, "qa_open": 3, "closed": 5, "safety": 4, "driving": 5, "suite": 1})
    only = set(args.only.split(",")) if args.only else None
    started = time.perf_counter()
    if not only or "training" in only:
        update_readme("training", training_table())
    sections = [(name, commands) for name, commands in experiments(seeds) if not only or name in only]
    with ThreadPoolExecutor(max_workers=args.streams) as pool:
        for future in [pool.submit(regenerate, name, commands, args.out, args.batch) for name, commands in sections]:
            future.result()
    print(f"all sections: {time.perf_counter() - started:.0f} s wall time", file=sys.stderr)


if __name__ == "__main__":
    main()
