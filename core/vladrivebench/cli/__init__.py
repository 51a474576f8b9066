"""Adding ``vdb`` commands (``register_commands``): progress on stderr and option parsing as the core does.

A command reports long work with :class:`Progress` (the one progress line of every ``vdb`` command: done /
total, rate, ETA; redrawn on a terminal, throttled in logs), parses ``key=value`` options with
:func:`parse_options`, and raises :class:`~vladrivebench.VdbError` for every user mistake — the ``vdb``
entry point prints it as one line and exits with status 2.
"""

from vladrivebench._cli.progress import Progress, format_duration
from vladrivebench._engine.options import parse_options, parse_value

__all__ = ["Progress", "format_duration", "parse_options", "parse_value"]
