"""`stereodic export`: Export a rig's pinhole models for other software."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "export", "Export a rig's pinhole models for other software", 5)
