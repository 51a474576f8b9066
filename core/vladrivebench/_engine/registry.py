"""The plugin registry: discovers plugins through entry points and collects what each registers.

Every plugin — the core's built-ins included — is a module or object with ``@vladrivebench.hookimpl``
functions, exposed in the ``vladrivebench`` entry-point group. Each is loaded in isolation: one that fails
to import, implements a misspelt hook, raises while registering or registers a name that is taken, is
reported (name, distribution, error) and leaves no trace, while all others keep working. With
``strict=True`` (``vdb --strict-plugins`` or ``VDB_STRICT_PLUGINS=1``) such a failure is fatal instead.
"""

from __future__ import annotations

import importlib
import importlib.metadata as metadata
import inspect
import os
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pluggy

from vladrivebench import PROJECT_NAME, hookspecs
from vladrivebench.errors import ConfigError, PluginLoadError, UnknownNameError, VdbError

ENTRY_POINT_GROUP = PROJECT_NAME
STRICT_ENV = "VDB_STRICT_PLUGINS"
DISABLE_ENV = "VDB_DISABLE_PLUGINS"
KINDS = tuple(hookspecs.REGISTER_HOOKS.values())


class LazyFactory:
    """A factory named by its import path (``"package.module:attribute"``), imported on first use.

    Registering ``register("name", "my_plugin.model:make_model")`` keeps registration free of the
    module's imports; the factory's signature (used to check options) is the target's.
    """

    def __init__(self, target: str):
        module, sep, attribute = target.partition(":")
        if not sep or not module or not attribute:
            raise ValueError(f"a factory path must look like 'package.module:attribute', got {target!r}")
        self.target = target

    def resolve(self) -> Callable[..., Any]:
        module, _, attribute = self.target.partition(":")
        return getattr(importlib.import_module(module), attribute)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.resolve()(*args, **kwargs)

    @property
    def __signature__(self) -> inspect.Signature:
        return inspect.signature(self.resolve())

    def __repr__(self) -> str:
        return f"LazyFactory({self.target!r})"


@dataclass(frozen=True)
class Component:
    """One registered component: its kind and name, the factory that builds it, and who registered it."""

    kind: str
    name: str
    factory: Callable[..., Any] | None
    plugin: str
    distribution: str
    description: str = ""
    path: Path | None = None


@dataclass(frozen=True)
class DefaultDeclaration:
    """A plugin's ``register_defaults`` entry: use ``name`` for ``kind`` unless the user chooses."""

    kind: str
    name: str
    priority: int
    settings: Mapping[str, Any]
    plugin: str
    distribution: str


DEFAULT_KINDS = ("simulator", "labeler", "demo")
"""What plugins may declare defaults for (``demo`` names a model, with how ``vdb demo`` runs it)."""


@dataclass
class PluginInfo:
    """A plugin as ``vdb list-plugins`` shows it."""

    name: str
    distribution: str
    version: str
    status: str = "ok"
    error: str | None = None
    registered: dict[str, list[str]] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "distribution": self.distribution,
            "version": self.version,
            "status": self.status,
            "error": self.error,
            "registered": self.registered,
        }


class Registry:
    """All plugins and their components.

    ``plugins`` are extra ``(name, plugin_object)`` pairs registered after the entry points (tests use
    this to add a plugin for one test); ``entry_points=False`` skips discovery entirely, so a test sees
    only what it registered itself.
    """

    def __init__(
        self,
        plugins: Iterable[tuple[str, object]] = (),
        *,
        entry_points: bool = True,
        strict: bool | None = None,
        disabled: Iterable[str] | None = None,
    ):
        self.strict = _env_flag(STRICT_ENV) if strict is None else strict
        self.disabled = set(disabled if disabled is not None else _env_list(DISABLE_ENV))
        self.manager = pluggy.PluginManager(PROJECT_NAME)
        self.manager.add_hookspecs(hookspecs)
        self.plugins: list[PluginInfo] = []
        self._components: dict[str, dict[str, Component]] = {kind: {} for kind in KINDS}
        self._defaults: list[DefaultDeclaration] = []
        if entry_points:
            for ep in _entry_points():
                self._load_entry_point(ep)
        for name, obj in plugins:
            self.add_plugin(name, obj)

    # -- loading -------------------------------------------------------------------------------------
    def _load_entry_point(self, ep: metadata.EntryPoint) -> None:
        dist = ep.dist.name if ep.dist else "?"
        version = ep.dist.version if ep.dist else "?"
        if ep.name in self.disabled:
            self.plugins.append(PluginInfo(ep.name, dist, version, status="disabled"))
            return
        try:
            obj = ep.load()
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # any import-time failure (sys.exit() too) of a plugin is isolated
            self._fail(PluginInfo(ep.name, dist, version), f"cannot import {ep.value}: {_describe(exc)}")
            return
        self.add_plugin(ep.name, obj, distribution=dist, version=version)

    def add_plugin(self, name: str, obj: object, *, distribution: str = "", version: str = "") -> PluginInfo:
        """Register one plugin object and collect its components, in isolation from the others."""
        info = PluginInfo(name, distribution or "(local)", version or "-")
        if any(p.name == name and p.status == "ok" for p in self.plugins):
            return self._fail(info, f"a plugin named {name!r} is already loaded")
        try:
            self.manager.register(obj, name=name)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            return self._fail(info, f"invalid plugin: {_describe(exc)}")
        try:
            self.manager.check_pending()
        except pluggy.PluginValidationError as exc:
            self.manager.unregister(name=name)
            return self._fail(info, f"unknown hook: {_describe(exc)}")
        staged: list[Component] = []
        try:
            for hook_name, kind in hookspecs.REGISTER_HOOKS.items():
                for impl in getattr(self.manager.hook, hook_name).get_hookimpls():
                    if impl.plugin_name == name:
                        impl.function(register=self._collector(kind, info, staged))
            declared = self._collect_defaults(name, info, staged)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            self.manager.unregister(name=name)
            return self._fail(info, f"failed while registering: {_describe(exc)}")
        self._defaults.extend(declared)
        for comp in staged:
            self._components[comp.kind][comp.name] = comp
            info.registered.setdefault(comp.kind, []).append(comp.name)
        self.plugins.append(info)
        return info

    def _collector(self, kind: str, info: PluginInfo, staged: list[Component]) -> Callable[..., None]:
        def register(name_or_path: Any, factory: Callable[..., Any] | None = None, description: str = "") -> None:
            if kind == "scenario":
                path = Path(name_or_path)
                comp = Component(kind, str(path), None, info.name, info.distribution, description, path)
            else:
                if not isinstance(name_or_path, str) or not name_or_path:
                    raise ValueError(f"{kind} names must be non-empty strings, got {name_or_path!r}")
                if isinstance(factory, str):
                    factory = LazyFactory(factory)
                if not callable(factory):
                    raise ValueError(f"{kind} {name_or_path!r} needs a callable factory")
                comp = Component(kind, name_or_path, factory, info.name, info.distribution, description)
            owner = self._components[kind].get(comp.name)
            if owner is not None:
                raise ValueError(f"{kind} {comp.name!r} is already registered by plugin {owner.plugin!r} "
                                 f"({owner.distribution}), which keeps it; plugin {info.name!r} "
                                 f"({info.distribution}) must use another name")
            if any(c.kind == kind and c.name == comp.name for c in staged):
                raise ValueError(f"{kind} {comp.name!r} is registered twice by plugin {info.name!r}")
            staged.append(comp)

        return register

    def _collect_defaults(self, name: str, info: PluginInfo, staged: list[Component]) -> list[DefaultDeclaration]:
        declared: list[DefaultDeclaration] = []

        def register(kind: Any, component: Any, priority: int = 0, **settings: Any) -> None:
            if kind not in DEFAULT_KINDS:
                raise ValueError(f"defaults can be declared for {', '.join(DEFAULT_KINDS)}, not {kind!r}")
            own_kind = "model" if kind == "demo" else kind
            if not any(c.kind == own_kind and c.name == component for c in staged):
                raise ValueError(f"default {kind} {component!r} is not a {own_kind} this plugin registers")
            if not isinstance(priority, int) or isinstance(priority, bool):
                raise ValueError(f"default {kind} {component!r}: priority must be an integer, got {priority!r}")
            declared.append(DefaultDeclaration(kind, component, priority, dict(settings), info.name,
                                               info.distribution))

        for impl in self.manager.hook.register_defaults.get_hookimpls():
            if impl.plugin_name == name:
                impl.function(register=register)
        return declared

    def _fail(self, info: PluginInfo, error: str) -> PluginInfo:
        info.status, info.error = "error", error
        if self.strict:
            raise PluginLoadError(f"plugin {info.name!r} ({info.distribution}): {error}")
        self.plugins.append(info)
        return info

    # -- lookup --------------------------------------------------------------------------------------
    def names(self, kind: str) -> list[str]:
        return sorted(self._components[kind])

    def components(self, kind: str) -> list[Component]:
        return [self._components[kind][n] for n in self.names(kind)]

    def get(self, kind: str, name: str) -> Component:
        """The component, or a one-line error with suggestions and the available names."""
        try:
            return self._components[kind][name]
        except KeyError:
            if name in self.disabled:
                raise ConfigError(f"{kind} {name!r} is disabled ({DISABLE_ENV}={','.join(sorted(self.disabled))}); "
                                  f"remove it from {DISABLE_ENV} to use it") from None
            raise UnknownNameError(kind, name, self.names(kind)) from None

    def create(self, kind: str, name: str, options: Mapping[str, Any] | None = None) -> Any:
        """Build a component, checking ``options`` against its factory's signature first."""
        comp = self.get(kind, name)
        options = dict(options or {})
        check_options(kind, name, comp.factory, options)
        try:
            return comp.factory(**options)
        except ModuleNotFoundError as exc:
            raise VdbError(
                f"{kind} {name!r} needs the Python package {exc.name!r}, which is not installed: "
                f"pip install {exc.name} (plugin {comp.plugin!r}, distribution {comp.distribution})"
            ) from None

    def call_hook(self, hook_name: str, **kwargs: Any) -> list[Any]:
        """Call a non-register hook (e.g. ``register_commands``) on every plugin, isolating failures."""
        results = []
        for impl in getattr(self.manager.hook, hook_name).get_hookimpls():
            try:
                results.append(impl.function(**kwargs))
            except KeyboardInterrupt:
                raise
            except BaseException as exc:  # sys.exit() in a plugin's hook too: reported, never the process's end
                info = next((p for p in self.plugins if p.name == impl.plugin_name), None)
                where = f"{impl.plugin_name!r} ({info.distribution})" if info else repr(impl.plugin_name)
                if self.strict:
                    raise PluginLoadError(f"plugin {where}: {hook_name} failed: {_describe(exc)}") from None
                if info is not None:
                    info.status, info.error = "error", f"{hook_name} failed: {_describe(exc)}"
        return results

    def default_declarations(self, kind: str) -> list[DefaultDeclaration]:
        """Every plugin's default for ``kind``, highest priority first (ties in plugin order)."""
        return sorted((d for d in self._defaults if d.kind == kind), key=lambda d: -d.priority)

    def default(self, kind: str, flag: str) -> DefaultDeclaration:
        """The default ``kind`` by the rule of :func:`~vladrivebench.hookspecs.register_defaults`, or a
        one-line error saying how to choose with ``flag``."""
        declared = self.default_declarations(kind)
        what = "model for vdb demo" if kind == "demo" else kind
        if not declared:
            listing = ", ".join(self.names("model" if kind == "demo" else kind)) or "none installed"
            raise ConfigError(f"no installed plugin declares a default {what}: choose one with {flag} "
                              f"(available: {listing})")
        tied = [d for d in declared if d.priority == declared[0].priority]
        if len(tied) > 1:
            names = ", ".join(f"{d.name!r} (plugin {d.plugin!r}, {d.distribution})" for d in tied)
            raise ConfigError(f"several plugins declare the default {what} with priority {tied[0].priority}: "
                              f"{names}; choose one with {flag}")
        return declared[0]

    def failures(self) -> list[PluginInfo]:
        return [p for p in self.plugins if p.status == "error"]


def check_options(kind: str, name: str, factory: Callable[..., Any] | None, options: Mapping[str, Any]) -> None:
    """Raise a one-line :class:`ConfigError` if ``factory`` cannot take ``options``."""
    if factory is None:
        return
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        return
    params = sig.parameters.values()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return
    accepted = [p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
    unknown = [k for k in options if k not in accepted]
    if unknown:
        takes = ", ".join(accepted) or "no options"
        raise ConfigError(f"{kind} {name!r} does not take option {unknown[0]!r} (it takes: {takes})")


_default: Registry | None = None


def get_registry(*, strict: bool | None = None) -> Registry:
    """The process-wide registry, built on first use from the installed entry points."""
    global _default
    if _default is None or (strict and not _default.strict):
        _default = Registry(strict=strict)
    return _default


def set_registry(registry: Registry | None) -> Registry | None:
    """Replace the process-wide registry (tests); returns the previous one."""
    global _default
    previous, _default = _default, registry
    return previous


def _entry_points() -> list[metadata.EntryPoint]:
    eps = metadata.entry_points(group=ENTRY_POINT_GROUP)
    seen: set[tuple[str, str]] = set()
    unique = []
    # The core first, then by distribution name and entry-point name: which plugin keeps a contested name
    # never depends on the order sys.path lists the distributions in.
    for ep in sorted(eps, key=lambda e: (e.name != "core", (e.dist.name if e.dist else "").lower(), e.name)):
        key = (ep.name, ep.value)
        if key not in seen:  # the same distribution found twice on sys.path
            seen.add(key)
            unique.append(ep)
    return unique


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _env_flag(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}


def _env_list(name: str) -> list[str]:
    return [s.strip() for s in os.environ.get(name, "").split(",") if s.strip()]
