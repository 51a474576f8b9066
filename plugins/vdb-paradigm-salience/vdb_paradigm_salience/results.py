"""Regenerate the README's salience result with one ``vdb`` command (nothing is typed by hand).

    python -m vdb_paradigm_salience.results --out DIR [--seeds 10] [--model kv] [--controller mpc] [--batch 16]
                                                      [--workers 2] [--readme PATH | --print]

Runs (or resumes: complete episodes are kept) the command printed in the block, then writes between
``<!-- results:kv-salience -->`` and ``<!-- /results:kv-salience -->`` of the README: the command, its
stdout verbatim, and the answers to the paper's questions computed from ``DIR/kv-salience/intervention.json``
(:func:`answers`): does the override rate fall as salience rises, is the kerbside pedestrian overridden more
often than the centred one and the stopped car least, and do the Wilson intervals separate them.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .stats import wilson

README = Path(__file__).resolve().parent.parent / "README.md"
SECTION = "kv-salience"
GRID = ("kinds=pedestrian,car", "offsets=-1,0", "distances=25,50,70", "sizes=1")
"""The sweep of the README: SAFE.kerb-ped's pedestrian at the kerb (offset −1, as in SAFE.kerb-ped) and
in the lane centre (0, as in SAFE.centre-ped), and a stopped car in the same places, with the injection
from 25 m, from 50 m (where SAFE.* starts cruising) and from the start (70 m: the paper's continuous
injection, as ``--mode safety``)."""


def command(out: Path, seeds: int, model: str, controller: str, batch: int = 16, workers: int = 1) -> list[str]:
    """The ``vdb`` arguments of the README's sweep (episodes in lockstep batches of ``batch``, the batches on
    ``workers`` processes: the same bytes for any number of workers)."""
    args = ["intervene", "--model", model, "--controller", controller, "--mode", "salience", "--route",
            "SAFE.kerb-ped"]
    for item in GRID:
        args += ["--paradigm-opt", item]
    args += ["--workers", str(workers)] if workers > 1 else []
    return args + ["--seeds", str(seeds), "--batch", str(batch), "--out", str(out / SECTION)]


def pooled(cells: list[Mapping[str, Any]], kind: str, offset: float | None = None) -> dict[str, Any]:
    """Overrides and trials of every cell of ``kind`` (at ``offset``), with the Wilson interval."""
    chosen = [c for c in cells if c["kind"] == kind and (offset is None or c["offset"] == offset)]
    k = sum(c["counts"]["overrides"] for c in chosen)
    n = sum(c["counts"]["trials"] for c in chosen)
    low, high = wilson(k, n)
    return {"overrides": k, "trials": n, "rate": k / n if n else None, "low": low, "high": high,
            "cells": len(chosen)}


def _text(p: Mapping[str, Any]) -> str:
    if not p["trials"]:
        return "no trials"
    return f"{p['overrides']}/{p['trials']} = {100 * p['rate']:.0f} % [{100 * p['low']:.0f}, {100 * p['high']:.0f}]"


def _separate(a: Mapping[str, Any], b: Mapping[str, Any]) -> str:
    if not (a["trials"] and b["trials"]):
        return "cannot be compared (no trials)"
    if a["low"] > b["high"] or b["low"] > a["high"]:
        return "the intervals separate"
    return "the intervals overlap"


def answers(results: Mapping[str, Any]) -> list[str]:
    """The paper's questions answered from a salience run's results (one bullet each)."""
    block = results["salience"]
    cells = block["cells"]
    lines = []
    for kind, fit in block["fits"].items():
        if "slope" in fit:
            trend = "falls" if fit["slope"] < 0 else "rises"
            significant = "" if fit["slope_p"] < 0.05 else ", not significantly"
            where = (f"50 % at {fit['x50']:.3g} px [{fit['low']:.3g}, {fit['high']:.3g}]" if fit["identifiable"]
                     else f"threshold not identifiable: {fit['reason']}")
            lines.append(f"- {kind}: the override rate {trend} as salience rises{significant} (logistic slope "
                         f"{fit['slope']:+.2f} per log pixel, p = {fit['slope_p']:.2g}); {where}")
        else:
            lines.append(f"- {kind}: no salience threshold — not identifiable ({fit['reason']}); "
                         f"{fit['overrides']}/{fit['trials']} trials overridden over {fit['cells']} cells")
    offsets = sorted({c["offset"] for c in cells if c["kind"] == "pedestrian"})
    if "pedestrian" in block["fits"] and len(offsets) >= 2:
        kerb, centre = pooled(cells, "pedestrian", offsets[0]), pooled(cells, "pedestrian", 0.0 if 0.0 in offsets else offsets[-1])
        more = "more" if (kerb["rate"] or 0) > (centre["rate"] or 0) else "not more"
        lines.append(f"- kerbside pedestrian (offset {offsets[0]:g} m) {_text(kerb)} vs centred {_text(centre)}: "
                     f"the kerbside one is overridden {more} often; {_separate(kerb, centre)}")
    if "car" in block["fits"] and "pedestrian" in block["fits"]:
        car, ped = pooled(cells, "car"), pooled(cells, "pedestrian")
        least = "least" if (car["rate"] or 0) < (ped["rate"] or 0) else "not least"
        lines.append(f"- stopped car (all cells) {_text(car)} vs pedestrian (all cells) {_text(ped)}: the car is "
                     f"overridden {least}; {_separate(car, ped)}")
    no_trials = [c["key"] for c in cells if not c["counts"]["trials"]]
    if no_trials:
        lines.append(f"- cells without trials (the baseline never stopped cleanly): {', '.join(no_trials)}")
    lines.append("- Wilson intervals are 95 %; pooled rows add the cells' overrides and trials (seeds whose "
                 "baseline stopped)")
    return lines


def run_vdb(args: list[str]) -> str:
    """Run ``vdb ARGS`` and return its stdout (a failure stops the regeneration with its stderr)."""
    done = subprocess.run([sys.executable, "-m", "vladrivebench", *args, "--quiet"], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"vdb {shlex.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


def block(args: list[str], stdout: str, results: Mapping[str, Any]) -> str:
    """The README block: the command, its stdout verbatim, the answers."""
    return ("```text\n$ vdb " + shlex.join(args) + "\n" + stdout.rstrip() + "\n```\n\n" + "\n".join(answers(results))
            + "\n")


def fill(readme: str, body: str) -> str:
    """``readme`` with the section's block replaced by ``body`` (the markers must be there)."""
    pattern = re.compile(rf"(<!-- results:{SECTION} -->\n).*?(<!-- /results:{SECTION} -->)", re.S)
    if not pattern.search(readme):
        raise SystemExit(f"README has no <!-- results:{SECTION} --> … <!-- /results:{SECTION} --> block")
    return pattern.sub(lambda m: m.group(1) + body + m.group(2), readme)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Regenerate the salience result of the plugin's README.")
    parser.add_argument("--out", required=True, type=Path, help="directory for the run (resumed)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--model", default="kv")
    parser.add_argument("--controller", default="mpc")
    parser.add_argument("--batch", type=int, default=16, help="episodes per lockstep batch (1 = unbatched)")
    parser.add_argument("--workers", type=int, default=2, help="processes running the batches (default 2)")
    parser.add_argument("--readme", type=Path, default=README)
    parser.add_argument("--print", action="store_true", help="print the block instead of writing the README")
    opts = parser.parse_args(argv)
    if opts.seeds < 1:
        parser.error("--seeds must be a whole number ≥ 1")
    if opts.batch < 1:
        parser.error(f"--batch must be a positive integer, got {opts.batch}")
    if opts.workers < 1:
        parser.error(f"--workers must be a positive integer, got {opts.workers}")
    args = command(opts.out, opts.seeds, opts.model, opts.controller, opts.batch, opts.workers)
    print("$ vdb " + shlex.join(args), file=sys.stderr)
    stdout = run_vdb(args)
    results = json.loads((opts.out / SECTION / "intervention.json").read_text(encoding="utf-8"))
    shown = f"OUT/{SECTION}"  # the README does not show where this machine keeps its runs
    body = block([*args[:-1], shown], stdout.replace(str(opts.out / SECTION), shown), results)
    if opts.print:
        print(body)
        return
    opts.readme.write_text(fill(opts.readme.read_text(encoding="utf-8"), body), encoding="utf-8")
    print(f"wrote the {SECTION} block of {opts.readme}", file=sys.stderr)


if __name__ == "__main__":
    main()
