"""Rectifying stereo image pairs with a rig: each camera's intensity matrix, then its IMM, onto the common
virtual sensor; and an overlay picture with epipolar rows to check the result by eye.

In the rectified pair a scene point lies on the same row of both images (exactly for central lenses;
for non-central ones the EVM says how far off, see `stereodic.triangulate`).
"""

from __future__ import annotations

import cv2
import numpy as np

from stereodic.rig import Rig
from stereodic.undistort import undistort_image


def rectify_pair(rig: Rig, left: np.ndarray, right: np.ndarray, intensity: bool = True,
                 fixed_point: bool = False, where: tuple = ("left", "right"), exact: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The rectified (virtual) images of a real image pair (8/16-bit, each its camera's size): same dtype,
    (Hv, Wv), blank pixels 0. intensity: apply each camera's intensity matrix if the rig has one;
    fixed_point: OpenCV's 1/32-pixel maps instead of exact float maps; where: the images' names for
    error messages; exact: float32 images, the interpolated grey levels not rounded to the input's integer
    type (for DIC: the rounding adds noise to every match)."""
    out = []
    for side, image, name in zip(("left", "right"), (left, right), where):
        cam = rig.camera(side)
        out.append(undistort_image(image, cam.imm, cam.im if intensity else None, fixed_point, where=name,
                                   exact=exact))
    return out[0], out[1]


def epipolar_overlay(left: np.ndarray, right: np.ndarray, every: int = 32) -> np.ndarray:
    """(Hv, 2 Wv, 3) uint8 BGR picture: the two rectified images side by side (scaled to 8 bits), with a
    coloured line on every `every`-th row across both: a feature must sit on the same line in both."""
    def to8(img):
        img = img.astype(np.float32)
        top = float(img.max()) or 1.0
        return np.clip(img * (255.0 / top), 0, 255).astype(np.uint8)

    pair = cv2.cvtColor(np.hstack([to8(left), to8(right)]), cv2.COLOR_GRAY2BGR)
    colours = ((0, 0, 255), (0, 200, 0), (255, 80, 0), (0, 200, 255))
    for k, r in enumerate(range(every // 2, pair.shape[0], every)):
        pair[r, :] = colours[k % len(colours)]
    pair[:, left.shape[1]] = (255, 255, 255)
    return pair
