"""calib: captured fringe images -> per-pixel camera rays (the PRVM).

Lowest layer of stereodic: it imports neither `stereodic` nor `scanners`.
"""

__version__ = "0.1.0"
