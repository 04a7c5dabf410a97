"""Pictures of a camera's departure from the ideal models (matplotlib), for `stereodic show` and docs.

Each function draws into a new figure and returns it; the caller saves or shows it.
"""

from __future__ import annotations

import numpy as np

from stereodic.virtual.imm import IMM


def plot_noncentrality(miss_mm: np.ndarray, miss_px: np.ndarray | None = None, title: str = "non-centrality"):
    """Heat maps over the real image of how far each ray misses the fitted optical centre (mm) and,
    if given, the pinhole model's resulting image error (pixels, `stereodic.virtual.camera.miss_in_pixels`)."""
    import matplotlib.pyplot as plt
    maps = [(miss_mm, "miss distance (mm)")] + ([] if miss_px is None else [(miss_px, "pinhole error (px)")])
    fig, axes = plt.subplots(1, len(maps), figsize=(5.5 * len(maps), 4), squeeze=False)
    for ax, (m, label) in zip(axes[0], maps):
        im = ax.imshow(m, cmap="viridis")
        ax.set_title(label)
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def round_down(x: float) -> float:
    """The largest of 1, 2, 5 x 10^k not above x (x > 0): a round number for scales."""
    k = np.floor(np.log10(x))
    return float(max(m * 10.0 ** k for m in (1, 2, 5) if m * 10.0 ** k <= x * (1 + 1e-9)))


def arrows(ax, u, v, du, dv, unit: str, color: str = "white") -> None:
    """Arrows (du, dv) at the grid points (u, v) (2-D arrays, data units), magnified by a round factor so
    that the longest (99th percentile) spans about 1.5 grid steps, and the scale above the axes: an
    arrow of a round length and the factor. `unit` names the arrows' unit ("px")."""
    length = np.hypot(du, dv)
    top = float(np.nanpercentile(length, 99)) if np.isfinite(length).any() else 0.0
    if top <= 0:
        return
    step = float(u[0, 1] - u[0, 0]) if u.shape[1] > 1 else 1.0
    magnify = round_down(1.5 * step / top)
    key = round_down(top)
    q = ax.quiver(u, v, du, dv, color=color, angles="xy", scale_units="xy", scale=1 / magnify, width=0.003)
    ax.quiverkey(q, 0.97, 1.035, key, f"arrow scale: {key:g} {unit}\n(drawn {magnify:g}x)", labelpos="W",
                 coordinates="axes", color="black", fontproperties={"size": 8})


def plot_distortion(imm: IMM, step: int = 32, title: str = "distortion map"):
    """Where each virtual pixel samples the real image, relative to the best similarity transform
    (scale, rotation, shift) between the two grids: arrows on a grid every `step` virtual pixels
    (`arrows`: magnified, with their scale) over a colour map of the displacement length (real pixels)."""
    import matplotlib.pyplot as plt
    v, u = np.mgrid[0:imm.shape[0], 0:imm.shape[1]].astype(np.float64)
    ok = imm.valid
    src = np.stack([u[ok], v[ok]], -1)
    dst = np.stack([imm.map_x[ok], imm.map_y[ok]], -1).astype(np.float64)
    # least-squares similarity dst ~ a*src + b*perp(src) + t, complex form
    zs, zd = src[:, 0] + 1j * src[:, 1], dst[:, 0] + 1j * dst[:, 1]
    design = np.stack([zs, np.ones_like(zs)], -1)
    coef = np.linalg.lstsq(design, zd, rcond=None)[0]
    fitted = coef[0] * (u + 1j * v) + coef[1]
    disp = np.where(ok, imm.map_x + 1j * imm.map_y - fitted, np.nan)
    fig, ax = plt.subplots(figsize=(7, 5.5))
    im = ax.imshow(np.abs(disp), cmap="magma")
    s = (slice(step // 2, None, step), slice(step // 2, None, step))
    arrows(ax, u[s], v[s], disp[s].real, disp[s].imag, "real px", color="cyan")
    ax.set_title(title, loc="left")
    ax.set_xlabel("virtual u (px)")
    ax.set_ylabel("virtual v (px)")
    fig.colorbar(im, ax=ax, shrink=0.8, label="displacement from a similarity (real px)")
    fig.tight_layout()
    return fig


def plot_evm(evm: np.ndarray, title: str = "error vector matrix"):
    """Length of each virtual pixel's error vector (radians, model-less minus modelled direction)."""
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 5.5))
    im = ax.imshow(np.linalg.norm(evm, axis=-1), cmap="viridis")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, shrink=0.8, label="|EVM| (rad)")
    fig.tight_layout()
    return fig
