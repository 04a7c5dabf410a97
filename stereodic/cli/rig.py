"""`stereodic rig`: Build a rectified virtual stereo pair from two PRVMs."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "rig", "Build a rectified virtual stereo pair from two PRVMs", 5)
