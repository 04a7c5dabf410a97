"""Saved DIC results with an analytic truth, for the gauge tests: a plate tilted 10 degrees about the
rig's y axis, seen by a pinhole left camera, through a reference state, a rigid motion, tensions with
Poisson contraction (plus the same rigid motion) and a bulge; written as `stereodic dic` writes dic.npz
(points, displacements and state 0's original left image positions), with a little noise on the
points. The truth comes from the formulas here, never from the code under test."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from calib.npz_stream import write_stacked_npz

F_PX, CX, CY = 2400.0, 320.0, 256.0      # the left camera: pinhole at the rig's origin, looking along +z
CENTRE = np.array([4.0, -2.0, 300.0])    # the plate's centre, mm
TILT = np.radians(10.0)
E1 = np.array([np.cos(TILT), 0.0, np.sin(TILT)])   # the plate's edges, rig frame
E2 = np.array([0.0, 1.0, 0.0])
N = np.cross(E1, E2)                                # away from the camera
POISSON = 0.3


def _rotation(axis, deg):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


RIGID = (_rotation((0.3, 1.0, 0.2), 0.8), np.array([0.25, -0.15, 0.4]))


@dataclass(frozen=True)
class State:
    """Engineering strain along e1 (Poisson along e2), rigid motion on or off, bulge height (mm, towards
    the camera) and radius (mm) at (a, b) = BULGE_AT."""

    strain: float = 0.0
    rigid: bool = False
    bulge_mm: float = 0.0


BULGE_AT, BULGE_RADIUS = (5.0, 1.0), 4.0
STATES = (State(), State(rigid=True), State(0.005, True), State(0.01, True), State(bulge_mm=0.2))


def bulge(a, b, height):
    """The bulge's height (mm, towards the camera) at material point (a, b) mm."""
    return height * np.exp(-((a - BULGE_AT[0]) ** 2 + (b - BULGE_AT[1]) ** 2) / BULGE_RADIUS ** 2)


def place(a, b, st: State) -> np.ndarray:
    """(..., 3) the rig-frame position of material point (a, b) (mm from the plate's centre) in state st."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    local = ((1 + st.strain) * a)[..., None] * E1 + ((1 - POISSON * st.strain) * b)[..., None] * E2 \
        - bulge(a, b, st.bulge_mm)[..., None] * N
    if st.rigid:
        local = local @ RIGID[0].T + RIGID[1]
    return CENTRE + local


def project(P: np.ndarray) -> np.ndarray:
    """(..., 2) left image pixels of rig points."""
    return np.stack([CX + F_PX * P[..., 0] / P[..., 2], CY + F_PX * P[..., 1] / P[..., 2]], -1)


def material_at(px) -> np.ndarray:
    """(N, 2) material (a, b) of the reference plate seen at left image pixels (N, 2): ray meets plane."""
    px = np.atleast_2d(np.asarray(px, float))
    rays = np.column_stack([(px[:, 0] - CX) / F_PX, (px[:, 1] - CY) / F_PX, np.ones(len(px))])
    s = (CENTRE @ N) / (rays @ N)
    P = rays * s[:, None] - CENTRE
    return np.column_stack([P @ E1, P @ E2])


def grid_ab(nx: int = 81, ny: int = 41, half=(20.0, 10.0)):
    a = np.linspace(-half[0], half[0], nx)
    b = np.linspace(-half[1], half[1], ny)
    return np.meshgrid(a, b)


def write_tension_result(path, *, noise_mm: float = 1e-4, window: int = 7, seed: int = 0, nx: int = 81,
                         ny: int = 41, states=STATES) -> None:
    """dic.npz of the plate (module docstring) at `path`: grid 0.5 mm apart on the plate."""
    A, B = grid_ab(nx, ny)
    rng = np.random.default_rng(seed)
    P0 = place(A, B, states[0])
    pts = [place(A, B, st) + rng.normal(0, noise_mm, A.shape + (3,)) for st in states]
    pts[0] = P0 + rng.normal(0, noise_mm, A.shape + (3,))
    px = [project(p) for p in pts]
    meta = {"format": "stereodic.dic/1", "settings": {"strain_window": window, "strain_measure": "green-lagrange"},
            "state_labels": [f"state {k}" for k in range(len(states))], "world_from_rig": np.eye(4).tolist()}
    arrays = {"meta": np.array(json.dumps(meta)), "x": np.arange(nx) * 5.0, "y": np.arange(ny) * 5.0,
              "active": np.ones((ny, nx), bool)}
    stacked = {"state": lambda: (np.array(k) for k in range(len(states))),
               "points": lambda: iter(pts),
               "displacement": lambda: (p - pts[0] for p in pts),
               "converged": lambda: (np.ones((ny, nx), bool) for _ in states),
               "left_x0": lambda: (p[..., 0] for p in px),
               "left_y0": lambda: (p[..., 1] for p in px)}
    write_stacked_npz(path, arrays, stacked, len(states))


def write_image_result(path, *, strains=(0.0025, 0.005, 0.01), step: int = 5, size=(200, 120)) -> None:
    """A dic2d NPZ of a uniaxial tension (engineering strain along x, Poisson along y, about the image
    centre) at each of `strains`, grid every `step` pixels."""
    xs, ys = np.arange(10, size[0] - 10, step, dtype=float), np.arange(10, size[1] - 10, step, dtype=float)
    X, Y = np.meshgrid(xs, ys)
    xc, yc = size[0] / 2, size[1] / 2
    meta = {"format": "stereodic.dic2d/1", "images": [f"img{k + 1}.png" for k in range(len(strains))],
            "strain_measure": None, "settings": {}}
    arrays = {"meta": np.array(json.dumps(meta)), "x": xs, "y": ys, "active": np.ones(X.shape, bool)}
    stacked = {"u": lambda: (e * (X - xc) for e in strains),
               "v": lambda: (-POISSON * e * (Y - yc) for e in strains)}
    write_stacked_npz(path, arrays, stacked, len(strains))
