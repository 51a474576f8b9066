"""The scenario suite, shipped as data inside the core as `vladrivebench.suite`."""
