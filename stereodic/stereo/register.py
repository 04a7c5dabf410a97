"""Registration of a separately calibrated camera into a common WCS (seed, "Virtual stereo camera": the
cameras "can also be calibrated separately ... there should be additional registration").

What it uses: two PRVMs of the same physical camera (same pixels) - `own`, its careful calibration in its
own display WCS (facing the display straight), and `common`, a calibration in the common WCS, e.g. from
a registration dataset in which the display (at two or more stage positions) is seen by both cameras of
the rig. The same pixel's ray is one physical line in both frames, so the rigid transform
X_common = R X_own + t is fitted to all pixels valid in both:
- R from the directions alone (Kabsch / Wahba on the unit vectors: R d_own ~ d_common);
- t from the lines: minimise sum |(I - d d^T)(R o_own + t - o_common)|^2 over t, a 3x3 linear system
  (d, o_common the common ray's direction and point); exact for any lens, central or not;
with iteratively re-weighted (Cauchy) pixels so that a few bad rays do not pull it. The common
calibration may be coarse (fewer frames, noisier): only the 6 numbers of the transform come from it,
averaged over all pixels; the rays themselves keep the quality of the own calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.errors import InputError
from calib.prvm_file import PRVM
from stereodic.virtual.camera import fit_optical_centre


@dataclass
class Registration:
    """X_common = rotation @ X_own + translation_mm (WCS mm). rms_mm: RMS distance, at the working
    distance, between the transformed own rays and the common rays (pixels used: `pixels`)."""

    rotation: np.ndarray
    translation_mm: np.ndarray
    rms_mm: float
    pixels: int


def estimate_registration(own: PRVM, common: PRVM, *, max_rays: int = 100_000, iterations: int = 8,
                          where=None) -> Registration:
    """The rigid transform from one camera's own WCS into a common WCS (module docstring).

    Parameters
    ----------
    own : PRVM
        The camera's careful calibration, in its own WCS (mm).
    common : PRVM
        The same camera's (same pixels) calibration in the common WCS.
    max_rays : int
        The fit uses an even sub-grid of at most this many pixels valid in both.
    iterations : int
        Re-weighting iterations.
    where : str or path, optional
        The name of `common` (a file) in messages.

    Returns
    -------
    registration : Registration
        X_common = rotation (3, 3) @ X_own + translation_mm (3,), mm; the RMS distance (mm) between the
        transformed and common rays and the number of pixels used. InputError naming `where` if the two
        are not the same camera (sizes differ) or share fewer than 100 valid pixels.
    """
    if (own.width, own.height) != (common.width, common.height):
        raise InputError(where, f"is {common.width}x{common.height} but the camera is {own.width}x{own.height}: "
                                f"not the same camera")
    both = own.valid & common.valid & np.isfinite(own.direction).all(-1) & np.isfinite(common.direction).all(-1)
    if both.sum() < 100:
        raise InputError(where, f"only {int(both.sum())} pixels are valid in both calibrations (need >= 100)")
    step = max(1, int(np.ceil(np.sqrt(both.sum() / max_rays))))
    sel = both[::step, ::step]
    o_a, d_a = own.origin[::step, ::step][sel], own.direction[::step, ::step][sel]
    o_b, d_b = common.origin[::step, ::step][sel], common.direction[::step, ::step][sel]
    w = np.ones(len(o_a))
    eye = np.eye(3)
    for _ in range(iterations):
        u, _, vt = np.linalg.svd(np.einsum("n,ni,nj->ij", w, d_b, d_a))
        rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
        proj = eye - d_b[:, :, None] * d_b[:, None, :]                       # (N, 3, 3)
        a = np.einsum("n,nij->ij", w, proj)
        b = np.einsum("n,nij,nj->i", w, proj, o_b - o_a @ rot.T)
        t = np.linalg.solve(a, b)
        r = _line_distance(o_a @ rot.T + t, d_a @ rot.T, o_b, d_b, _depth(common))
        w = 1.0 / (1.0 + (r / max(3.0 * float(np.median(r)), 1e-9)) ** 2)
    return Registration(rot, t, float(np.sqrt(np.mean(r ** 2))), int(len(r)))


def _depth(prvm: PRVM) -> float:
    """A typical distance (mm) from the reference plane back to the camera along the rays: the registration
    residual is measured there and on the reference plane."""
    centre, _ = fit_optical_centre(prvm)
    return float(np.median(np.linalg.norm(prvm.origin[prvm.valid] - centre, axis=-1)))


def _line_distance(o1, d1, o2, d2, depth: float) -> np.ndarray:
    """Mean distance between corresponding lines at the plane points o2 and o2 - depth * d2."""
    out = 0.0
    for s in (0.0, -depth):
        p = o2 + s * d2 - o1
        out = out + np.linalg.norm(p - np.einsum("ni,ni->n", p, d1)[:, None] * d1, axis=-1) / 2
    return out


def apply_registration(prvm: PRVM, reg: Registration, wcs: str) -> PRVM:
    """The PRVM's rays in the common WCS (origins on its plane z = reference_z_mm there), with meta
    `wcs` = `wcs` and `registration` (the transform and its RMS)."""
    meta = {**prvm.meta, "wcs": wcs,
            "registration": {"rotation": reg.rotation.tolist(), "translation_mm": reg.translation_mm.tolist(),
                             "rms_mm": reg.rms_mm, "pixels": reg.pixels}}
    try:
        return prvm.transformed(reg.rotation, reg.translation_mm, meta)
    except ValueError:
        raise InputError(None, "after registration some rays point towards -z: the common WCS must have the "
                               "cameras looking along +z") from None
