"""The plugin: one hook. The factory is named by its import path, so registering imports nothing heavy."""

from __future__ import annotations

import vladrivebench


@vladrivebench.hookimpl
def register_paradigms(register):
    register("salience", "vdb_paradigm_salience.paradigm:Salience",
             description="override rate of 'road is clear, accelerate' against the obstacle's salience "
                         "(kind × offset × onset distance × size from one SAFE route), logistic threshold")
