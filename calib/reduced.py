"""The reduced-dimensional PRVM (the seed's consumer-camera mode): one stage position, six photos.

With the display roughly perpendicular to the optical axis, the decoded display point (c, r) of every
camera pixel maps the camera to the display plane. A perfect camera would map that plane to the image by a
homography; the best-fitting homography H (display px -> image px) defines the undistorted image, and
D(u, v) = H(c(u, v), r(u, v)) - (u, v) is each pixel's distortion. The undistortion map gives, for every
output pixel q, the camera pixel p with p + D(p) = q (solved by fixed-point iteration), ready for
`cv2.remap`. Exact for any lens on the calibrated plane; for other depths it holds for central lenses.

File: an `.npz` with map_x, map_y (H, W) float32 (source camera pixel of each output pixel, NaN where
unknown), valid (H, W) bool, homography (3, 3) float64 and meta (JSON, format "stereodic.undistort/1").
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import cv2
import numpy as np

from calib import __version__
from calib.atomic import write_npz
from calib.errors import InputError
from calib.npzfile import read_npz
from calib.regularise import Adaptive, Smoother, smooth_fields

FORMAT = "stereodic.undistort/1"
ITERATIONS = 20


@dataclass
class UndistortMap:
    """map_x, map_y: (H, W) float32 source camera pixel of each output pixel; valid: (H, W) bool;
    homography: (3, 3) display pixel -> output pixel; meta: JSON metadata."""

    map_x: np.ndarray
    map_y: np.ndarray
    valid: np.ndarray
    homography: np.ndarray
    meta: dict = field(default_factory=dict)

    def apply(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """The undistorted image (same dtype; 0 where the map is unknown)."""
        mx = np.where(self.valid, self.map_x, -1).astype(np.float32)
        my = np.where(self.valid, self.map_y, -1).astype(np.float32)
        return cv2.remap(image, mx, my, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def save(self, path: str | os.PathLike) -> None:
        meta = {"format": FORMAT, "software": f"stereodic {__version__}", **self.meta}
        write_npz(path, map_x=self.map_x.astype(np.float32), map_y=self.map_y.astype(np.float32),
                  valid=self.valid, homography=self.homography, meta=np.array(json.dumps(meta)))


def load_undistort_map(path: str | os.PathLike) -> UndistortMap:
    """Read an undistortion map; InputError naming the file if it is not one."""
    meta, a = read_npz(path, FORMAT, "undistortion map")
    missing = [k for k in ("map_x", "map_y", "valid", "homography") if k not in a]
    if missing:
        raise InputError(path, f"not an undistortion map: lacks {', '.join(missing)}")
    return UndistortMap(a["map_x"], a["map_y"], a["valid"], a["homography"], meta)


def fit_homography(coord: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Least-squares homography display px (c, r) -> camera px (u, v) over the valid pixels."""
    h, w = valid.shape
    step = max(1, int(np.sqrt(valid.sum() / 50000)))
    v, u = np.mgrid[0:h:step, 0:w:step]
    sel = valid[::step, ::step]
    src = np.stack([coord[0][::step, ::step][sel], coord[1][::step, ::step][sel]], axis=1)
    dst = np.stack([u[sel], v[sel]], axis=1).astype(np.float64)
    hom, _ = cv2.findHomography(src, dst, 0)
    if hom is None:
        raise ValueError("the decoded display points do not determine a homography")
    return hom


def undistort_map(coord: np.ndarray, valid: np.ndarray,
                  smoother: Smoother | Adaptive | None = Smoother()) -> UndistortMap:
    """The undistortion map of one decoded stage position.

    coord: (2, H, W) display pixels (c, r) seen by each camera pixel; valid: (H, W) bool. The distortion
    field is regularised with `smoother` (None: used as decoded).
    """
    h, w = valid.shape
    hom = fit_homography(coord, valid)
    c, r = coord
    den = hom[2, 0] * c + hom[2, 1] * r + hom[2, 2]
    ideal_u = (hom[0, 0] * c + hom[0, 1] * r + hom[0, 2]) / den
    ideal_v = (hom[1, 0] * c + hom[1, 1] * r + hom[1, 2]) / den
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    disp = np.stack([ideal_u - u, ideal_v - v])
    if smoother is not None:
        disp = smooth_fields(disp, valid, smoother).fields
    fill = np.where(valid[None], disp, 0.0).astype(np.float32)
    qx, qy = u.astype(np.float32), v.astype(np.float32)
    px, py = qx.copy(), qy.copy()
    for _ in range(ITERATIONS):                       # p = q - D(p)
        dx = cv2.remap(fill[0], px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        dy = cv2.remap(fill[1], px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        px, py = qx - dx, qy - dy
    inside = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    src_ok = cv2.remap(valid.astype(np.float32), px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT) > 0.999
    ok = inside & src_ok
    return UndistortMap(np.where(ok, px, np.nan).astype(np.float32), np.where(ok, py, np.nan).astype(np.float32),
                        ok, hom)
