"""`stereodic rectify`: Rectify a stereo image pair with a rig."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "rectify", "Rectify a stereo image pair with a rig", 5)
