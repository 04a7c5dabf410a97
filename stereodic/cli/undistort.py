"""`stereodic undistort`: Undistort images with a camera's virtual pinhole model."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "undistort", "Undistort images with a camera's virtual pinhole model", 4)
