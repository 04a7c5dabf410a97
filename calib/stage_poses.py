"""The display's actual pose at each stage position, estimated from the fringe data (below the stage floor).

A stage moves the display along its axis with small errors: the travel (a few micrometres), the
carriage's tilt (pitch, yaw; hundredths of a degree) and its straightness (lateral run-out). Rays fitted
to the nominal positions inherit those errors (the "stage floor"). With 3 or more positions each
pixel's points over-determine its line, and the poses can be refined together with the rays
(`calib.poses`, starting from the nominal poses, with `calib.poses.staged_basis`): pose 0 stays the WCS
(DESIGN.md: the display at the first stage position), and the affine trend of the travel (scale and
direction: what a wrong stage axis or encoder scale does) stays the nominal one - parallel planes
cannot tell it, so it is fixed from the stage's own numbers. What is estimated per position: its tilt
and turn (3 angles) and its z and lateral errors off that trend - as far as the data tell them. They do
not tell all of it: for a (nearly) central camera, turning each display about the camera's centre by an
angle that grows as 1/distance - 1/distance at position 0 keeps every pixel's points on a line (each
point moves by an amount linear in its distance along the ray), so one combination of the positions'
angles per axis is (nearly) free as well, and what it changes is the rays' directions. So the
parameters are taken along the eigenvectors of their information matrix (scaled by the stage's own
tolerances, `TOLERANCE_DEG`, `TOLERANCE_UM`), and a direction is estimated only where the data fix it
better than the stage's tolerance; the others stay nominal.

The refined poses are used when they lower the residual significantly: by more than a chi-square with
as many degrees of freedom as free parameters would by chance (its mean plus `SIGNIFICANCE` standard
deviations), in units of the refined fit's residual variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.capture import Capture
from calib.decode import DecodedPosition
from calib.positions import point_weights
from calib.poses import PoseFit, information, log_so3, pose_sample, refine_poses, staged_basis

SIGNIFICANCE = 5.0
# a precision stage's own accuracy per position (pitch, yaw and roll; travel and straightness): the
# scale against which a direction of the pose errors counts as observable
TOLERANCE_DEG = 0.01
TOLERANCE_UM = 5.0


@dataclass
class StageFit:
    """The stage's estimated poses. rotation (M, 3, 3), translation (M, 3): each position's display in
    the WCS (X = R q + t); nominal (M, 3): the nominal translations; fit: the `calib.poses.PoseFit`;
    used: whether the refined poses lower the residual significantly (and are used for the rays);
    z_mm: the nominal positions; free: the number of free parameters."""

    rotation: np.ndarray
    translation: np.ndarray
    nominal: np.ndarray
    fit: PoseFit
    used: bool
    z_mm: list[float]
    free: int

    @property
    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.rotation, self.translation

    def errors(self) -> list[dict]:
        """Per position, the estimated stage error at the centre of the display area the camera sees
        (`PoseFit.centre`): z and lateral (um) from the nominal position, tilt about the display's x
        and y axes and turn about its normal (degrees, rotation vector), each with its 1-sigma."""
        out = []
        for k, z in enumerate(self.z_mm):
            centre = self.fit.centre[k]
            q = np.linalg.solve(self.rotation[k], centre - self.translation[k])      # display-frame point
            offset = centre - (q + self.nominal[k])
            angle = np.degrees(log_so3(self.rotation[k]))
            sd = np.sqrt(np.maximum(np.diag(self.fit.covariance[k]), 0))
            out.append({"z_mm": z, "z_error_um": 1000 * offset[2], "lateral_um": (1000 * offset[:2]).tolist(),
                        "tilt_deg": angle.tolist(), "sd_z_um": 1000 * sd[5], "sd_lateral_um": (1000 * sd[3:5]).tolist(),
                        "sd_tilt_deg": np.degrees(sd[:3]).tolist(), "centre_mm": centre.tolist(),
                        "rms_um": 1000 * float(self.fit.rms_mm[k])})
        return out

    def to_json(self) -> dict:
        """`meta.stage_poses` of the PRVM: whether the refined poses were used, the residual before and
        after (weighted sums of squares), and the errors per position (`errors`)."""
        return {"used": self.used, "cost_nominal": self.fit.cost_start, "cost_refined": self.fit.cost,
                "free_parameters": self.free,
                "positions": self.errors(),
                "gauge": "position 0 is the WCS; the linear trend of the travel is the nominal one"}


def estimate_stage(capture: Capture, positions: list[DecodedPosition]) -> StageFit:
    """Refine the display's pose at each of 3 or more stage positions (module docstring)."""
    z = np.array([p.z_mm for p in positions])
    ax, ay, az = capture.stage_axis
    nominal = np.stack([z * ax / az, z * ay / az, z], axis=1)
    sample = pose_sample([p.coord for p in positions], [point_weights(p) for p in positions],
                         capture.display.pitch_mm)
    rotation = np.broadcast_to(np.eye(3), (len(z), 3, 3)).copy()
    full = staged_basis(z)
    # the residual's scale from a fit of every parameter (its poorly fixed ones do not change the cost)
    sigma2 = refine_poses(sample, rotation, nominal, basis=full).sigma ** 2
    scale = np.where(np.abs(full[np.arange(full.shape[0]) % 6 < 3]).sum(axis=0) > 0,
                     np.radians(TOLERANCE_DEG), TOLERANCE_UM / 1000)
    info = information(sample, rotation, nominal, basis=full) * np.outer(scale, scale)
    lam, vec = np.linalg.eigh(info)
    observable = lam > sigma2                     # 1-sigma along the direction below one tolerance
    basis = full @ (scale[:, None] * vec[:, observable])
    fit = refine_poses(sample, rotation, nominal, basis=basis)
    n = basis.shape[1]
    drop = (fit.cost_start - fit.cost) / fit.sigma ** 2
    used = n > 0 and drop > n + SIGNIFICANCE * np.sqrt(2 * n)
    return StageFit(fit.rotation, fit.translation, nominal, fit, bool(used), [float(v) for v in z], n)
