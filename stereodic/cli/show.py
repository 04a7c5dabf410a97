"""`stereodic show`: Pictures of a result (distortion, residuals, strain, cloud)."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "show", "Pictures of a result (distortion, residuals, strain, cloud)", 3)
