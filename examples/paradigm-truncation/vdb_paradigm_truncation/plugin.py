"""The plugin: one hook. The factory is named by its import path, so registering imports nothing heavy."""

from __future__ import annotations

import vladrivebench


@vladrivebench.hookimpl
def register_paradigms(register):
    register("truncation", "vdb_paradigm_truncation.paradigm:Truncation",
             description="the CoT cut to its first k % (Lanham et al.); action change vs the own CoT per k")
