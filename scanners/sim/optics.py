"""Exact ray optics: intersection with planes and refraction through plane-parallel glass (Snell's law).

Arrays of points and directions have shape (..., 3), float64, in any one Cartesian frame (mm).
"""

from __future__ import annotations

import numpy as np


def intersect_plane(origin: np.ndarray, direction: np.ndarray, point: np.ndarray,
                    normal: np.ndarray) -> np.ndarray:
    """Points (..., 3) where the lines origin + t*direction meet the plane through `point` with `normal`."""
    t = np.einsum("...i,i->...", np.asarray(point, float) - origin, normal) / np.einsum(
        "...i,i->...", direction, normal)
    return origin + t[..., None] * direction


def refract(direction: np.ndarray, normal: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Unit directions (..., 3) after crossing an interface from index n1 into index n2 (Snell's law).

    `direction`: unit incident directions; `normal`: unit normal of the interface oriented along the
    propagation (direction . normal > 0). Raises ValueError on total internal reflection.
    """
    cos_i = np.einsum("...i,i->...", direction, normal)
    eta = n1 / n2
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    if np.any(sin2_t > 1.0):
        raise ValueError("total internal reflection")
    cos_t = np.sqrt(1.0 - sin2_t)
    return eta * direction + (cos_t - eta * cos_i)[..., None] * normal


def through_slab(origin: np.ndarray, direction: np.ndarray, entry_point: np.ndarray, normal: np.ndarray,
                 thickness_mm: float, index: float) -> tuple[np.ndarray, np.ndarray]:
    """Trace rays through a plane-parallel glass plate in air.

    The plate's entry face passes through `entry_point` with unit `normal` pointing along the propagation
    (into the glass); its exit face is `thickness_mm` further along the normal. Returns the exit points
    (..., 3) on the exit face and the exit directions (..., 3) (parallel to the incident ones).
    """
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    if np.any(np.einsum("...i,i->...", direction, normal) <= 0):
        raise ValueError("rays must travel into the plate (direction . normal > 0)")
    p1 = intersect_plane(origin, direction, entry_point, normal)
    inside = refract(direction, normal, 1.0, index)
    p2 = intersect_plane(p1, inside, np.asarray(entry_point, float) + thickness_mm * normal, normal)
    return p2, refract(inside, normal, index, 1.0)


def rotation(axis: str, angle_rad: float) -> np.ndarray:
    """3x3 right-handed rotation matrix about the x, y or z axis."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m
