"""Integer-pixel initial guesses by zero-normalised cross-correlation (ZNCC) search.

`search_integer` finds where the subset around one reference point went in the deformed image, within a
square search window (OpenCV's matchTemplate, FFT-based for large windows): the seeds of propagation.
`row_search` does the same along the row only (rectified stereo: the match lies on the same row), and
`row_seed_search` wraps it as a seed search of the propagation.
Positions in pixels, (x, y) = (column, row) of the reference image.
"""

from __future__ import annotations

import cv2
import numpy as np


def _as_f32(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(img, dtype=np.float32)


def _best(score: np.ndarray) -> tuple[int, int, float]:
    score = np.nan_to_num(score, nan=-1.0, posinf=-1.0, neginf=-1.0)
    r, c = np.unravel_index(int(np.argmax(score)), score.shape)
    return int(r), int(c), float(score[r, c])


def search_integer(ref: np.ndarray, dfm: np.ndarray, x: int, y: int, half: int, radius: int,
                   centre: tuple[int, int] = (0, 0)) -> tuple[int, int, float]:
    """Integer displacement (du, dv) of the subset of half-width `half` centred on pixel (x, y) of `ref`
    that maximises ZNCC in `dfm`, searched within `radius` pixels of `centre` = (du0, dv0).

    Returns (du, dv, zncc); zncc = -1 when the window leaves the image or the subset has no texture."""
    h, w = ref.shape
    if not (half <= x < w - half and half <= y < h - half):
        return 0, 0, -1.0
    tpl = _as_f32(ref[y - half:y + half + 1, x - half:x + half + 1])
    if float(tpl.std()) == 0.0:
        return 0, 0, -1.0
    x0 = max(0, x + centre[0] - radius - half)
    x1 = min(w, x + centre[0] + radius + half + 1)
    y0 = max(0, y + centre[1] - radius - half)
    y1 = min(h, y + centre[1] + radius + half + 1)
    if x1 - x0 < 2 * half + 1 or y1 - y0 < 2 * half + 1:
        return 0, 0, -1.0
    score = cv2.matchTemplate(_as_f32(dfm[y0:y1, x0:x1]), tpl, cv2.TM_CCOEFF_NORMED)
    r, c, z = _best(score)
    return x0 + c + half - x, y0 + r + half - y, z


def row_search(ref: np.ndarray, dfm: np.ndarray, xs: np.ndarray, ys: np.ndarray, *, half: int,
               dmin: int, dmax: int, rows: int = 0) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, ...]:
    """Integer disparities along the rows of a rectified pair: for each point of `ref`, the shift d in
    [dmin, dmax] along the same row of `dfm` (match at x + d) with the highest ZNCC (cv2.matchTemplate).

    Parameters
    ----------
    ref, dfm : (H, W) array
        The two images (e.g. left and right rectified).
    xs, ys : (N,) int
        The points in `ref`, pixels (x = column, y = row).
    half : int
        The subset's half-width, pixels (side 2 half + 1).
    dmin, dmax : int
        The range of shifts searched, pixels.
    rows : int
        Also search that many rows above and below (a band about the row, for a rig whose rows no longer
        line up exactly).

    Returns
    -------
    d : (N,) int64
        The best shift along the row, pixels.
    dv : (N,) int64
        The best row shift, pixels; returned only with `rows` > 0.
    zncc : (N,) float64
        Its ZNCC; -1 where no shift of the range keeps the subset in the image.
    """
    h, w = ref.shape
    d_out = np.zeros(len(xs), np.int64)
    dv_out = np.zeros(len(xs), np.int64)
    z_out = np.full(len(xs), -1.0)
    ref32 = _as_f32(ref)
    def32 = _as_f32(dfm)
    for k, (x, y) in enumerate(zip(np.asarray(xs, int), np.asarray(ys, int))):
        if not (half <= x < w - half and half <= y < h - half):
            continue
        lo = max(x + dmin, half)
        hi = min(x + dmax, w - 1 - half)
        top, bottom = max(y - rows, half), min(y + rows, h - 1 - half)
        if hi < lo:
            continue
        tpl = ref32[y - half:y + half + 1, x - half:x + half + 1]
        band = def32[top - half:bottom + half + 1, lo - half:hi + half + 1]
        r, c, z = _best(cv2.matchTemplate(band, tpl, cv2.TM_CCOEFF_NORMED))
        d_out[k] = lo + c - x
        dv_out[k] = top + r - y
        z_out[k] = z
    return (d_out, z_out) if rows == 0 else (d_out, dv_out, z_out)


def row_seed_search(dmin: int, dmax: int, rows: int = 0):
    """A seed search with `search_integer`'s signature that looks along the row only (or a band of `rows`
    rows either side of it), at shifts dmin..dmax (its radius and centre are ignored): the seeds of a
    rectified stereo pair."""
    def search(ref, dfm, x, y, half, radius, centre):
        if rows == 0:
            d, z = row_search(ref, dfm, [x], [y], half=half, dmin=dmin, dmax=dmax)
            return int(d[0]), 0, float(z[0])
        d, dv, z = row_search(ref, dfm, [x], [y], half=half, dmin=dmin, dmax=dmax, rows=rows)
        return int(d[0]), int(dv[0]), float(z[0])
    return search
