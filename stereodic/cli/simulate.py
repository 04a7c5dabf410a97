"""`stereodic simulate`: write a simulated dataset with its ground truth."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "simulate", "Write a simulated dataset with its ground truth", 2)
