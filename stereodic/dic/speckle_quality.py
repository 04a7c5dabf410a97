"""How good a speckle pattern is for DIC, before the test (`stereodic speckle`).

From one image of the speckled specimen (frame: pixels, x = column, y = row; grey levels):
- the image noise sigma: estimated from the image (`texture.estimate_noise`, Immerkaer's operator: an
  upper bound on speckle, since fine texture adds to it), or measured from a second image of the same
  static scene: sigma = std(I1 - I2') / sqrt(2), I2' the second image scaled to the first's mean and
  standard deviation (a change of lighting between the two is not noise, and ZNSSD ignores it);
- the mean intensity gradient, MIG = mean |grad I| (Pan et al. 2010), grey levels per pixel;
- per subset, the sum of squared subset intensity gradients SSSIG (Pan et al. 2008), along x (for u)
  and y (for v): `texture.sssig`, from the gradients of the image's cubic B-spline (no low-pass: the
  bound of the random error is that of the raw image);
- the predicted random error of a subset's displacement, sigma_u ~ sqrt(2) sigma / sqrt(SSSIG) (the
  larger of u and v: `texture.predicted_noise`), for each subset size: its median and 95th percentile
  over the subsets inside the region; the smallest subset whose median reaches a target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereodic.dic.interpolation import BSplineImage
from stereodic.dic.texture import estimate_noise, predicted_noise, sssig

SIZES = tuple(range(9, 102, 2))  # the subset sizes (odd, pixels) of the noise curve


@dataclass
class SpeckleQuality:
    """sigma: image noise (grey levels) and how it was found ("estimated" or "measured"); mig: mean
    intensity gradient (grey levels / px); sizes: subset sizes (px); median_px, p95_px: predicted random
    error per size (px); subset: the size of the maps; sssig_map: (H, W) min of SSSIG x and y at `subset`
    (grey levels^2), noise_map: (H, W) predicted error at `subset` (px), NaN where the subset leaves the
    image or the region; target_px and smallest: the smallest size whose median reaches the target (None
    if none does)."""

    sigma: float
    sigma_source: str
    mig: float
    sizes: np.ndarray
    median_px: np.ndarray
    p95_px: np.ndarray
    subset: int
    sssig_map: np.ndarray
    noise_map: np.ndarray
    target_px: float
    smallest: int | None


def speckle_quality(image: np.ndarray, *, subset: int = 21, target_px: float = 0.01,
                    roi: tuple[int, int, int, int] | None = None, second: np.ndarray | None = None,
                    sizes=SIZES) -> SpeckleQuality:
    """The quality figures of the module docstring for `image` (2-D, any real dtype). roi: (x0, y0, x1,
    y1) inclusive pixel bounds of the subset centres considered (default: the whole image); second: a
    second image of the same static scene, to measure the noise."""
    img = np.asarray(image, np.float64)
    h, w = img.shape
    if second is not None:
        other = np.asarray(second, np.float64)
        other = (other - other.mean()) * (img.std() / other.std()) + img.mean()
        sigma, source = float(np.std(img - other) / np.sqrt(2.0)), "measured"
    else:
        sigma, source = estimate_noise(image), "estimated"
    b = BSplineImage.from_image(img, order=3, prefilter_sigma=0.0)
    g = b.pixel_gradients()
    x0, y0, x1, y1 = roi if roi is not None else (0, 0, w - 1, h - 1)
    region = np.zeros((h, w), bool)
    region[y0:y1 + 1, x0:x1 + 1] = True
    mig = float(np.mean(np.hypot(g[1], g[2])[region]))
    yy, xx = np.nonzero(region)
    stride = max(1, int(np.sqrt(yy.size / 250_000)))  # statistics on at most ~250,000 subsets
    yy, xx = yy[::stride], xx[::stride]
    med, p95 = [], []
    for n in sizes:
        half = n // 2
        inside = (xx >= half) & (xx < w - half) & (yy >= half) & (yy < h - half)
        noise = predicted_noise(b, xx[inside], yy[inside], half, sigma)
        med.append(float(np.median(noise)) if noise.size else np.nan)
        p95.append(float(np.percentile(noise, 95)) if noise.size else np.nan)
    med, p95 = np.array(med), np.array(p95)
    half = subset // 2
    sums = sssig(b, half)
    fits = np.zeros((h, w), bool)
    fits[half:h - half, half:w - half] = True
    fits &= region
    vy, vx = np.nonzero(fits)
    noise_map = np.full((h, w), np.nan)
    noise_map[vy, vx] = predicted_noise(b, vx, vy, half, sigma, sums)
    sssig_map = np.where(fits, np.minimum(sums[0], sums[1]), np.nan)
    reach = np.flatnonzero(med <= target_px)
    smallest = int(np.asarray(sizes)[reach[0]]) if reach.size else None
    return SpeckleQuality(sigma, source, mig, np.asarray(sizes), med, p95, subset, sssig_map, noise_map, target_px,
                          smallest)


def plot(quality: SpeckleQuality, path) -> None:
    """One PNG (atomic): the map of the predicted error at the chosen subset, and the error against the
    subset size (median, 95th percentile, target)."""
    from matplotlib.figure import Figure   # not pyplot: the caller's backend (a notebook's) stays as it is

    from calib.atomic import atomic_output
    q = quality
    fig = Figure(figsize=(12, 5))
    a, b = fig.subplots(1, 2)
    im = a.imshow(q.noise_map, cmap="viridis", interpolation="nearest")
    fig.colorbar(im, ax=a, label="predicted random error (px)")
    a.set_title(f"predicted error, {q.subset} x {q.subset} subsets")
    a.set_xlabel("x (px)")
    a.set_ylabel("y (px)")
    b.loglog(q.sizes, q.median_px, "o-", label="median")
    b.loglog(q.sizes, q.p95_px, "s--", label="95th percentile")
    b.axhline(q.target_px, color="k", lw=0.8, label=f"target {q.target_px:g} px")
    if q.smallest is not None:
        b.axvline(q.smallest, color="r", lw=0.8, label=f"smallest subset reaching it: {q.smallest} px")
    b.set_xlabel("subset size (px)")
    b.set_ylabel("predicted random error (px)")
    b.set_title(f"noise {q.sigma:.2f} grey ({q.sigma_source}), MIG {q.mig:.1f} grey/px")
    b.grid(True, which="both", alpha=0.3)
    b.legend()
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=100)
