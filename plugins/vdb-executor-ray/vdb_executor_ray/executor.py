"""The Ray executor: one long-lived Ray actor per worker, each running episodes one at a time.

Each actor is its own process that lives for the whole sweep, so the sweep's worker function builds the
model and simulator once per actor and reuses them for every episode it is given — the same contract as
the core's ``process`` executor, on one machine or a cluster. Results are yielded as they finish; a job
whose actor dies (a crash in a native library, a lost node) comes back as a
:class:`~vladrivebench._engine.executors.JobFailure` and the actor is replaced.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from vladrivebench import ConfigError
from vladrivebench.executors import JobFailure, check_workers, failure_of


class _EpisodeWorker:
    """The actor: runs ``worker(job)``; whatever ``worker`` caches at module level stays in this process."""

    def run(self, worker: Callable[[Any], Any], job: Any) -> Any:
        try:
            return worker(job)
        except Exception as exc:
            return failure_of(job, exc)

    def pid(self) -> int:
        return os.getpid()


PROBE_TIMEOUT_S = 3.0
"""How long the executor waits for a cluster's port to accept a connection before refusing the address."""


def check_reachable(address: str, timeout: float = PROBE_TIMEOUT_S) -> None:
    """Refuse (one line) a ``host:port`` or ``ray://host:port`` address whose port accepts no TCP connection
    within ``timeout`` seconds, before ``ray.init`` would retry it for minutes. ``"auto"`` and ``"local"``
    are left to Ray."""
    import socket

    target = address.strip()
    if target in {"auto", "local"}:
        return
    host, sep, port = target.split("://", 1)[-1].rstrip("/").rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"executor 'ray': address must be 'auto', 'host:port' or 'ray://host:port', got {address!r}")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"executor 'ray': no Ray cluster answers at {address} ({reason}); start one "
                          f"(`ray start --head`) or give --address of a running cluster") from None


class RayExecutor:
    """Runs jobs on ``workers`` Ray actors.

    ``address`` is passed to ``ray.init`` (``None`` starts a local Ray instance with
    ``workers × num_cpus_per_worker`` CPUs and ``object_store_mb`` of object store, shut down after the
    sweep; ``"auto"`` or ``"ray://host:10001"`` joins an existing cluster, which is left running). If Ray
    is already initialised in this process it is used as it is. A local instance's workers get this
    process's ``sys.path``, like spawned processes do, so locally added plugins resolve there too.
    """

    in_process = False

    def __init__(self, workers: int = 2, address: str | None = None, num_cpus_per_worker: float = 1.0,
                 object_store_mb: int = 200):
        self.workers = check_workers(workers)
        if not isinstance(num_cpus_per_worker, (int, float)) or num_cpus_per_worker <= 0:
            raise ConfigError(f"executor 'ray': num_cpus_per_worker must be a number > 0, got {num_cpus_per_worker!r}")
        if address is not None and (not isinstance(address, str) or not address.strip()):
            raise ConfigError(f"executor 'ray': address must be a non-empty string, got {address!r}")
        if address is not None:
            check_reachable(address)
        self.address = address
        self.num_cpus_per_worker = float(num_cpus_per_worker)
        self.object_store_mb = int(object_store_mb)

    def run(self, worker: Callable[[Any], Any], jobs: Iterable[Any]) -> Iterator[Any]:
        import ray

        pending = deque(jobs)
        if not pending:
            return
        started_here = self._connect(ray)
        actor_class = ray.remote(num_cpus=self.num_cpus_per_worker, max_restarts=0)(_EpisodeWorker)
        actors = [actor_class.remote() for _ in range(min(self.workers, len(pending)))]
        in_flight: dict[Any, tuple[int, Any]] = {}

        def submit(index: int) -> None:
            job = pending.popleft()
            in_flight[actors[index].run.remote(worker, job)] = (index, job)

        try:
            for index in range(len(actors)):
                submit(index)
            while in_flight:
                ready, _ = ray.wait(list(in_flight), num_returns=1)
                index, job = in_flight.pop(ready[0])
                result, actor_died = self._collect(ray, ready[0], job)
                if actor_died:
                    ray.kill(actors[index])
                    actors[index] = actor_class.remote()
                yield result
                if pending:
                    submit(index)
        finally:
            for actor in actors:
                ray.kill(actor)
            if started_here:
                ray.shutdown()

    def _connect(self, ray: Any) -> bool:
        """Initialise Ray unless it already is; True if this call started it (then it is shut down after)."""
        if ray.is_initialized():
            return False
        options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                   "logging_level": logging.ERROR, "configure_logging": False}
        if self.address is None:
            options["num_cpus"] = math.ceil(self.workers * self.num_cpus_per_worker)
            options["object_store_memory"] = self.object_store_mb * 1024 * 1024
            # The local raylet inherits this environment and passes it to the workers it starts (a
            # runtime_env would do the same at several seconds per actor).
            with _environment(PYTHONPATH=local_pythonpath()):
                ray.init(**options)
        else:
            ray.init(address=self.address, **options)
        return True

    @staticmethod
    def _collect(ray: Any, ref: Any, job: Any) -> tuple[Any, bool]:
        """The job's result, or a JobFailure; and whether its actor died."""
        try:
            return ray.get(ref), False
        except ray.exceptions.RayActorError as exc:
            reason = " ".join(str(exc).split())[:200]
            return JobFailure(job, f"ray worker died while running this job ({reason})"), True
        except ray.exceptions.RayError as exc:
            return failure_of(job, exc), False


@contextlib.contextmanager
def _environment(**values: str) -> Iterator[None]:
    saved = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def local_pythonpath() -> str:
    """This process's import path, for the workers of a local Ray instance."""
    entries = [os.path.abspath(p) for p in sys.path if p and os.path.isdir(p)]
    existing = os.environ.get("PYTHONPATH", "")
    return os.pathsep.join(dict.fromkeys(entries + ([existing] if existing else [])))
