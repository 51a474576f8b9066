"""``python -m vdb_labeler_ensemble``: the prompt file, how a CoT is shown to the models, and labelling
a JSONL file of CoTs without the ``vdb`` command.

    python -m vdb_labeler_ensemble prompt > my_prompt.toml
    python -m vdb_labeler_ensemble render cots.jsonl --id 3 [--prompt my_prompt.toml]
    python -m vdb_labeler_ensemble label cots.jsonl -o labelled.jsonl --backends SPEC[,SPEC…] [--dry-run]

The JSONL format is the core's (``vladrivebench._analysis.labels.read_jsonl``): one object a line with ``id``,
``text`` and/or ``slots``, and ``context``. Mistakes print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence

from vladrivebench import ConfigError, VdbError

PROG = "python -m vdb_labeler_ensemble"


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except VdbError as exc:
        print(f"{PROG}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted (every reply received so far is in the cache)", file=sys.stderr)
        return 130


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="The ensemble LLM labeler of VLADriveBench.")
    commands = parser.add_subparsers(required=True, metavar="COMMAND")

    prompt = commands.add_parser("prompt", help="print the shipped prompt file (copy it to make your own)")
    prompt.set_defaults(run=_prompt)

    render = commands.add_parser("render", help="print the messages one CoT of a JSONL file is sent as")
    render.add_argument("cots", help="JSONL file of CoTs")
    render.add_argument("--id", help="which CoT (default: the first)")
    render.add_argument("--prompt", default="", help="your prompt file (default: the shipped v1)")
    render.set_defaults(run=_render)

    label = commands.add_parser("label", help="label a JSONL file of CoTs")
    label.add_argument("cots", help="JSONL file of CoTs")
    label.add_argument("-o", "--output", help="where to write the labelled JSONL (required unless --dry-run)")
    label.add_argument("--backends", required=True, help="comma-separated KIND:MODEL[@BASE_URL][?options]")
    label.add_argument("--tie-breaker", default="", help="backend asked only when a vote is split")
    label.add_argument("--cache", default="", help="SQLite cache file (default: user cache dir; 'off': none)")
    label.add_argument("--concurrency", type=int, default=4, help="calls in flight per backend (default 4)")
    label.add_argument("--max-retries", type=int, default=5, help="retries of a failed call (default 5)")
    label.add_argument("--timeout", type=float, default=60.0, help="seconds per call (default 60)")
    label.add_argument("--min-votes", type=int, default=0, help="valid answers needed (default: a majority)")
    label.add_argument("--prompt", default="", help="your prompt file (default: the shipped v1)")
    label.add_argument("--dry-run", action="store_true", help="print the calls a run would make, make none")
    label.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    label.set_defaults(run=_label)
    return parser


def _prompt(args: argparse.Namespace) -> int:
    from .prompt import default_prompt_path

    sys.stdout.write(default_prompt_path().read_text(encoding="utf-8"))
    return 0


def _render(args: argparse.Namespace) -> int:
    from vladrivebench.labels import read_jsonl

    from .prompt import load_prompt

    entries = read_jsonl(args.cots)
    chosen = next((e for e in entries if args.id is None or e.id == args.id), None)
    if chosen is None:
        raise ConfigError(f"{args.cots}: no CoT with id {args.id!r} (ids: {', '.join(e.id for e in entries[:10])}…)")
    system, user = load_prompt(args.prompt or None).render(chosen.item)
    print(f"--- system ---\n{system}\n--- user ---\n{user}", end="")
    return 0


def _label(args: argparse.Namespace) -> int:
    from vladrivebench.labels import read_jsonl, write_jsonl

    from .labeler import build_labeler

    if not args.dry_run and not args.output:
        raise ConfigError("label: give --output FILE for the labelled JSONL (or --dry-run to only count calls)")
    entries = read_jsonl(args.cots)
    labeler = build_labeler(args.backends, args.tie_breaker, args.cache, args.concurrency, args.max_retries,
                            args.timeout, args.prompt, args.min_votes, progress=not args.no_progress)
    with labeler:
        items = [entry.item for entry in entries]
        if args.dry_run:
            _print_plan(labeler.plan(items), len(items))
            return 0
        labeler.check()
        labels = labeler.label_batch(items)
    write_jsonl(args.output, entries, labels)
    unlabelled = sum(1 for label in labels if label.unlabelled)
    print(json.dumps({"labelled": len(labels) - unlabelled, "unlabelled": unlabelled, "output": args.output,
                      "labeler": labeler.name, "version": labeler.version}))
    return 0


def _print_plan(plan: dict[str, dict[str, int]], items: int) -> None:
    print(f"{items} CoTs")
    width = max(len(name) for name in plan)
    for name, counts in plan.items():
        extra = f" (an upper bound: at least {counts['at_least']})" if "at_least" in counts else ""
        print(f"{name:<{width}}  calls {counts['calls']:>6}  cached {counts['cached']:>6}{extra}")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
