"""VLADriveBench: is a driving VLA's chain-of-thought about the world, and connected to its action?

The core is small on purpose: records, protocols, hook specifications, the plugin registry, the runner,
the episode log format and the CLI. Models, simulators, labelers and most metrics are plugins.
Importing this package must stay cheap: no torch, transformers or libsumo, ever.
"""

import pluggy

__version__ = "0.1.0"

PROJECT_NAME = "vladrivebench"
"""One name everywhere: the hook marker, the entry-point group and the import package."""

hookimpl = pluggy.HookimplMarker(PROJECT_NAME)
"""Decorate a plugin's hook implementations with this marker (``@vladrivebench.hookimpl``)."""

__all__ = ["PROJECT_NAME", "__version__", "hookimpl"]
