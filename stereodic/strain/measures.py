"""Strain measures of a fitted deformation: Green-Lagrange, Euler-Almansi, logarithmic (Hencky) and
engineering (Biot), their principal values and direction, and the von Mises equivalent strain.

`stereodic.strain.fit` fits, around every point, the deformed tangent vectors g_a = e_a + dD/ds_a of the
local frame (e1, e2) (the surface's tangent plane, or the image plane in 2-D). Their dot products give the
right Cauchy-Green tensor C = F^T F = [[g1.g1, g1.g2], [g1.g2, g2.g2]], with eigenvalues lambda_i^2 (the
principal stretches squared) and eigenvectors N_i in the frame (e1, e2). Every measure is
E = sum_i f(lambda_i) N_i N_i^T, components in the frame (e1, e2):
- green-lagrange: f = (lambda^2 - 1) / 2, i.e. E = (C - I) / 2 (the default; exactly `Strain.exx, eyy, exy`);
- euler-almansi: f = (1 - lambda^-2) / 2, i.e. (I - C^-1) / 2: the spatial tensor (I - B^-1) / 2, B = F F^T,
  rotated back by the rotation R of F = R U, so that its components are on the same material axes;
- log (Hencky, true strain): f = ln(lambda), i.e. ln U;
- engineering (Biot, nominal strain): f = lambda - 1, i.e. U - I (the change of length per unit length
  along the principal directions).
Principal strains: major = f(lambda_1) >= minor = f(lambda_2); angle: from e1 to the major direction,
degrees in (-90, 90]. Von Mises equivalent strain, with the out-of-plane principal strain taken from
incompressibility, e3 = -(e1 + e2): e_vm = sqrt(2/3 (e1^2 + e2^2 + e3^2)) (uniaxial tension of an
incompressible material gives e_vm = e1; exact for the log measure, a convention for the others).
All dimensionless; NaN where the strain is not valid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.strain.fit import Strain

MEASURES = ("green-lagrange", "euler-almansi", "log", "engineering")
_STRETCH = {  # f of the squared principal stretch
    "green-lagrange": lambda c: 0.5 * (c - 1.0),
    "euler-almansi": lambda c: 0.5 * (1.0 - 1.0 / c),
    "log": lambda c: 0.5 * np.log(c),
    "engineering": lambda c: np.sqrt(c) - 1.0,
}
FIELDS = ("exx", "eyy", "exy", "major", "minor", "angle_deg", "von_mises")


@dataclass
class StrainMeasure:
    """One measure on a grid, (ny, nx) arrays: tensor components exx, eyy, exy in the frame (e1, e2);
    principal strains major >= minor, angle_deg (e1 to the major direction, degrees); von_mises; valid
    (bool). NaN exactly where valid is False."""

    measure: str
    exx: np.ndarray
    eyy: np.ndarray
    exy: np.ndarray
    major: np.ndarray
    minor: np.ndarray
    angle_deg: np.ndarray
    von_mises: np.ndarray
    valid: np.ndarray


def cauchy_green(strain: Strain) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C11, C22, C12) of the right Cauchy-Green tensor in the frame (e1, e2) of a fitted strain."""
    e2 = np.cross(strain.normal, strain.e1)
    g1 = strain.e1 + strain.grad[..., 0]
    g2 = e2 + strain.grad[..., 1]
    return np.sum(g1 * g1, -1), np.sum(g2 * g2, -1), np.sum(g1 * g2, -1)


def measure_strain(strain: Strain, *, measure: str = "green-lagrange") -> StrainMeasure:
    """A strain measure, its principal strains and von Mises equivalent, of a fitted strain.

    Parameters
    ----------
    strain : Strain
        The fit (`strain_3d`, `strain_2d`), (ny, nx).
    measure : str
        One of MEASURES: "green-lagrange", "euler-almansi", "log", "engineering" (module docstring).

    Returns
    -------
    measure : StrainMeasure
        ``exx``, ``eyy``, ``exy`` (ny, nx) in the fit's frame (e1, e2), principal ``major`` >= ``minor``,
        ``angle_deg`` (e1 to the major direction, degrees), ``von_mises``; dimensionless, NaN exactly
        where not ``valid``. ValueError for an unknown measure.
    """
    if measure not in MEASURES:
        raise ValueError(f"strain measure must be one of {MEASURES}, got {measure!r}")
    ok = strain.valid
    c11, c22, c12 = cauchy_green(strain)
    mean, half = 0.5 * (c11 + c22), np.hypot(0.5 * (c11 - c22), c12)
    lam1, lam2 = mean + half, mean - half                       # squared principal stretches
    theta = 0.5 * np.arctan2(2.0 * c12, c11 - c22)               # e1 to the major direction
    with np.errstate(invalid="ignore", divide="ignore"):
        f1, f2 = _STRETCH[measure](lam1), _STRETCH[measure](lam2)
    if measure == "green-lagrange":
        exx, eyy, exy = strain.exx, strain.eyy, strain.exy
    else:
        c, s = np.cos(theta), np.sin(theta)
        exx, eyy, exy = f1 * c * c + f2 * s * s, f1 * s * s + f2 * c * c, (f1 - f2) * s * c
    e3 = -(f1 + f2)
    vm = np.sqrt(2.0 / 3.0 * (f1 * f1 + f2 * f2 + e3 * e3))
    angle = np.degrees(theta)
    angle = np.where(angle <= -90.0, angle + 180.0, angle)
    nan = lambda a: np.where(ok, a, np.nan)  # noqa: E731
    return StrainMeasure(measure, nan(exx), nan(eyy), nan(exy), nan(f1), nan(f2), nan(angle), nan(vm), ok)
