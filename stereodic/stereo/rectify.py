"""Rectifying stereo image pairs with a rig: each camera's intensity matrix, then its IMM, onto the common
virtual sensor; and how well the rows line up: features matched between the rectified images, their
vertical disparity, and a picture that shows it.

In the rectified pair a scene point lies on the same row of both images (exactly for central lenses;
for non-central ones the EVM says how far off, see `stereodic.stereo.triangulate`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereodic.dic.background import side_by_side
from stereodic.stereo.rig import Rig
from stereodic.virtual.undistort import undistort_image


def rectify_pair(rig: Rig, left: np.ndarray, right: np.ndarray, *, intensity: bool = True,
                 fixed_point: bool = False, where: tuple = ("left", "right"), exact: bool = False
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The rectified (virtual) images of a real image pair: intensity matrix, then IMM, per camera.

    Parameters
    ----------
    rig : Rig
        The rectified pair (`stereodic.stereo.rig.build_rig`, `load_rig`).
    left, right : (H, W) uint8 or uint16
        The real images, each its camera's size.
    intensity : bool
        Apply each camera's intensity matrix, where the rig has one.
    fixed_point : bool
        OpenCV's 1/32-pixel maps instead of the exact float maps.
    where : (str, str)
        The images' names in messages.
    exact : bool
        float32 images: the interpolated grey levels not rounded to the input's integer type (for DIC:
        the rounding adds noise to every match).

    Returns
    -------
    left_v, right_v : (Hv, Wv) arrays
        The rectified images on the rig's common virtual sensor, the input's dtype (float32 with
        `exact`); blank pixels 0.
    """
    def one(side: str, image: np.ndarray, name) -> np.ndarray:
        cam = rig.camera(side)
        return undistort_image(image, cam.imm, im=cam.im if intensity else None, fixed_point=fixed_point,
                               where=name, exact=exact)

    # the two cameras side by side on the run's threads (OpenCV's remap and numpy release the GIL)
    out = side_by_side(lambda: one("left", left, where[0]), lambda: one("right", right, where[1]))
    return out[0], out[1]


def row_band(height: int) -> int:
    """Rows above and below its own that `row_alignment` accepts a feature's match in by default: an
    eighth of the image height, at least 16."""
    return max(16, height // 8)


@dataclass
class RowAlignment:
    """Features matched between the two rectified images: left position (x, y), right column x_right, the
    vertical disparity dy = y_right - y_left (pixels, sub-pixel; 0 for a perfect rectification) and the
    match's ZNCC. (N,) float64 arrays."""

    x: np.ndarray
    y: np.ndarray
    x_right: np.ndarray
    dy: np.ndarray
    zncc: np.ndarray

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.dy ** 2))) if self.dy.size else float("nan")


def row_alignment(left: np.ndarray, right: np.ndarray, *, max_dy: int | None = None, half: int = 10,
                  count: int = 150, min_zncc: float = 0.9) -> RowAlignment:
    """How well the rows of a rectified pair line up, from features matched between the two images.

    ORB features of both images (`stereodic.dic.initial_guess.image_features`: kept for a read-only
    image, so that the stereo start of a run reuses them) are matched whatever the rows' offset and kept
    where a local RANSAC affine agrees (`consistent_matches`: a periodic or stripe pattern gives no
    reliable match); at most `count` of them, spread over the image (one per cell of a regular lattice),
    whose subsets of half-width `half` lie inside both images' valid areas, are refined to sub-pixel by
    IC-GN with an affine subset from the match (the 2D DIC engine, `stereodic.dic`: the two views
    foreshorten a surface differently) and kept where they converge with at least `min_zncc` and rows
    within `max_dy` of their own (None: `row_band`, an eighth of the height, at least 16: a rig whose
    calibration no longer fits its images can put them tens of rows apart).

    Parameters
    ----------
    left, right : (H, W) array
        The rectified pair (blank pixels 0), any real dtype.

    Returns
    -------
    match : RowAlignment
        The refined matches, rectified pixels; empty when none converged.
    """
    from stereodic.dic import BSplineImage, DicSettings, correlate_points
    from stereodic.dic.initial_guess import consistent_matches, image_features

    h, w = left.shape
    max_dy = row_band(h) if max_dy is None else int(max_dy)
    p, q = consistent_matches(*side_by_side(lambda: image_features(left), lambda: image_features(right)))
    side = 2 * half + 1
    kernel = np.ones((side + 2, side + 2), np.uint8)
    inside = [cv2.erode((img > 0).astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0)
              for img in (left, right)]
    xl, yl = np.rint(p).astype(np.int64).T
    xr, yr = np.rint(q).astype(np.int64).T
    ok = ((xl >= 0) & (xl < w) & (yl >= 0) & (yl < h) & (xr >= 0) & (xr < w) & (yr >= 0) & (yr < h)
          & (np.abs(q[:, 1] - p[:, 1]) <= max_dy + 1))
    ok[ok] = (inside[0][yl[ok], xl[ok]] > 0) & (inside[1][yr[ok], xr[ok]] > 0)
    if not ok.any():
        return RowAlignment(*(np.empty(0) for _ in range(5)))
    # one match per cell of a lattice of about `count` cells over the image: spread, and a few hundred at most
    cell = max(float(np.sqrt(h * w / count)), 1.0)
    sel = np.flatnonzero(ok)
    key = (yl[sel] // cell).astype(np.int64) * (int(w // cell) + 1) + (xl[sel] // cell).astype(np.int64)
    sel = sel[np.unique(key, return_index=True)[1]]
    sel = sel[np.linspace(0, sel.size - 1, min(count, sel.size)).astype(np.int64)]
    x, y = xl[sel].astype(np.float64), yl[sel].astype(np.float64)
    start = q[sel] - p[sel]                      # the match's displacement, about a pixel good
    settings = DicSettings(subset=side, min_zncc=min_zncc)
    res = correlate_points(BSplineImage.from_image(left, order=3, prefilter_sigma=settings.prefilter_sigma),
                           BSplineImage.from_image(right, order=3, prefilter_sigma=settings.prefilter_sigma), x, y,
                           start, settings=settings)
    ok = np.isfinite(res.u) & (np.abs(res.v) <= max_dy)
    return RowAlignment(x[ok], y[ok], x[ok] + res.u[ok], res.v[ok], res.zncc[ok])


def offset_text(match: RowAlignment) -> str:
    """A sentence naming the rows' offset when the rows are more than a pixel apart, else ""."""
    if not match.dy.size or np.median(np.abs(match.dy)) <= 1.0:
        return ""
    return (f"the rows are {match.dy.min():+.1f} to {match.dy.max():+.1f} px apart: the rig's calibration no longer "
            f"fits these images (a camera moved or refocused?); `stereodic dic` re-orients it from the speckle")


def plot_row_alignment(left: np.ndarray, right: np.ndarray, match: RowAlignment, every: int = 32):
    """A matplotlib figure that shows by eye and in numbers whether the rows line up: both rectified
    images side by side with a labelled line every `every` rows and the matched features joined across;
    three magnified crops of matches (left above right, the feature's row drawn through both); the
    vertical disparity of every match against its column. Returns the figure."""
    import matplotlib
    from matplotlib.figure import Figure   # not pyplot: the caller's backend (a notebook's) stays as it is

    from calib.numbers import fixed

    def to8(img):
        img = img.astype(np.float32)
        return np.clip(img * (255.0 / (float(img.max()) or 1.0)), 0, 255)

    h, w = left.shape
    fig = Figure(figsize=(12, 8.2), layout="constrained")
    grid = fig.add_gridspec(2, 4, height_ratios=[1.35, 1])
    ax = fig.add_subplot(grid[0, :])
    ax.imshow(np.hstack([to8(left), to8(right)]), cmap="gray", interpolation="nearest")
    for r in range(every // 2, h, every):
        ax.axhline(r, color="#ffd166", lw=0.6, alpha=0.7)
    ax.set_yticks(range(every // 2, h, 2 * every))
    ax.axvline(w - 0.5, color="white", lw=1.5)
    n = match.dy.size
    lim = max(0.05, float(np.abs(match.dy).max()) if n else 0.05)
    cmap = matplotlib.colormaps["coolwarm"]
    ax.plot(match.x, match.y, "o", ms=3, mfc="none", mec="#06d6a0")
    ax.plot(w + match.x_right, match.y + match.dy, "o", ms=3, mfc="none", mec="#06d6a0")
    order = np.argsort(np.abs(match.dy))
    picks = [order[0], order[len(order) // 2], order[-1]] if n else []
    for name, k in zip("ABC", picks):
        ax.plot([match.x[k], w + match.x_right[k]], [match.y[k], match.y[k] + match.dy[k]], "-", lw=1,
                color="#ef476f")
        for px in (match.x[k], w + match.x_right[k]):
            ax.annotate(name, (px, match.y[k]), xytext=(4, -4), textcoords="offset points", color="#ef476f",
                        fontsize=11, fontweight="bold")
    ax.set_xlim(-0.5, 2 * w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_xticks([w / 2, 1.5 * w], ["left rectified image", "right rectified image"])
    ax.set_ylabel("rectified row (px)")
    title = (f"Rectified pair: a scene point lies on the same row in both images (yellow lines every {every} rows; "
             f"circles: {n} features matched left to right)")
    if n and offset_text(match):
        title += "\n" + offset_text(match)
    ax.set_title(title, fontsize=10, color="#c1121f" if n and offset_text(match) else "black")
    if n == 0:
        fig.add_subplot(grid[1, :]).text(
            0.5, 0.5, f"No feature with texture in both directions could be matched within {row_band(h)} rows of "
                      f"its own,\nso the row alignment cannot be measured from this pair (stripes or a blank "
                      f"scene?\nor rows further apart than that). Rectify a pair that shows speckle or a "
                      f"chessboard.", ha="center", va="center", fontsize=11)
        fig.axes[-1].set_axis_off()
        return fig
    half = 20
    for slot, (k, label) in enumerate(zip(picks, ("A: smallest |dy|", "B: median |dy|", "C: largest |dy|"))):
        cx, cy, cr = int(match.x[k]), int(match.y[k]), int(match.x_right[k])
        y0, y1 = max(cy - half, 0), min(cy + half + 1, h)
        crop_l = to8(left)[y0:y1, max(cx - half, 0):cx + half + 1]
        crop_r = to8(right)[y0:y1, max(cr - half, 0):cr + half + 1]
        width = min(crop_l.shape[1], crop_r.shape[1])
        sub = fig.add_subplot(grid[1, slot])
        sub.imshow(np.vstack([crop_l[:, :width], np.full((2, width), 255.0), crop_r[:, :width]]), cmap="gray",
                   interpolation="nearest")
        gap = crop_l.shape[0] + 2
        sub.axhline(cy - y0, color="#06d6a0", lw=1.2)
        sub.axhline(gap + cy - y0, color="#06d6a0", lw=1.2)
        sub.axhline(gap + cy - y0 + match.dy[k], color="#ef476f", lw=1.2, ls="--")
        sub.set_xticks([])
        sub.set_yticks([(y1 - y0) / 2, gap + (y1 - y0) / 2], ["left", "right"])
        sub.set_title(f"{label}\nrow {cy}, dy {fixed(match.dy[k], 3)} px", fontsize=9)
        if slot == 0:
            sub.set_xlabel("green: the feature's row in the left image\nred dashes: where the right image has it",
                           fontsize=8)
    res = fig.add_subplot(grid[1, 3])
    res.axhline(0, color="black", lw=0.8)
    res.scatter(match.x, match.dy, s=8, c=match.dy, cmap=cmap, vmin=-lim, vmax=lim)
    res.set_xlabel("left column (px)")
    res.set_ylabel("y_right - y_left (px; 0: rows aligned)")
    res.set_ylim(-1.2 * lim, 1.2 * lim)
    res.set_title(f"vertical disparity, {n} features\nRMS {fixed(match.rms, 3)} px, max "
                  f"{fixed(np.abs(match.dy).max(), 3)} px", fontsize=9)
    return fig
