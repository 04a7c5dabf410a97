"""Strain measures (stereodic.strain.measures) of homogeneous deformations, against closed forms computed
independently with scipy's matrix functions: E = (C - I)/2, (I - C^-1)/2 (= R^T (I - B^-1)/2 R),
ln U = logm(C)/2, U - I = sqrtm(C) - I, their eigenvalues and the von Mises equivalent."""

import numpy as np
import pytest
from scipy import linalg

from stereodic.strain.fit import strain_2d, strain_3d
from stereodic.strain.measures import MEASURES, measure_strain

F = np.array([[1.12, 0.07], [-0.15, 0.93]])        # stretch, shear and a rotation of about 8 degrees


def _closed_form(F, measure):
    C = F.T @ F
    U = linalg.sqrtm(C).real
    return {"green-lagrange": 0.5 * (C - np.eye(2)), "euler-almansi": 0.5 * (np.eye(2) - np.linalg.inv(C)),
            "log": 0.5 * linalg.logm(C).real, "engineering": U - np.eye(2)}[measure]


def _field(F, n=9, step=3.0):
    xs = np.arange(n) * step
    X, Y = np.meshgrid(xs, xs)
    u = (F[0, 0] - 1) * X + F[0, 1] * Y
    v = F[1, 0] * X + (F[1, 1] - 1) * Y
    return xs, u, v


@pytest.mark.parametrize("measure", MEASURES)
def test_homogeneous_2d(measure):
    xs, u, v = _field(F)
    m = measure_strain(strain_2d(xs, xs, u, v, window=5), measure=measure)
    E = _closed_form(F, measure)
    c = (4, 4)
    assert m.valid[c]
    assert m.exx[c] == pytest.approx(E[0, 0], abs=1e-12) and m.eyy[c] == pytest.approx(E[1, 1], abs=1e-12)
    assert m.exy[c] == pytest.approx(E[0, 1], abs=1e-12)
    w, vecs = np.linalg.eigh(E)
    assert (m.major[c], m.minor[c]) == pytest.approx((w[1], w[0]), abs=1e-12)
    major = vecs[:, 1]
    angle = np.degrees(np.arctan2(major[1], major[0]))
    angle = (angle + 90) % 180 - 90
    assert m.angle_deg[c] == pytest.approx(angle, abs=1e-9) or abs(abs(m.angle_deg[c] - angle) - 180) < 1e-9
    e3 = -(w[0] + w[1])
    assert m.von_mises[c] == pytest.approx(np.sqrt(2 / 3 * (w @ w + e3 * e3)), abs=1e-12)
    assert np.isnan(m.exx[0, 0]) and not m.valid[0, 0]          # the window needs its neighbours


def test_green_lagrange_is_the_fit_itself_and_euler_almansi_the_rotated_spatial_tensor():
    xs, u, v = _field(F)
    s = strain_2d(xs, xs, u, v, window=5)
    gl = measure_strain(s)
    assert np.array_equal(gl.exx, s.exx, equal_nan=True) and np.array_equal(gl.exy, s.exy, equal_nan=True)
    ea = measure_strain(s, measure="euler-almansi")
    R, _ = linalg.polar(F)                                      # F = R U
    e_spatial = 0.5 * (np.eye(2) - np.linalg.inv(F @ F.T))      # (I - B^-1) / 2
    rotated = R.T @ e_spatial @ R
    assert (ea.exx[4, 4], ea.eyy[4, 4], ea.exy[4, 4]) == pytest.approx((rotated[0, 0], rotated[1, 1], rotated[0, 1]),
                                                                       abs=1e-12)


def test_uniaxial_incompressible_log_strain():
    stretch = 1.3
    Fu = np.diag([stretch, 1 / np.sqrt(stretch)])
    xs, u, v = _field(Fu)
    m = measure_strain(strain_2d(xs, xs, u, v, window=5), measure="log")
    assert m.major[4, 4] == pytest.approx(np.log(stretch), abs=1e-12)
    assert m.von_mises[4, 4] == pytest.approx(np.log(stretch), abs=1e-12)   # e_vm = e1 in uniaxial tension
    assert m.angle_deg[4, 4] == pytest.approx(0.0, abs=1e-9)


def test_on_a_tilted_surface_3d():
    """The same deformation on a plane tilted 35 degrees about y: the tangent-frame measures equal the
    2-D closed forms."""
    xs, u, v = _field(F)
    X, Y = np.meshgrid(xs, xs)
    Q = linalg.expm(np.array([[0, 0, 1], [0, 0, 0], [-1, 0, 0]]) * np.radians(35))
    P = np.stack([X, Y, np.zeros_like(X)], -1) @ Q.T
    D = np.stack([u, v, np.zeros_like(u)], -1) @ Q.T
    s = strain_3d(P, D, window=5)
    for measure in MEASURES:
        m = measure_strain(s, measure=measure)
        E = _closed_form(F, measure)
        assert (m.exx[4, 4], m.eyy[4, 4], m.exy[4, 4]) == pytest.approx((E[0, 0], E[1, 1], E[0, 1]), abs=1e-10)


def test_unknown_measure():
    xs, u, v = _field(F)
    with pytest.raises(ValueError, match="hencky"):
        measure_strain(strain_2d(xs, xs, u, v, window=5), measure="hencky")
