"""Gray-code structured light: binary-reflected Gray code of the projector column (or row), decoded per
pixel, alone or as the period order of a phase-shifted fringe.

Pattern: bit B of the code shows, at panel column c, the value (g(c) >> B) & 1 with g(c) = c ^ (c >> 1)
(white where 1; "inverse": the complement), as OpenCV's structured_light.GrayCodePattern does. The bits
B >= b0 fix the stripe s = c >> b0 (stripes of 2**b0 panel pixels): g(c) >> b0 = g(c >> b0).

Decoding (`decode_gray`), per pixel and bit: the bit is 1 where the pattern frame is brighter than its
inverse (or, without inverses, than the mean of the white and black frames); it is *decisive* where that
difference exceeds DECISIVE_FRACTION of the pixel's contrast (white - black, or without flats the largest
difference over the bits) and the JPEG/noise floor `min_difference`. A pixel with every bit decisive gets
its stripe's centre; a pixel with exactly one undecided bit whose two codes are neighbouring stripes (in a
Gray code only one bit changes between neighbours, so this is a pixel on their boundary) gets the
boundary between them; any other undecided pixel is flagged UNDECIDED, never guessed. Unlit pixels
(contrast below `min_contrast`) are flagged DARK.

Coordinates are panel pixels with pixel centres at integers (as the fringes' phase, `calib.patterns`):
stripe s covers columns s w .. s w + w - 1, centre s w + (w - 1) / 2, w = 2**b0.

Gray code plus phase shifting (`unwrap_with_gray`): the fringe's wrapped phase gives the position inside
a period P, the Gray code its order. With stripes of at most P / 2 the stripe centre is within P / 4 of
the true column, so the order k = rint((c_gray - f) / P) (f the phase's column in the period) is right
whatever happens at the Gray stripes' edges (their misalignment with the fringe's wrap, the cameras' blur:
at worst the neighbouring stripe, still within P / 4 + the boundary's half-width); the complementary
(one bit finer) stripe is what makes this hold at the period edges. A pixel whose residual exceeds
GRAY_TOLERANCE of a period is flagged UNWRAP.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.capture import Capture, Frame, Pattern
from calib.errors import InputError
from calib.imageio import IMAGE_SUFFIXES

FOLDER_SUFFIXES = IMAGE_SUFFIXES + (".jpg", ".jpeg", ".bmp")   # what OpenCV's samples save too

DECISIVE_FRACTION = 0.1     # a bit is decisive where |pattern - inverse| >= this fraction of the contrast
GRAY_TOLERANCE = 0.4        # periods: the largest disagreement of the Gray code and the phase kept


def gray(n: np.ndarray) -> np.ndarray:
    """The binary-reflected Gray code of the non-negative integers n."""
    n = np.asarray(n, np.int64)
    return n ^ (n >> 1)


def gray_to_binary(g: np.ndarray) -> np.ndarray:
    """The integers whose Gray codes are g (inverse of `gray`)."""
    n = np.array(g, np.int64, copy=True)
    shift = 1
    while shift < 64:
        n ^= n >> shift
        shift *= 2
    return n


def gray_bits(extent_px: int) -> int:
    """The number of Gray-code bits that number `extent_px` panel pixels (OpenCV's count)."""
    return max(1, int(np.ceil(np.log2(extent_px))))


def gray_profile(n: int, bit: int, inverse: bool = False) -> np.ndarray:
    """(n,) uint8 0/1: bit `bit` of the Gray code of columns 0..n-1 (complemented if `inverse`)."""
    v = ((gray(np.arange(n)) >> bit) & 1).astype(np.uint8)
    return 1 - v if inverse else v


@dataclass
class GrayDecoded:
    """One camera's Gray-code decoding. coord: (H, W) float32 panel pixels (stripe centre or boundary),
    NaN where flagged; contrast: (H, W) float32 pattern contrast and offset: the mean level, the frames'
    units; quality: (H, W) uint8 `calib.phase` flags; stripe_px: the stripe width 2**low_bit."""

    coord: np.ndarray
    contrast: np.ndarray
    offset: np.ndarray
    quality: np.ndarray
    stripe_px: int


def decode_gray(patterns: list[np.ndarray], inverses: list[np.ndarray] | None, white: np.ndarray | None,
                black: np.ndarray | None, *, low_bit: int, extent_px: int, min_contrast: float,
                min_difference: float = 0.0) -> GrayDecoded:
    """Panel coordinate of every pixel from its Gray-code frames (module docstring).

    Parameters
    ----------
    patterns : list of (H, W) arrays
        The frames of bits low_bit, low_bit + 1, ... (least significant first), camera values.
    inverses : list of (H, W) arrays, optional
        Each bit's inverse frame, same order; None: the threshold is the mean of `white` and `black`.
    white, black : (H, W) arrays, optional
        The all-white and all-black frames; needed without inverses; with them the contrast is
        white - black, else the largest |pattern - inverse| over the bits.
    low_bit : int
        The finest bit given (stripes of 2**low_bit panel pixels).
    extent_px : int
        The panel's size along the code's axis, pixels (codes beyond it are flagged).
    min_contrast : float
        Contrast below which a pixel is unlit (DARK), camera units.
    min_difference : float
        The smallest |pattern - inverse| that decides a bit whatever the contrast (noise floor), camera units.

    Returns
    -------
    decoded : GrayDecoded
        Coordinates (panel pixels), contrast, mean level and flags.
    """
    if inverses is None and (white is None or black is None):
        raise ValueError("Gray code without inverse frames needs the white and black frames")
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    if inverses is not None:
        diffs = [f32(p) - f32(q) for p, q in zip(patterns, inverses)]
    else:
        mid = (f32(white) + f32(black)) / 2
        diffs = [2 * (f32(p) - mid) for p in patterns]
    if white is not None and black is not None:
        contrast, offset = f32(white) - f32(black), (f32(white) + f32(black)) / 2
    else:
        contrast = np.max(np.abs(np.stack(diffs)), axis=0)
        offset = sum(f32(p) + f32(q) for p, q in zip(patterns, inverses)) / np.float32(2 * len(patterns))
    from calib.phase import DARK, UNDECIDED   # here: calib.phase's kernels bring numba (0.15 s of import)
    shape = contrast.shape
    limit = np.maximum(DECISIVE_FRACTION * contrast, np.float32(min_difference))
    code = np.zeros(shape, np.int64)
    undecided = np.zeros(shape, np.int8)
    which = np.zeros(shape, np.int64)                # the undecided bit (where exactly one)
    for k, d in enumerate(diffs):
        code |= (d > 0).astype(np.int64) << k
        weak = np.abs(d) < limit
        undecided += weak
        which[weak] = k
    code &= ~np.where(undecided == 1, np.int64(1) << which, 0)      # the undecided bit as 0 ...
    s0 = gray_to_binary(code)
    s1 = gray_to_binary(code | (np.int64(1) << which))                # ... and as 1
    w = 1 << low_bit
    coord = np.where(undecided == 0, s0 * w + (w - 1) / 2, np.maximum(s0, s1) * w - 0.5)
    boundary = (undecided == 1) & (np.abs(s0 - s1) == 1)
    quality = np.zeros(shape, np.uint8)
    quality[~((undecided == 0) | boundary)] |= UNDECIDED
    quality[(coord < -0.5) | (coord > extent_px - 0.5)] |= UNDECIDED
    quality[~(contrast >= min_contrast)] |= DARK
    out = np.where(quality == 0, coord, np.nan).astype(np.float32)
    return GrayDecoded(out, contrast, offset, quality, w)


def unwrap_with_gray(coord_gray: np.ndarray, phase: np.ndarray, period_px: float,
                     stripe_px: int) -> tuple[np.ndarray, np.ndarray]:
    """The absolute panel coordinate of a wrapped fringe phase ordered by the Gray code (module docstring).

    Parameters
    ----------
    coord_gray : (H, W) float
        `decode_gray`'s coordinate, panel pixels (NaN: not decoded).
    phase : (H, W) float
        The fringe's wrapped phase 2 pi c / P (mod 2 pi), radians.
    period_px : float
        The fringe's period P, panel pixels.
    stripe_px : int
        The Gray code's stripe width; at most P / 2.

    Returns
    -------
    coord : (H, W) float64
        Panel pixels (NaN where either input is).
    consistent : (H, W) bool
        Where the Gray code and the phase agree within GRAY_TOLERANCE of a period.
    """
    if stripe_px > period_px / 2:
        raise ValueError(f"Gray-code stripes of {stripe_px} px are too wide to order fringes of period "
                         f"{period_px:g} px (at most half the period: add the finer bits)")
    t = np.asarray(phase, np.float64) / (2 * np.pi)
    f = (t - np.floor(t)) * period_px
    cycles = (np.asarray(coord_gray, np.float64) - f) / period_px
    k = np.rint(cycles)
    with np.errstate(invalid="ignore"):
        consistent = np.abs(cycles - k) <= GRAY_TOLERANCE
    return k * period_px + f, consistent


# ------------------------------------------------------------------ a folder in OpenCV's GrayCodePattern order

_NUMBERED = re.compile(r"^(.*?)(\d+)$")


def opencv_sequence(width_px: int, height_px: int) -> list[Pattern]:
    """The patterns of OpenCV's structured_light.GrayCodePattern(width, height) in its order: the column
    bits, most significant first, each followed by its inverse; the row bits the same way; white; black."""
    seq = []
    for axis, extent in (("x", width_px), ("y", height_px)):
        for bit in reversed(range(gray_bits(extent))):
            seq += [Pattern("gray", {"axis": axis, "bit": bit, "inverse": inv}) for inv in (False, True)]
    return seq + [Pattern("flat", {"level": 255}), Pattern("flat", {"level": 0})]


def opencv_folder(folder: str | os.PathLike, projector: tuple[int, int], cameras: tuple[str, str]) -> Capture:
    """A scan capture (one state) of a folder of images in OpenCV's GrayCodePattern order, read as it is.

    The image files are grouped by their name without its trailing number (``pattern_cam1_im7.jpg``: group
    ``pattern_cam1_im``, number 7); the two groups, in natural order, are the `cameras` (left, right), and
    within a group the numbers 1, 2, ... (or 0, 1, ...) follow `opencv_sequence`. InputError naming the
    folder when there are not exactly two groups, or a group lacks an image of the sequence."""
    from calib.image_files import natural_key
    from calib.imageio import image_size
    folder = Path(folder)
    groups: dict[str, dict[int, str]] = {}
    for p in sorted(folder.iterdir(), key=natural_key):
        m = _NUMBERED.match(p.stem)
        if p.is_file() and m and p.suffix.lower() in FOLDER_SUFFIXES:
            groups.setdefault(m.group(1), {})[int(m.group(2))] = p.name
    seq = opencv_sequence(*projector)
    if len(groups) != 2:
        raise InputError(folder, f"holds {len(groups)} numbered image series ({', '.join(groups) or 'none'}): an "
                                 f"OpenCV Gray-code scan has two, one per camera, of {len(seq)} images each "
                                 f"(or give a capture.json)")
    frames, sizes = [], {}
    for cam, (prefix, files) in zip(cameras, sorted(groups.items(), key=lambda kv: natural_key(kv[0]))):
        first = min(files)
        for k, pattern in enumerate(seq):
            name = files.get(first + k)
            if name is None:
                what = (f"{pattern.axis} bit {pattern.bit}{' inverse' if pattern.inverse else ''}"
                        if pattern.type == "gray" else ("white" if pattern.level else "black"))
                raise InputError(folder, f"lacks image {first + k} of the series {prefix}* ({what}: OpenCV's "
                                         f"Gray code of a {projector[0]}x{projector[1]} projector has {len(seq)} "
                                         f"images)")
            frames.append(Frame(cam, name, pattern, state=0))
        if len(files) != len(seq):
            raise InputError(folder, f"the series {prefix}* has {len(files)} images, OpenCV's Gray code of a "
                                     f"{projector[0]}x{projector[1]} projector has {len(seq)}")
        sizes[cam] = image_size(folder / files[first])
    return Capture(folder, "scan", sizes, frames,
                   extra={"projector": {"width_px": int(projector[0]), "height_px": int(projector[1])}})
