"""`stereodic dic2d`: 2D subset digital image correlation."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "dic2d", "2D subset digital image correlation", 8)
