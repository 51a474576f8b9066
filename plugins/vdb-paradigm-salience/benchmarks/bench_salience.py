"""Cost of one salience cell, and what the paradigm adds to the plain episodes it is made of.

    python plugins/vdb-paradigm-salience/benchmarks/bench_salience.py [--model scripted] [--controller pid]
                                                                      [--seeds 2] [--route SAFE.kerb-ped]

One run of ``vdb intervene --mode salience`` on a small grid (pedestrian and car at offset 0, onset 25 and
50 m: 4 cells), in this process. Printed, all measured in this one run:

- episodes per cell (2 × seeds: a baseline and an injected episode per seed) and CPU seconds per cell
  (the whole intervene command — checks, preflight, episodes, MCAP logging, analysis — divided by the cells);
- the same cells' baseline and injected episodes re-driven as *plain* episodes (the model's own CoT, no
  paradigm, no log), and the ratio paradigm / plain: what onset detection, the salience renders at onset,
  the gate check, the injection's splicing, logging and analysis cost on top of simulating and running the
  model.

``vdb intervene`` runs a salience sweep's episodes one after another in one process (it has no executor
option); the cost per cell is therefore the figure that scales the sweep: cells × seeds × 2 episodes.
Times are CPU seconds of this process (``time.process_time``), so a loaded machine changes them less than
wall time.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

GRID = ["kinds=pedestrian,car", "offsets=0", "distances=25,50", "sizes=1"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="scripted")
    parser.add_argument("--controller", default="pid")
    parser.add_argument("--route", default="SAFE.kerb-ped")
    parser.add_argument("--seeds", type=int, default=2)
    args = parser.parse_args()
    from vdb_paradigm_salience.grid import check_grid, grid_options
    from vladrivebench.testing import run_cli
    from vladrivebench.world import load_suite

    options = dict(item.split("=", 1) for item in GRID)
    routes = check_grid(grid_options(**options), [load_suite()[args.route]])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        command = ["intervene", "--model", args.model, "--controller", args.controller, "--route", args.route,
                   "--mode", "salience", "--seeds", str(args.seeds), "--quiet", "--out", str(out)]
        for item in GRID:
            command += ["--paradigm-opt", item]
        start = time.process_time()
        with contextlib.redirect_stdout(io.StringIO()):  # the result tables are not what is measured
            code = run_cli(command)
        paradigm_s = time.process_time() - start
        if code != 0:
            raise SystemExit(f"vdb intervene failed with status {code}")
        from vladrivebench.testing import find_episodes, read_episode

        steps = {p.stem: len(read_episode(p).steps) for p in find_episodes(out)}
    plain_s = plain_episodes(args, routes, steps)
    cells, per_cell = len(routes), 2 * args.seeds
    print(f"salience sweep, model {args.model} / {args.controller}, base route {args.route}, {cells} cells × "
          f"{args.seeds} seeds")
    print(f"  episodes per cell:             {per_cell}")
    print(f"  CPU s per cell (vdb intervene): {paradigm_s / cells:.2f}  ({paradigm_s / (cells * per_cell):.2f} s "
          f"per episode, {sum(steps.values()) / (cells * per_cell):.0f} steps per episode)")
    print(f"  CPU s per cell (plain episodes): {plain_s / cells:.2f}")
    print(f"  ratio paradigm / plain:        {paradigm_s / plain_s:.2f}")


def plain_episodes(args: argparse.Namespace, routes: list, steps: dict[str, int]) -> float:
    """CPU seconds to drive each logged episode's route for as many steps with the own CoT, no log."""
    from vladrivebench.episodes import run_episode
    from vladrivebench.testing import build

    model, sim = build("model", args.model), build("simulator", "kinematic")
    controller = build("controller", args.controller)
    total = 0.0
    for route in routes:
        for seed in range(args.seeds):
            for name in ("baseline", "accel"):
                count = next(n for stem, n in steps.items() if f"__{route.id}__s{seed}__{name}" in stem)
                start = time.process_time()
                run_episode(model, sim, controller, route, seed, max_steps=count)
                total += time.process_time() - start
    return total


if __name__ == "__main__":
    main()
