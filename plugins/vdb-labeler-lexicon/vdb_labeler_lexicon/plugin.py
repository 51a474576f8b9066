"""Entry point of the ``vdb-labeler-lexicon`` distribution: registers the labeler ``lexicon``.

Registration imports nothing but this module; the rules are imported when the labeler is built.
"""

from __future__ import annotations

import vladrivebench


def make_lexicon_labeler(filter_phantom_car: bool = False):
    """Build the lexicon labeler (``--labeler-opt filter_phantom_car=true`` to drop ORION's phantom car)."""
    from .labeler import LexiconLabeler

    return LexiconLabeler(filter_phantom_car=filter_phantom_car)


@vladrivebench.hookimpl
def register_labelers(register):
    register("lexicon", make_lexicon_labeler,
             description="deterministic offline lexicon rules (the default labeler)")


@vladrivebench.hookimpl
def register_defaults(register):
    register("labeler", "lexicon", priority=10)
