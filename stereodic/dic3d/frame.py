"""A stereo DIC run reported in another frame, or with each state's rigid motion removed (`stereodic dic
--frame specimen --remove-rigid`).

The specimen's frame is the best-fit plane of state 0's points (`stereodic.gauge.frame.specimen_frame`:
origin at their centroid or a chosen pixel of the original left reference image, x along a chosen
direction of that image, z towards the cameras). Every state's points and displacements are turned
into it, and its strains refitted on the reference shape in that frame (`stereodic.strain.StrainFit`:
e1 is the specimen's x projected on the local tangent plane), in the run's strain measure. With the
rigid motion removed, each state also carries its deformation-only displacement: the rigid motion that
best carries the reference points onto the state's (`stereodic.gauge.frame.rigid_motion`) taken back
out; the full displacement stays.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from stereodic.dic3d.stereo import StereoSettings, StereoState
from stereodic.gauge.frame import SpecimenFrame, rigid_motion, specimen_frame
from stereodic.strain import StrainFit
from stereodic.strain_measures import measure_strain


class ReportingFrame:
    """Turns a run's states (rig frame) into the reporting frame: call it with a StereoState for the same
    state in the specimen's frame (`strain` None, `measure` refitted) and/or with its `deformation`.

    Parameters
    ----------
    state0 : StereoState
        The reference state (rig frame), whose points and left original-image positions define the frame.
    settings : StereoSettings
        The run's settings (strain window and measure).
    specimen : bool
        Report in the specimen's frame (else the rig's).
    remove_rigid : bool
        Give each state's deformation-only displacement.
    origin_px, x_direction_px
        As `stereodic.gauge.frame.specimen_frame` (pixels of the original left reference image).
    """

    def __init__(self, state0: StereoState, settings: StereoSettings, *, specimen: bool = True,
                 remove_rigid: bool = False, origin_px=None, x_direction_px=(1.0, 0.0)):
        self.frame: SpecimenFrame | None = None
        if specimen:
            ok = state0.converged & np.isfinite(state0.points).all(-1)
            self.frame = specimen_frame(state0.points[ok], state0.left.real[ok], origin_px=origin_px,
                                        x_direction_px=x_direction_px)
        self.settings, self.remove_rigid = settings, remove_rigid
        self._P0 = self._points(state0.points)
        self._fit = StrainFit(self._P0, window=settings.strain_window) if specimen and settings.strain_window \
            else None

    def _points(self, P: np.ndarray) -> np.ndarray:
        return P if self.frame is None else self.frame.apply(P)

    def record(self) -> dict:
        """The frame as the outputs record it."""
        base = {"frame": "rig"} if self.frame is None else self.frame.record()
        return {**base, "rigid_motion_removed": self.remove_rigid}

    def __call__(self, st: StereoState) -> StereoState:
        P = self._points(st.points)
        D = st.displacement if self.frame is None else self.frame.rotate(st.displacement)
        measure = st.measure
        if self._fit is not None:
            measure = measure_strain(self._fit(D), measure=self.settings.strain_measure)
        deformation = None
        if self.remove_rigid:
            R, t = rigid_motion(self._P0, P)
            deformation = (P - t) @ R - self._P0        # R^T (P - t) less the reference
        return dataclasses.replace(st, points=P, displacement=D, strain=None if self.frame else st.strain,
                                   measure=measure, deformation=deformation)
