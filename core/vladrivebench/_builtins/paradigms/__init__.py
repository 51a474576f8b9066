"""The core's intervention paradigms, registered through ``register_paradigms`` like any plugin's.

Each module is one paradigm built from the public API only (:mod:`vladrivebench.intervention`,
:mod:`vladrivebench.metrics`): :mod:`.open_loop`, :mod:`.closed_loop`, :mod:`.safety`. A third-party
paradigm is the same: one module and an entry point (see ``examples/paradigm-truncation``).
"""
