"""calib: captured fringe images -> per-pixel camera rays (the PRVM).

Lowest layer of stereodic: it imports neither `stereodic` nor `scanners`.
"""

import os

# numba's parallel kernels: OpenMP (libgomp, installed by ./run). The TBB wheel that Open3D brings is
# older than numba accepts, and probing it prints a warning on every first parallel call.
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")

__version__ = "0.1.0"
