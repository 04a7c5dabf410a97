"""`stereodic dic`: Stereo 3D digital image correlation."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "dic", "Stereo 3D digital image correlation", 8)
