"""`stereodic acquire`: Drive the real stage, display and camera."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "acquire", "Drive the real stage, display and camera", 7)
