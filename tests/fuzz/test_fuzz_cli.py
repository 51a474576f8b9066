"""Table-driven bad inputs over every CLI surface: exit 2, one ``vdb: error:`` line, no traceback, nothing
already written changed (every file under the case's directory hashed before and after).

``python tests/fuzz/test_fuzz_cli.py`` prints how every case ended, per surface (the figures of issue 17).
"""

from __future__ import annotations

import os
import shutil
import sys
from collections import Counter
from pathlib import Path

import pytest
from cases import CASES  # noqa: E402
from harness import OUTCOMES, classify, explain, run_in_process, run_subprocess, snapshot  # noqa: E402

_TEMPLATE: dict[str, Path] = {}


def complete_run(base: Path) -> Path:
    """A complete one-episode run (scripted on P.1, labelled with the default labeler), made once."""
    if "run" not in _TEMPLATE:
        from vladrivebench.testing import run_cli

        template = base / "template-run"
        assert run_cli(["run", "--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--quiet",
                        "--sim-opt", "render=false", "--out", str(template)]) == 0
        assert run_cli(["label", str(template), "--quiet"]) == 0
        _TEMPLATE["run"] = template
    return _TEMPLATE["run"]


def prepare(name: str, tmp: Path, base: Path):
    shutil.copytree(complete_run(base), tmp / "run")
    case = CASES[name](tmp, tmp / "run")
    case.name = name
    return case


def check(case, ended, before, after) -> None:
    assert classify(case, ended, before, after) == "one line", explain(case, ended, before, after)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-template")


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_is_one_line(name, tmp_path, base):
    case = prepare(name, tmp_path, base)
    before = snapshot(tmp_path)
    ended = run_in_process(case)
    check(case, ended, before, snapshot(tmp_path))


SUBPROCESS_CASES = ["plugins: plugin_exits_at_import_strict", "config: config_not_utf8",
                    "paths: report_out_is_episode_log"]


@pytest.mark.parametrize("name", SUBPROCESS_CASES)
def test_bad_input_is_one_line_in_a_new_process(name, tmp_path, base):
    case = prepare(name, tmp_path, base)
    before = snapshot(tmp_path)
    ended = run_subprocess(case, tmp_path)
    check(case, ended, before, snapshot(tmp_path))


def tally(root: Path) -> dict[str, Counter]:
    """How every case ended, by surface."""
    base = root / "template"
    base.mkdir()
    by_surface: dict[str, Counter] = {}
    skip = [s for s in os.environ.get("FUZZ_SKIP", "").split(",") if s]  # e.g. a case that hangs on old code
    for index, name in enumerate(sorted(CASES)):
        if any(s in name for s in skip):
            by_surface.setdefault(name.split(":")[0], Counter())["hang"] += 1
            print(f"  {'hang':12} {name}: skipped (FUZZ_SKIP)", file=sys.stderr)
            continue
        tmp = root / f"case{index}"
        tmp.mkdir()
        case = prepare(name, tmp, base)
        before = snapshot(tmp)
        ended = run_in_process(case)
        outcome = classify(case, ended, before, snapshot(tmp))
        by_surface.setdefault(name.split(":")[0], Counter())[outcome] += 1
        if outcome != "one line":
            last = (ended.error_lines or [repr(ended.escaped)])[-1][:150]
            print(f"  {outcome:12} {name}: {last}", file=sys.stderr)
    return by_surface


if __name__ == "__main__":  # pragma: no cover - the figures for the report
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        result = tally(Path(scratch))
    total = Counter()
    columns = (*OUTCOMES, "hang")
    print(f"{'surface':12}" + "".join(f"{o:>14}" for o in columns))
    for surface, counts in sorted(result.items()):
        total.update(counts)
        print(f"{surface:12}" + "".join(f"{counts[o]:>14}" for o in columns))
    print(f"{'all':12}" + "".join(f"{total[o]:>14}" for o in columns))
