"""Output files of ``vdb report`` and ``vdb label --texts``: never an input, a log or a run's own file.

Every check runs before the command computes or writes anything and fails with one line naming the flag,
the path and what is expected.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from vladrivebench.errors import ConfigError

RUN_MANIFEST = "run.json"
RUN_OWNED_DIRS = ("episodes", "labels")
RUN_OWNED_FILES = ("run.json", "failures.json", "intervention.json")
LOG_SUFFIXES = (".mcap", ".partial")


def check_output_file(out: Path, flag: str, inputs: Iterable[Path] = (), runs: Iterable[Path] = ()) -> None:
    """Refuse an output file that would replace an input, an episode log, or a file a run directory owns
    (its manifest, failures, episodes/ and labels/), or that cannot be written where it is."""
    for given in inputs:
        if _same_file(out, given):
            raise ConfigError(f"{flag} {out}: is the input {given}; write the output to another file")
    if out.suffix.lower() in LOG_SUFFIXES:
        raise ConfigError(f"{flag} {out}: an episode log's name ({out.suffix}); expected a new output file")
    if out.is_dir():
        raise ConfigError(f"{flag} {out}: is a directory; expected a file name")
    run = _enclosing_run(out, runs)
    if run is not None:
        inside = out.resolve().relative_to(run.resolve())
        if inside.parts[0] in RUN_OWNED_DIRS or str(inside) in RUN_OWNED_FILES:
            raise ConfigError(f"{flag} {out}: inside the run directory {run}, which this command does not own "
                              f"({inside.parts[0]}); expected a file outside episodes/ and labels/")
    _check_parent(out, flag)


def _check_parent(out: Path, flag: str) -> None:
    parent = out.parent if str(out.parent) else Path(".")
    for ancestor in [parent, *parent.parents]:
        if ancestor.exists() and not ancestor.is_dir():
            raise ConfigError(f"{flag} {out}: {ancestor} is a file, not a folder")
    if not parent.is_dir():
        raise ConfigError(f"{flag} {out}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (out.exists() and not os.access(out, os.W_OK)):
        raise ConfigError(f"{flag} {out}: cannot write there (read-only)")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _enclosing_run(path: Path, runs: Iterable[Path]) -> Path | None:
    """The run directory (holding ``run.json``, or one of ``runs``) that ``path`` lies in, if any."""
    try:
        resolved = path.resolve()
        known = {Path(r).resolve() for r in runs}
    except OSError:
        return None
    for ancestor in resolved.parents:
        if ancestor in known or (ancestor / RUN_MANIFEST).is_file():
            return ancestor
    return None
