"""Episode metadata records the versions of every package that took part and every option's effective value."""

from __future__ import annotations

from vladrivebench import hookimpl
from vladrivebench._engine.registry import Registry
from vladrivebench._engine.sweep import ComponentSpec, collect_versions, effective_options


def make_model(alpha: float = 0.5, mode: str = "fast", *, limit: int | None = None):
    return object()


class Plugin:
    @hookimpl
    def register_models(self, register):
        register("defaults", make_model)


def test_effective_options_fill_in_every_factory_default():
    registry = Registry([("p", Plugin())], entry_points=False)
    assert effective_options(registry, ComponentSpec("model", "defaults", {})) == \
        {"alpha": 0.5, "mode": "fast", "limit": None}
    assert effective_options(registry, ComponentSpec("model", "defaults", {"mode": "slow"}))["mode"] == "slow"


def test_versions_include_the_requirements_of_a_components_distribution():
    registry = Registry()
    versions = collect_versions(registry, [ComponentSpec("model", "kv", {})])
    for name in ("vdb-model-neural", "vdb-adapter-transformers", "torch", "transformers"):
        assert versions.get(name, "-") != "-", name
    assert versions["python"] and versions["vladrivebench"]
