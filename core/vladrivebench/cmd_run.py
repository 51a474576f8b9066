"""``vdb run`` / ``vdb scenarios`` / ``vdb demo`` (being built)."""

COMMANDS: list = []
