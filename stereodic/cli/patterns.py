"""`stereodic patterns`: Write phase-shifting fringe patterns for a display."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "patterns", "Write phase-shifting fringe patterns for a display", 3)
