"""Run ``vdb`` on bad input and classify how it ended.

Every refused input must end in *one line*: exit status 2, exactly one stderr line starting ``vdb: error:``,
no traceback, and every file that existed before byte-identical afterwards (nothing new left behind either).
The other outcomes are named after what a user sees:

- ``traceback``: an exception escaped (in-process) or a traceback was printed;
- ``wrong status``: no traceback, but not exit 2 with exactly one ``vdb: error:`` line;
- ``silent``: exit 0, the input was accepted;
- ``lost``: a file that existed before was changed or removed, or the refused command left new files.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import subprocess
import sys
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

OUTCOMES = ("one line", "traceback", "wrong status", "silent", "lost")


@dataclass
class Ended:
    """How one ``vdb`` call ended."""

    status: int | None
    stdout: str
    stderr: str
    escaped: BaseException | None = None

    @property
    def error_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


@dataclass
class Case:
    """One bad input: the arguments (after ``vdb``), extra environment and import paths, expected status."""

    name: str
    args: list[str]
    env: Mapping[str, str] = field(default_factory=dict)
    sys_path: tuple[str, ...] = ()
    status: int = 2
    mentions: tuple[str, ...] = ()  # words the error line must contain (what, where)


def snapshot(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (and ``dir`` for every directory), by relative path."""
    state: dict[str, str] = {}
    for path in sorted(root.rglob("*")):
        rel = str(path.relative_to(root))
        if path.is_symlink() and not path.exists():
            state[rel] = "dangling link"
        elif path.is_dir():
            state[rel] = "dir"
        else:
            try:
                state[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError as exc:
                state[rel] = f"unreadable {exc.errno}"
    return state


@contextlib.contextmanager
def _environment(env: Mapping[str, str], sys_path: tuple[str, ...]) -> Iterator[None]:
    saved_env = {key: os.environ.get(key) for key in env}
    saved_path = list(sys.path)
    os.environ.update(env)
    sys.path[:0] = list(sys_path)
    import importlib

    importlib.invalidate_caches()
    from vladrivebench._engine.registry import set_registry

    previous = set_registry(None)  # a fresh registry sees the environment and the extra plugins
    try:
        yield
    finally:
        set_registry(previous)
        sys.path[:] = saved_path
        for key, value in saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        _forget_plugin_commands()


def _forget_plugin_commands() -> None:
    from vladrivebench._cli import main as cli_main

    cli_main.VdbGroup._plugins_added = False
    cli_main.cli._plugins_added = False


def run_in_process(case: Case) -> Ended:
    """``vdb ARGS`` in this process (``vladrivebench.testing.run_cli``), stdout and stderr captured."""
    from vladrivebench.testing import run_cli

    out, err = io.StringIO(), io.StringIO()
    with _environment(case.env, case.sys_path), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = run_cli(case.args)
        except BaseException as exc:  # noqa: BLE001 - the harness reports what escaped, whatever it is
            return Ended(None, out.getvalue(), err.getvalue(), exc)
    return Ended(status, out.getvalue(), err.getvalue())


def run_subprocess(case: Case, cwd: Path) -> Ended:
    """``python -m vladrivebench ARGS`` in a new process."""
    env = {**os.environ, **case.env}
    if case.sys_path:
        env["PYTHONPATH"] = os.pathsep.join([*case.sys_path, env.get("PYTHONPATH", "")])
    done = subprocess.run([sys.executable, "-m", "vladrivebench", *case.args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=120, stdin=subprocess.DEVNULL)
    return Ended(done.returncode, done.stdout, done.stderr)


def classify(case: Case, ended: Ended, before: Mapping[str, str], after: Mapping[str, str]) -> str:
    """One of :data:`OUTCOMES`."""
    changed = [p for p, digest in before.items() if after.get(p) != digest]
    created = [p for p in after if p not in before]
    if ended.escaped is not None or "Traceback (most recent call last)" in ended.stderr + ended.stdout:
        return "traceback"
    if changed or (created and case.status != 0):
        return "lost"
    if case.status != 0 and ended.status == 0:
        return "silent"
    lines = ended.error_lines
    if ended.status != case.status:
        return "wrong status"
    if case.status == 2 and (len(lines) != 1 or not lines[0].startswith("vdb: error: ")):
        return "wrong status"
    if case.status == 2 and not all(word.lower() in lines[0].lower() for word in case.mentions):
        return "wrong status"
    return "one line"


def explain(case: Case, ended: Ended, before: Mapping[str, str], after: Mapping[str, str]) -> str:
    """What went wrong, for an assertion message."""
    changed = sorted(p for p, digest in before.items() if after.get(p) != digest)
    created = sorted(p for p in after if p not in before)
    return (f"{case.name}: vdb {' '.join(case.args)} -> status {ended.status}, escaped {ended.escaped!r}\n"
            f"stderr: {ended.stderr[-2000:]}\nstdout: {ended.stdout[-500:]}\n"
            f"changed: {changed[:10]} created: {created[:10]}")
