"""The PRVM file: `stereodic.prvm/1`, an `.npz` of per-pixel rays (DESIGN.md).

A ray is (origin, direction): origin is where the ray crosses the plane z = reference_z_mm (WCS, mm),
direction a unit vector with positive z, from the camera towards the scene. The simulator's `truth.npz`
uses the same keys, so a calibration and its truth load the same way.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from calib import __version__
from calib.atomic import write_npz
from calib.errors import InputError
from calib.npzfile import read_npz

FORMAT = "stereodic.prvm/1"
REQUIRED = ("origin", "direction", "valid")


@dataclass
class PRVM:
    """Per-pixel rays of one camera.

    origin: (H, W, 3) float64, WCS mm, on z = reference_z_mm. direction: (H, W, 3) float64 unit, z > 0.
    valid: (H, W) bool. residual_mm: (H, W) float32, RMS distance of the decoded points from the
    fitted line (NaN where only two planes were used). meta: the JSON metadata (format, camera, width,
    height, reference_z_mm, dataset, software version, ...). extra: further arrays kept in the file
    (uncertainty, intensity matrix, quality, ...).
    """

    origin: np.ndarray
    direction: np.ndarray
    valid: np.ndarray
    residual_mm: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def height(self) -> int:
        return self.valid.shape[0]

    @property
    def width(self) -> int:
        return self.valid.shape[1]

    @property
    def reference_z_mm(self) -> float:
        return float(self.meta.get("reference_z_mm", 0.0))

    def at_z(self, z_mm: float | np.ndarray) -> np.ndarray:
        """(H, W, 3) points where each ray crosses the plane z = z_mm (WCS mm)."""
        t = (np.asarray(z_mm, dtype=np.float64) - self.reference_z_mm) / self.direction[..., 2]
        return self.origin + t[..., None] * self.direction

    def transformed(self, rotation: np.ndarray, translation: np.ndarray, meta: dict | None = None) -> PRVM:
        """The same rays in another frame, X_new = rotation @ X + translation (mm), origins on its plane
        z = reference_z_mm; `meta` replaces the meta (default: kept). ValueError if a valid ray does not
        point towards +z there."""
        rotation = np.asarray(rotation, float)
        d = self.direction @ rotation.T
        if np.any(d[self.valid][:, 2] <= 0):
            raise ValueError("in the new frame some rays point towards -z")
        o = self.origin @ rotation.T + np.asarray(translation, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            o = o + ((self.reference_z_mm - o[..., 2]) / d[..., 2])[..., None] * d
        return PRVM(o, d, self.valid.copy(), self.residual_mm, dict(self.meta) if meta is None else meta,
                    dict(self.extra))

    def save(self, path: str | os.PathLike) -> None:
        """Write the `.npz` atomically."""
        meta = {"format": FORMAT, "width": self.width, "height": self.height,
                "reference_z_mm": self.reference_z_mm, "software": f"stereodic {__version__}", **self.meta}
        residual = self.residual_mm if self.residual_mm is not None else np.full(self.valid.shape, np.nan,
                                                                                np.float32)
        write_npz(path, origin=self.origin.astype(np.float64), direction=self.direction.astype(np.float64),
                  valid=self.valid.astype(bool), residual_mm=residual.astype(np.float32),
                  meta=np.array(json.dumps(meta)), **self.extra)


def load_prvm(path: str | os.PathLike) -> PRVM:
    """Read and check a stereodic.prvm/1 file.

    Parameters
    ----------
    path : path
        The file (``.npz``).

    Returns
    -------
    prvm : PRVM
        (H, W, 3) float64 ray origins (WCS mm, on z = reference_z_mm) and unit directions, (H, W) bool
        validity, and the optional per-pixel arrays and metadata. InputError naming the file if it is not
        a PRVM file.
    """
    meta, arrays = read_npz(path, FORMAT, "PRVM")
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        raise InputError(path, f"not a PRVM file: lacks {', '.join(missing)}")
    origin, direction, valid = arrays.pop("origin"), arrays.pop("direction"), arrays.pop("valid")
    h, w = valid.shape if valid.ndim == 2 else (0, 0)
    if valid.ndim != 2 or origin.shape != (h, w, 3) or direction.shape != (h, w, 3):
        raise InputError(path, f"array shapes disagree: origin {origin.shape}, direction {direction.shape}, "
                               f"valid {valid.shape}")
    residual = arrays.pop("residual_mm", None)
    return PRVM(origin.astype(np.float64), direction.astype(np.float64), valid.astype(bool), residual, meta,
                arrays)
