"""A stereo DIC run reported in the specimen's frame (`stereodic dic --frame specimen`).

The frame is the best-fit plane of state 0's points (`stereodic.gauge.frame.specimen_frame`: origin at
their centroid or a chosen pixel of the original left reference image, x along a chosen direction of
that image, z towards the cameras). Every state's points and displacements are turned into it, and its
strains refitted on the reference shape in that frame (`stereodic.strain.StrainFit`: e1 is the
specimen's x projected on the local tangent plane), in the run's strain measure.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from stereodic.dic3d.stereo import StereoSettings, StereoState
from stereodic.gauge.frame import SpecimenFrame, specimen_frame
from stereodic.strain import StrainFit
from stereodic.strain_measures import measure_strain


class SpecimenStates:
    """Turns a run's states into the specimen's frame: call it with a StereoState (rig frame) for the same
    state in the specimen's frame (`strain` None, `measure` refitted).

    Parameters
    ----------
    state0 : StereoState
        The reference state (rig frame), whose points and left original-image positions define the frame.
    settings : StereoSettings
        The run's settings (strain window and measure).
    origin_px, x_direction_px
        As `stereodic.gauge.frame.specimen_frame` (pixels of the original left reference image).
    """

    def __init__(self, state0: StereoState, settings: StereoSettings, *, origin_px=None,
                 x_direction_px=(1.0, 0.0)):
        ok = state0.converged & np.isfinite(state0.points).all(-1)
        self.frame: SpecimenFrame = specimen_frame(state0.points[ok], state0.left.real[ok], origin_px=origin_px,
                                                   x_direction_px=x_direction_px)
        self.settings = settings
        self._fit = StrainFit(self.frame.apply(state0.points), window=settings.strain_window) \
            if settings.strain_window else None

    def __call__(self, st: StereoState) -> StereoState:
        D = self.frame.rotate(st.displacement)
        measure = None
        if self._fit is not None:
            measure = measure_strain(self._fit(D), measure=self.settings.strain_measure)
        return dataclasses.replace(st, points=self.frame.apply(st.points), displacement=D, strain=None,
                                   measure=measure)
