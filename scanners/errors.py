"""Hardware faults: a stage that times out or alarms, a camera that is gone, a display that fails.

Acquisition stops cleanly on a `HardwareError`, keeping every frame captured so far; the command line
reports it in one line with exit status 1.
"""


class HardwareError(RuntimeError):
    """A device did not do what it was told (timeout, alarm, rejected command, lost connection)."""
