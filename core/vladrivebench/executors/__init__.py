"""Writing an executor: how a failing job comes back, and how the worker count is checked.

An executor plugin's ``run(worker, jobs)`` yields ``worker(job)`` for every job; a job that raises (or whose
worker dies) comes back as a :class:`JobFailure` made with :func:`failure_of`, never stopping the others.
:class:`SequentialExecutor` is the reference implementation.
"""

from vladrivebench._engine.executors import JobFailure, SequentialExecutor, check_workers, failure_of

__all__ = ["JobFailure", "SequentialExecutor", "check_workers", "failure_of"]
