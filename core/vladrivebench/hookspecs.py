"""Hook specifications: how a plugin tells VLADriveBench what it provides.

Every hook is register-style: the plugin receives a ``register`` callable and calls it once per component.
Registration must be cheap: register a *factory* (a class or function) and import heavy libraries (torch,
transformers, libsumo) inside it, when the component is first created — ``vdb list-plugins`` and
``vdb --help`` load every plugin and must stay fast and light.

A factory may also be given as its import path, ``"package.module:attribute"``: it is imported when
the component is first built (and its signature checked against the options then).

Hooks evolve compatibly: arguments may be added, never renamed or removed. A plugin implements only the
hooks it needs; a misspelt hook name is reported as an error of that plugin.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pluggy

from vladrivebench import PROJECT_NAME

hookspec = pluggy.HookspecMarker(PROJECT_NAME)

Register = Callable[..., None]


@hookspec
def register_models(register: Register) -> None:
    """Register VLA models.

    ``register(name, factory, description="")``: ``factory(**options)`` returns a
    :class:`~vladrivebench.protocols.VLAModel`; options come from ``--model-opt key=value`` or a config
    file and are checked against the factory's signature before it is called.

    Example::

        @vladrivebench.hookimpl
        def register_models(register):
            register("my-vla", make_my_vla, description="My VLA on transformers")
    """


@hookspec
def register_simulators(register: Register) -> None:
    """Register simulators.

    ``register(name, factory, description="")``: ``factory(**options)`` returns a
    :class:`~vladrivebench.protocols.Simulator` (options from ``--sim-opt key=value``).
    """


@hookspec
def register_labelers(register: Register) -> None:
    """Register CoT labelers.

    ``register(name, factory, description="")``: ``factory(**options)`` returns a
    :class:`~vladrivebench.protocols.Labeler` (options from ``--labeler-opt key=value``).
    """


@hookspec
def register_metrics(register: Register) -> None:
    """Register metrics.

    ``register(name, factory, description="")``: ``factory()`` returns a
    :class:`~vladrivebench.protocols.Metric`; ``vdb metrics`` and ``vdb report`` compute every registered
    metric, so a new metric distribution shows up in reports without touching the core.
    """


@hookspec
def register_controllers(register: Register) -> None:
    """Register trajectory-tracking controllers.

    ``register(name, factory, description="")``: ``factory(**options)`` returns a
    :class:`~vladrivebench.protocols.Controller`.
    """


@hookspec
def register_executors(register: Register) -> None:
    """Register executors (how a sweep of episodes is run).

    ``register(name, factory, description="")``: ``factory(workers=N, **options)`` returns a
    :class:`~vladrivebench.protocols.Executor`.
    """


@hookspec
def register_scenarios(register: Register) -> None:
    """Register scenario files or packs.

    ``register(path, description="")``: ``path`` is a scenario file (TOML or JSON) or a directory whose
    ``*.toml``/``*.json`` files are scenarios. Every file is validated when loaded; ids must be unique.

    Example::

        @vladrivebench.hookimpl
        def register_scenarios(register):
            register(pathlib.Path(__file__).parent / "my_pack")
    """


@hookspec
def register_conditions(register: Register) -> None:
    """Register CoT intervention conditions.

    ``register(name, factory, description="")``: ``factory()`` returns a condition: an object satisfying
    ``vladrivebench._intervention.conditions.Condition`` (e.g. a ``TextCondition``), whose ``name`` equals ``name``.
    """


@hookspec
def register_defaults(register: Register) -> None:
    """Declare which of your components should be used when the user names none.

    ``register(kind, name, priority=0, **settings)``: ``kind`` is a component kind (``"simulator"`` for
    ``--sim``, ``"labeler"`` for ``vdb label``) or ``"demo"`` (the model ``vdb demo`` runs; ``settings`` then
    say how: ``controller``, ``sim_options``, ``model_options`` and a one-line ``about``). ``name`` must be
    one of your own components of that kind (for ``"demo"``: one of your models).

    The rule when several plugins declare a default of the same kind: the highest ``priority`` wins; two
    declarations sharing the highest priority are refused with one line naming both, and the user chooses
    on the command line. The core declares none of its own for these kinds — it names no plugin component.

    Example::

        @vladrivebench.hookimpl
        def register_defaults(register):
            register("simulator", "my-sim", priority=10)
    """


@hookspec
def register_commands(cli: Any) -> None:
    """Add commands to the ``vdb`` command-line tool.

    ``cli`` is the top-level ``click.Group``; add commands with ``@cli.command()``. Import heavy
    libraries inside the command's function, not at module level.
    """


REGISTER_HOOKS: dict[str, str] = {
    "register_models": "model",
    "register_simulators": "simulator",
    "register_labelers": "labeler",
    "register_metrics": "metric",
    "register_controllers": "controller",
    "register_executors": "executor",
    "register_scenarios": "scenario",
    "register_conditions": "condition",
}
"""Register-style hooks and the kind of component each registers."""
