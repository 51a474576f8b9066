"""Executors: how a sweep of independent jobs (episodes) is run.

An executor's ``run(worker, jobs)`` yields ``worker(job)`` for every job, in any order. ``worker`` is a
picklable module-level function that reports its own failures as results; if a worker raises anyway, or
its process dies, the executor yields a :class:`JobFailure` for that job and goes on with the others.

Built in: ``sequential`` (in this process), ``process`` (a pool of spawned worker processes; each
worker process lives for the whole sweep, so whatever the worker function caches — a loaded model, a
simulator — is built once per process and reused across episodes) and ``pipelined`` (jobs on threads of
this process, their models in one model-server process, so the harness of one job runs while the model
computes another's step). A distributed engine is a plugin (``vdb-executor-ray``).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import wait
from typing import Any

from vladrivebench.errors import ConfigError


@dataclass(frozen=True)
class JobFailure:
    """A job whose worker raised or whose worker process died; ``error`` is one line."""

    job: Any
    error: str
    details: str = ""


def failure_of(job: Any, exc: BaseException) -> JobFailure:
    """A :class:`JobFailure` for ``job`` from an exception, with its traceback as details."""
    text = " ".join(str(exc).split())
    details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return JobFailure(job, f"{type(exc).__name__}: {text}" if text else type(exc).__name__, details)


def check_workers(workers: Any) -> int:
    """``workers`` as a positive int, or a one-line :class:`ConfigError`."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be a whole number ≥ 1, got {workers!r}")
    return workers


def check_start_method(executor: str, start_method: Any) -> str:
    """``start_method`` if this platform's multiprocessing has it, else a one-line :class:`ConfigError`."""
    if start_method not in multiprocessing.get_all_start_methods():
        raise ConfigError(f"executor {executor!r}: start_method {start_method!r} is not available here "
                          f"(available: {', '.join(multiprocessing.get_all_start_methods())})")
    return start_method


def stop_process(process: Any, timeout: float = 5.0) -> None:
    """Wait up to ``timeout`` seconds for ``process`` to end (it was asked to), then kill it."""
    process.join(timeout=timeout)
    if process.is_alive():
        process.kill()
        process.join()


class SequentialExecutor:
    """Runs every job in this process, one after the other (the reference for determinism)."""

    in_process = True

    def __init__(self, workers: int = 1):
        self.workers = check_workers(workers)

    def run(self, worker: Callable[[Any], Any], jobs: Iterable[Any]) -> Iterator[Any]:
        for job in jobs:
            try:
                result = worker(job)
            except Exception as exc:
                result = failure_of(job, exc)
            yield result


class ProcessExecutor:
    """A pool of ``workers`` spawned processes, each running jobs one at a time for the whole sweep.

    The pool is its own small dispatcher rather than ``concurrent.futures``: it knows which job each
    process holds, so a process that dies (a segfault in a native library, the OOM killer) fails only
    that job — reported as a :class:`JobFailure` — and is replaced. Workers die with the parent
    (``PR_SET_PDEATHSIG`` on Linux), so a killed sweep leaves no orphans writing files.
    """

    in_process = False

    def __init__(self, workers: int = 2, start_method: str = "spawn"):
        self.workers = check_workers(workers)
        self.start_method = check_start_method("process", start_method)

    def run(self, worker: Callable[[Any], Any], jobs: Iterable[Any]) -> Iterator[Any]:
        pending = deque(jobs)
        if not pending:
            return
        context = multiprocessing.get_context(self.start_method)
        slots: list[_Slot] = [_Slot.start(context, worker) for _ in range(min(self.workers, len(pending)))]
        try:
            while pending or any(slot.job is not None for slot in slots):
                for index, slot in enumerate(slots):
                    if slot.job is None and pending:
                        if not slot.process.is_alive():  # died while idle (e.g. the OOM killer)
                            slots[index] = slot = _Slot.start(context, worker)
                        slot.assign(pending.popleft())
                busy = [slot for slot in slots if slot.job is not None]
                ready = wait([slot.conn for slot in busy] + [slot.process.sentinel for slot in busy])
                for slot in busy:
                    if slot.conn in ready or slot.process.sentinel in ready:
                        outcome = slot.collect()
                        if outcome is not None:
                            yield outcome
                        if slot.job is None and not slot.process.is_alive():  # its job was reported
                            slots[slots.index(slot)] = _Slot.start(context, worker)
        finally:
            for slot in slots:
                slot.stop()


@dataclass
class _Slot:
    """One worker process, its end of the pipe and the job it holds (if any)."""

    process: Any
    conn: Any
    job: Any = None

    @classmethod
    def start(cls, context: Any, worker: Callable[[Any], Any]) -> _Slot:
        parent_end, child_end = context.Pipe()
        process = context.Process(target=_worker_main, args=(child_end, worker), daemon=True)
        process.start()
        child_end.close()
        return cls(process, parent_end)

    def assign(self, job: Any) -> None:
        self.job = job
        try:
            self.conn.send(job)
        except OSError:  # the process died just now: collect() reports the job as failed
            pass

    def collect(self) -> Any:
        """The result of the job held, or a JobFailure if the process died; None if nothing is ready."""
        job = self.job
        try:
            if self.conn.poll():
                result = self.conn.recv()
                self.job = None
                return result
        except (EOFError, OSError):
            pass
        if self.process.is_alive():
            return None
        self.process.join()
        self.job = None
        code = self.process.exitcode
        how = f"killed by signal {-code}" if code is not None and code < 0 else f"exited with status {code}"
        return JobFailure(job, f"worker process {how} while running this job")

    def stop(self) -> None:
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        stop_process(self.process)
        self.conn.close()


def _worker_main(conn: Any, worker: Callable[[Any], Any]) -> None:
    """A worker process: receive jobs until told to stop (None) or the parent goes away."""
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the driver's to handle: it stops the pool
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        try:
            result = worker(job)
        except Exception as exc:
            result = failure_of(job, exc)
        try:
            conn.send(result)
        except Exception as exc:  # an unpicklable result
            conn.send(failure_of(job, exc))


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (no-op elsewhere)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, signal.SIGKILL, 0, 0, 0)
        parent = multiprocessing.parent_process()
        if parent is not None and os.getppid() != parent.pid:  # the parent died before prctl took effect
            os._exit(1)
    except (OSError, AttributeError):
        pass


PIPELINED_SWITCH_INTERVAL = 0.0005
"""Seconds between the interpreter's forced thread switches while the ``pipelined`` executor runs."""


class PipelinedExecutor:
    """``workers`` jobs at a time on threads of this process, their models in one model-server process.

    Each thread's models are :class:`~vladrivebench._engine.model_server.RemoteModel` proxies on its own
    pipe to the server (:mod:`~vladrivebench._engine.model_server`). A thread waiting for its batched model
    call holds no lock, so the other threads' harness (rendering, control, logging, simulation) runs
    meanwhile: with a batched model and ``workers=2`` on two cores, the server computes one batch job's
    step while the driver advances the other's lanes. A job's calls reach its own model instances in the
    order it makes them, so the logs are byte-identical to a sequential run.
    """

    in_process = False

    def __init__(self, workers: int = 2, start_method: str = "spawn"):
        self.workers = check_workers(workers)
        self.start_method = check_start_method("pipelined", start_method)
        self.server_stats: dict[str, float] = {}  # what the model server measured in the last run

    def run(self, worker: Callable[[Any], Any], jobs: Iterable[Any]) -> Iterator[Any]:
        import queue
        import threading

        from vladrivebench._engine.model_server import ModelServer
        from vladrivebench._engine.sweep import serve_models_from

        pending: queue.SimpleQueue = queue.SimpleQueue()
        count = 0
        for job in jobs:
            pending.put(job)
            count += 1
        if not count:
            return
        threads = min(self.workers, count)
        server = ModelServer(threads, self.start_method)
        results: queue.SimpleQueue = queue.SimpleQueue()
        stop = threading.Event()

        def work(pipe: int) -> None:
            with serve_models_from(server, pipe):
                while not stop.is_set():
                    try:
                        job = pending.get_nowait()
                    except queue.Empty:
                        return
                    try:
                        result = worker(job)
                    except Exception as exc:
                        result = failure_of(job, exc)
                    results.put(result)

        pool = [threading.Thread(target=work, args=(i,), daemon=True, name=f"vdb-pipelined-{i}")
                for i in range(threads)]
        switch_interval = sys.getswitchinterval()
        # A thread whose model step came back waits for the interpreter lock while another thread runs its
        # harness; the default 5 ms until a forced switch leaves the server idle longer (kv at B = 16: the
        # server waited 7.1–7.4 % of its span at 0.5 ms against 7.7–7.8 % at 5 ms).
        sys.setswitchinterval(PIPELINED_SWITCH_INTERVAL)
        for thread in pool:
            thread.start()
        try:
            for _ in range(count):
                yield _interruptible_get(results)
        finally:
            stop.set()
            for thread in pool:  # after the last result a thread only looks for more work
                thread.join(timeout=1.0)
            if not any(thread.is_alive() for thread in pool):  # no call in flight: the server may be asked
                try:
                    self.server_stats = server.stats()
                except (EOFError, OSError):  # the server died: the jobs it held were reported as failed
                    pass
            server.stop()
            for thread in pool:
                thread.join(timeout=5)
            sys.setswitchinterval(switch_interval)


def _interruptible_get(results: Any) -> Any:
    """The next item of a ``queue.SimpleQueue``, waking up often enough for Ctrl-C to reach this thread
    (a get without a timeout blocks signals until an item arrives)."""
    import queue

    while True:
        try:
            return results.get(timeout=0.2)
        except queue.Empty:
            continue
