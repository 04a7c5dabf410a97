"""`stereodic calibrate`: Calibrate one camera's per-pixel rays (PRVM)."""

from stereodic.cli.common import planned


def register(sub):
    planned(sub, "calibrate", "Calibrate one camera's per-pixel rays (PRVM)", 3)
