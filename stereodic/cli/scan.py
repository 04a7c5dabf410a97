"""`stereodic scan`: Structured-light scan to a point cloud."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "scan", "Structured-light scan to a point cloud", 6)
