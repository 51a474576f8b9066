"""Registration: cheap, imports only this module (the metric's code is imported when it is built)."""

from __future__ import annotations

import vladrivebench


def make_metric():
    from .metric import FirstMentionDistance

    return FirstMentionDistance()


@vladrivebench.hookimpl
def register_metrics(register):
    register("first_mention", make_metric, description="distance at which the target is first mentioned")
