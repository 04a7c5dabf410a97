"""Raw Bayer cameras (the seed's "Color camera"): every photosite is a pixel with its own ray.

A Bayer sensor's photosites sit under red, green and blue filters in a 2 x 2 mosaic (`cameras.NAME.bayer`
in the manifest: "RGGB", "BGGR", "GRBG" or "GBRG", the colours of the top-left 2 x 2 block read row by
row). Each colour sees the display's white through its own filter, so each has its own response (gain,
and the display's response curve seen through that filter), and the lens bends each colour its own way
(lateral chromatic aberration), so neighbouring photosites of different colours have rays that differ by
more than their neighbourhood would suggest. So the mosaic is taken apart into its four sub-lattices
(one per position in the 2 x 2 block: the two greens are two sub-lattices), and each is

- decoded as a camera of its own (`calib.positions.decode_positions` on a view of the capture that reads
  only that sub-lattice): its own intensity matrix and display response, its own modulation thresholds;
- regularised as a smooth field of its own (`smooth_planes`), on its own lattice (a window of W camera
  pixels is W / 2 sub-lattice pixels).

The rays are fitted per photosite on the full mosaic. Images may be raw (one channel, written as the
sensor gave them) or, where a camera cannot output raw, colour images: each photosite then takes its own
colour's value from the colour image (the seed: "the Bayer image can also be decoded from the color
image").
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.capture import Capture, Frame
from calib.decode import DecodedPosition
from calib.errors import InputError
from calib.intensity import IntensityMatrix
from calib.positions import decode_positions
from calib.prvm import Lines
from calib.ray_field import AUTO, auto_smoother, smooth_plane

# sub-lattices: (row, column) offsets within the 2 x 2 block
OFFSETS = ((0, 0), (0, 1), (1, 0), (1, 1))


def colours(pattern: str) -> dict[tuple[int, int], str]:
    """The colour ("R", "G", "B") of each sub-lattice offset of a Bayer pattern ("RGGB", ...)."""
    return {off: pattern[2 * off[0] + off[1]] for off in OFFSETS}


def colour_map(pattern: str, height: int, width: int) -> np.ndarray:
    """(H, W) array of the colour letter of each photosite."""
    out = np.empty((height, width), "<U1")
    for (dy, dx), c in colours(pattern).items():
        out[dy::2, dx::2] = c
    return out


def read_mosaic(path: Path, pattern: str) -> np.ndarray:
    """The raw mosaic of an image file: a one-channel image as it is; a colour image (BGR, OpenCV's
    order) re-mosaicked, each photosite taking its own colour's channel."""
    if not Path(path).is_file():
        raise InputError(path, "image file is missing")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "not a readable image")
    if img.dtype not in (np.uint8, np.uint16):
        raise InputError(path, f"pixel type {img.dtype} is not supported (8- or 16-bit)")
    if img.ndim == 2:
        return img
    channel = {"B": 0, "G": 1, "R": 2}
    out = np.empty(img.shape[:2], img.dtype)
    for (dy, dx), c in colours(pattern).items():
        out[dy::2, dx::2] = img[dy::2, dx::2, channel[c]]
    return out


@dataclass
class _Sublattice(Capture):
    """A capture seen through one Bayer sub-lattice of one camera: `read` returns that sub-lattice of
    the camera's raw mosaic; the camera's size is the sub-lattice's."""

    offset: tuple[int, int] = (0, 0)
    pattern: str = "RGGB"
    full_size: tuple[int, int] = (0, 0)

    def read(self, frame: Frame) -> np.ndarray:
        img = read_mosaic(self.path(frame), self.pattern)
        w, h = self.full_size
        if img.shape != (h, w):
            raise InputError(self.path(frame), f"image is {img.shape[1]}x{img.shape[0]}, camera "
                                               f"{frame.camera!r} is {w}x{h}")
        dy, dx = self.offset
        return img[dy::2, dx::2]


def sublattice(capture: Capture, camera: str, offset: tuple[int, int]) -> Capture:
    """A view of `capture` whose camera `camera` is its sub-lattice at `offset` (row, column)."""
    w, h = capture.cameras[camera]
    dy, dx = offset
    size = ((w - dx + 1) // 2, (h - dy + 1) // 2)
    fields = {f.name: getattr(capture, f.name) for f in dataclasses.fields(Capture)}
    fields.update(cameras={**capture.cameras, camera: size}, bayer={})
    return _Sublattice(**fields, offset=offset, pattern=capture.bayer[camera], full_size=(w, h))


@dataclass
class BayerIntensity(IntensityMatrix):
    """The intensity matrix of a Bayer camera: offset and gain per photosite (H, W), each sub-lattice
    with its own display response (`responses`, in `OFFSETS` order); `response` is the first green's."""

    responses: tuple = ()

    def fringe_waveform(self, low: float, high: float, samples: int = 1024) -> np.ndarray:
        raise ValueError("a Bayer camera's fringe waveform differs per colour: use its sub-lattices' own")

    def to_arrays(self, prefix: str = "im_") -> dict[str, np.ndarray]:
        out = super().to_arrays(prefix)
        out[f"{prefix}bayer_levels"] = np.stack([np.asarray(r.levels, np.float64) for r in self.responses])
        out[f"{prefix}bayer_luminance"] = np.stack([np.asarray(r.luminance, np.float64) for r in self.responses])
        return out


def _assemble(parts: list, shape: tuple[int, ...], dtype) -> np.ndarray:
    """A (..., H, W) array from the four sub-lattices' (..., h_i, w_i) arrays (`OFFSETS` order)."""
    out = np.empty(shape, dtype)
    for (dy, dx), a in zip(OFFSETS, parts):
        out[..., dy::2, dx::2] = a
    return out


def decode_bayer(capture: Capture, camera: str) -> tuple[list[DecodedPosition], BayerIntensity | None, list[str]]:
    """`calib.sensor.decode_all` for a Bayer camera: each sub-lattice decoded as its own camera
    (module docstring), the results put back together photosite by photosite."""
    w, h = capture.cameras[camera]
    names = colours(capture.bayer[camera])
    per = []
    for off in OFFSETS:
        positions, im, notes = decode_positions(sublattice(capture, camera, off), camera)
        per.append((positions, im, [f"{names[off]} photosites at {off}: {n}" for n in notes]))
    merged = []
    for k, first in enumerate(per[0][0]):
        parts = [p[0][k] for p in per]
        merged.append(dataclasses.replace(
            first, coord=_assemble([p.coord for p in parts], (2, h, w), np.float64),
            modulation=_assemble([p.modulation for p in parts], (2, h, w), np.float32),
            mean=_assemble([p.mean for p in parts], (2, h, w), np.float32),
            quality=_assemble([p.quality for p in parts], (h, w), np.uint8),
            mismatch_sigma={a: [max(vals) for vals in zip(*(p.mismatch_sigma[a] for p in parts))]
                            for a in first.mismatch_sigma}))
    ims = [p[1] for p in per]
    im = None
    if all(i is not None for i in ims):
        im = BayerIntensity(_assemble([i.offset for i in ims], (h, w), np.float32),
                            _assemble([i.gain for i in ims], (h, w), np.float32), ims[1].response,
                            tuple(i.response for i in ims))
    notes = sorted({n for p in per for n in p[2]})
    return merged, im, notes


def _sub_position(p: DecodedPosition, offset: tuple[int, int]) -> DecodedPosition:
    dy, dx = offset
    return dataclasses.replace(p, coord=p.coord[:, dy::2, dx::2], modulation=p.modulation[:, dy::2, dx::2],
                               mean=p.mean[:, dy::2, dx::2], quality=p.quality[dy::2, dx::2])


def smooth_planes(pattern: str, positions: list[DecodedPosition], smoother):
    """The `smooth(lines, z_mm)` of `calib.sensor.regularise_lines` for a Bayer camera: each
    sub-lattice's points on the plane smoothed as a field of its own (`smoother` as there; a fixed
    `Smoother`'s window is halved, as a sub-lattice pixel spans two camera pixels)."""

    def own(off):
        if smoother is None or smoother == AUTO:
            return auto_smoother([_sub_position(p, off) for p in positions])
        return dataclasses.replace(smoother, half_window=max(2, smoother.half_window // 2))

    used = {off: own(off) for off in OFFSETS}

    def smooth(lines: Lines, z_mm: float):
        h, w = lines.valid.shape
        xy, sigma, windows = [], [], []
        for off in OFFSETS:
            dy, dx = off
            sub = Lines(lines.start[dy::2, dx::2], lines.slope[dy::2, dx::2], lines.valid[dy::2, dx::2],
                        lines.residual_mm[dy::2, dx::2], lines.used[dy::2, dx::2], lines.z_ref)
            a, s, win = smooth_plane(sub, z_mm, used[off], smoother is not None)
            xy.append(None if a is None else a.transpose(2, 0, 1))
            sigma.append(s)
            windows.append(2 * win)                      # in camera pixels
        points = None if xy[0] is None else _assemble(xy, (2, h, w), np.float64).transpose(1, 2, 0)
        return points, _assemble(sigma, (h, w), np.float32), float(np.mean(windows))

    return smooth
