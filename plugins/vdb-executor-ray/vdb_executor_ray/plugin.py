"""Registers the ``ray`` executor. Importing this module does not import ray: the factory does."""

from __future__ import annotations

import vladrivebench


def make_executor(workers: int = 2, address: str | None = None, num_cpus_per_worker: float = 1.0,
                  object_store_mb: int = 200):
    """Build a :class:`~vdb_executor_ray.executor.RayExecutor` (see its docstring for the options)."""
    import ray  # noqa: F401  - fail here, with the registry's "pip install ray" message, if it is missing

    from .executor import RayExecutor

    return RayExecutor(workers=workers, address=address, num_cpus_per_worker=num_cpus_per_worker,
                       object_store_mb=object_store_mb)


@vladrivebench.hookimpl
def register_executors(register):
    register("ray", make_executor,
             description="Ray actors, one per worker, each keeping its model loaded (--address for a cluster)")
