"""stereodic: per-pixel rays -> virtual cameras, rectified stereo, matching, DIC and 3D.

Its processing modules depend on `calib` only; `stereodic.cli`, `stereodic.bench` and `stereodic.demo` are
the one layer that knows all three packages (they drive the rigs of `scanners`; tests/test_layering.py).
"""

import os

# OpenMP threads that finished their share sleep instead of spinning (libgomp spins for milliseconds by
# default): between the DIC kernels' parallel loops the process runs Python, and in a DIC run the next
# image pair is prepared in a thread beside it - a spinning thread would take the core from both
# (docs/dic.md, "Speed of long sequences"). Read once, when libgomp loads: set here, before anything of
# ours loads it; an explicit setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from calib import __version__  # noqa: E402

__all__ = ["__version__"]
