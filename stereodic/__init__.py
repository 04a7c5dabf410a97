"""stereodic: per-pixel rays -> virtual cameras, rectified stereo, matching, DIC and 3D.

Depends on `calib` only; `stereodic.cli` and `stereodic.bench` are the two places that know all three
packages (they drive the simulated rig of `scanners.sim`).
"""

from calib import __version__

__all__ = ["__version__"]
