"""The one libsumo simulation of this process.

libsumo runs SUMO inside the Python process and holds exactly one simulation per process. A
:class:`SumoSession` owns it: the first episode starts it (``libsumo.start``), later episodes reload it in
place (``libsumo.load``: a new network, routes and seed, a few milliseconds), ``close`` ends it. Creating a
second session while one is open in the same process raises :class:`SumoBusyError`; parallel episodes
run in separate processes (the ``process`` executor builds one simulator per worker process).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import threading
import weakref
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from vladrivebench import VdbError

from .network import sumo_environment

INSTALL_HINT = "pip install eclipse-sumo libsumo"


class SumoBusyError(VdbError):
    """A second SUMO simulation was asked for in a process that already runs one."""


class SumoUnavailableError(VdbError):
    """SUMO (libsumo, netconvert) is not installed or cannot start."""


_lock = threading.Lock()
_owner: weakref.ref | None = None
_running = False
"""Whether libsumo holds a simulation in this process (possibly left by an owner that was never closed)."""


def import_libsumo() -> Any:
    """The ``libsumo`` module, or a one-line error naming the packages to install."""
    os.environ.update({k: v for k, v in sumo_environment().items() if k == "SUMO_HOME"})
    try:
        import libsumo
    except ImportError as exc:
        raise SumoUnavailableError(
            f"simulator 'sumo' needs SUMO's libsumo, which is not installed ({exc}); install it with: "
            f"{INSTALL_HINT}"
        ) from None
    return libsumo


def netconvert_binary() -> str:
    """The path of SUMO's ``netconvert``: under ``$SUMO_HOME``, in the ``eclipse-sumo`` package, or on the
    ``PATH`` (libsumo may point ``SUMO_HOME`` at its data-only package, which has no programs)."""
    homes = [os.environ.get("SUMO_HOME"), eclipse_sumo_home()]
    candidates = [Path(home) / "bin" / name for home in homes if home for name in ("netconvert", "netconvert.exe")]
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    found = shutil.which("netconvert")
    if found:
        return found
    raise SumoUnavailableError(
        f"simulator 'sumo' needs SUMO's netconvert, which was not found (SUMO_HOME="
        f"{os.environ.get('SUMO_HOME') or 'unset'}, nor on PATH); install it with: {INSTALL_HINT}"
    )


def eclipse_sumo_home() -> str | None:
    """The SUMO installation inside the ``eclipse-sumo`` wheel (the ``sumo`` package), if installed."""
    try:
        import sumo
    except ImportError:
        return None
    return getattr(sumo, "SUMO_HOME", None)


def sumo_version(libsumo: Any) -> str:
    """SUMO's version string (e.g. ``1.28.0``)."""
    version = getattr(libsumo, "__version__", None)
    if version:
        return str(version)
    try:
        from importlib.metadata import version as dist_version

        return dist_version("libsumo")
    except Exception:
        return "unknown"


class SumoSession:
    """This process's libsumo simulation (see the module docstring). ``owner`` names who holds it."""

    def __init__(self, owner: object):
        global _owner
        self.libsumo = import_libsumo()
        with _lock:
            holder = _owner() if _owner is not None else None
            if holder is not None and holder is not owner:
                raise SumoBusyError(
                    "simulator 'sumo': another SUMO simulation is already open in this process (libsumo runs "
                    "one simulation per process); close() it first, or run episodes in parallel with "
                    "--executor process"
                )
            _owner = weakref.ref(owner)
        self._owner_ref = weakref.ref(owner)
        self.closed = False

    def begin(self, args: list[str], what: str) -> None:
        """Start the simulation with SUMO's command-line ``args`` (or reload it with them)."""
        global _running
        if self.closed:
            raise VdbError("simulator 'sumo': this simulator was closed; create a new one")
        with _captured_stderr() as messages:
            try:
                if _running:
                    self.libsumo.load(args)
                else:
                    self.libsumo.start(["sumo", *args])
                    _running = True
                failure = None
            except Exception as exc:
                failure = exc
        if failure is not None:
            _running = self._still_running()
            errors = [ln for ln in messages() if ln.lower().startswith("error")] or [_message(failure)]
            raise SumoUnavailableError(
                f"simulator 'sumo': SUMO failed to start for {what}: {errors[0]} "
                f"(if SUMO itself is broken, reinstall it: {INSTALL_HINT} --force-reinstall)"
            )

    def _still_running(self) -> bool:
        try:
            self.libsumo.simulation.getTime()
        except Exception:
            return False
        return True

    def close(self) -> None:
        """End the simulation and let another session start in this process. Safe to call twice."""
        global _owner, _running
        if self.closed:
            return
        self.closed = True
        if _running:
            try:
                self.libsumo.close()
            except Exception:  # already torn down by SUMO itself; nothing left to release
                pass
            _running = False
        with _lock:
            if _owner is not None and _owner() is self._owner_ref():
                _owner = None


@contextlib.contextmanager
def _captured_stderr() -> Iterator[Callable[[], list[str]]]:
    """Collect what SUMO writes on the process's standard error (file descriptor 2) inside the block:
    libsumo reports why it failed only there, its exception says just "Process Error"."""
    lines: list[str] = []
    try:
        sys.stderr.flush()
    except (AttributeError, ValueError):
        pass
    with tempfile.TemporaryFile(mode="w+b") as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            yield lambda: lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace")
            lines.extend(" ".join(ln.split()) for ln in text.splitlines() if ln.strip())


def _message(exc: BaseException) -> str:
    """One line from a libsumo exception (its SWIG proxies print as ``<… proxy of …>``)."""
    text = ""
    for attr in ("getString", "what"):
        getter = getattr(exc, attr, None)
        if callable(getter):
            try:
                text = str(getter())
            except Exception:
                text = ""
            if text:
                break
    if not text:
        text = " ".join(str(a) for a in exc.args) or type(exc).__name__
    return " ".join(text.split())
