"""`stereodic show`: pictures of a calibration result (PNG): distortion, residual, uncertainty, the mask
of pixels left out and why, and with `--truth` the ray error map against a simulated truth."""

from __future__ import annotations

from pathlib import Path

from stereodic.cli.common import add_input, add_output, wrote


def register(sub):
    p = sub.add_parser("show", help="pictures of a result (distortion, residuals, uncertainty, error)",
                       description="Write PNG pictures of a PRVM file: distortion.png (each pixel's departure "
                                   "from the best pinhole view, arrows with their scale), uncertainty.png, mask.png, "
                                   "residual.png (with three or more stage positions: two give no line-fit "
                                   "residual) and, with --truth, error.png (the ray error) and error_xy.png (its x "
                                   "and y components, one panel each).")
    add_input(p, "prvm", what="PRVM", metavar="CAM.npz", help="a camera's PRVM file (stereodic calibrate)")
    add_input(p, "--truth", what="truth", metavar="TRUTH.npz",
              help="the same camera's truth from a simulated dataset (truth.npz): also draw the ray error")
    add_output(p, kind="dir", metavar="DIR", help="folder of the pictures")
    p.set_defaults(func=run)


def run(args) -> int:
    from calib.prvm_file import load_prvm
    prvm = load_prvm(args.prvm)
    truth = load_prvm(args.truth) if args.truth else None
    if truth is not None:
        from calib.evaluate import check_truth
        check_truth(prvm, truth, args.prvm, args.truth)
    for path, what in write_report(prvm, args.output, truth):
        wrote(path, what)
    return 0


def _save(fig, path: Path) -> Path:
    from calib.atomic import atomic_output
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    return path


def _panel(fig, ax, data, title: str, label: str, cmap="viridis", vmin=None, vmax=None):
    """One map with its own axes (camera pixels) and colour bar."""
    im = ax.imshow(data, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
    fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("u (column, px)")
    ax.set_ylabel("v (row, px)")
    return im


def _image(data, title: str, label: str, path: Path, cmap="viridis", vmax=None, quiver=None) -> Path:
    """A map of `data` (0 to vmax, default its 99.5th percentile); quiver (u, v, du, dv): arrows on it,
    magnified to be seen, with an arrow of a round length as the scale."""
    import numpy as np
    from matplotlib.figure import Figure   # not pyplot: the caller's backend (a notebook's) stays as it is
    fig = Figure(figsize=(7, 5.6))
    ax = fig.subplots()
    finite = data[np.isfinite(data)]
    if vmax is None and finite.size:
        vmax = float(np.percentile(finite, 99.5))
    _panel(fig, ax, data, "" if quiver is not None else title, label, cmap, 0, vmax)
    if quiver is not None:
        from stereodic.virtual.plots import arrows
        arrows(ax, *quiver, "px")
        ax.set_title(title, fontsize=10, loc="left")
    return _save(fig, path)


def _signed_pair(x, y, title: str, label: str, path: Path) -> Path:
    """The x and y components of a signed error side by side, each with its own axes and colour bar
    (symmetric about zero, to its own 99.5th percentile)."""
    import numpy as np
    from matplotlib.figure import Figure
    fig = Figure(figsize=(12.5, 5.0), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, data, comp in zip(axes, (x, y), ("x", "y")):
        finite = np.abs(data[np.isfinite(data)])
        vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
        _panel(fig, ax, data, f"{comp} component (along display {'columns' if comp == 'x' else 'rows'})", label,
               "RdBu_r", -vmax, vmax)
    fig.suptitle(title)
    return _save(fig, path)


def distortion_px(prvm, z_mm: float):
    """(2, H, W) displacement (camera pixels) of each pixel from the best homography of the rays'
    points on the plane z = z_mm: how far the camera is from an ideal pinhole view of that plane."""
    import numpy as np

    from calib.reduced import fit_homography
    pts = prvm.at_z(z_mm)
    coord = np.stack([pts[..., 0], pts[..., 1]])
    hom = fit_homography(coord, prvm.valid)
    x, y = coord
    den = hom[2, 0] * x + hom[2, 1] * y + hom[2, 2]
    h, w = prvm.valid.shape
    v, u = np.mgrid[0:h, 0:w]
    return np.stack([(hom[0, 0] * x + hom[0, 1] * y + hom[0, 2]) / den - u,
                     (hom[1, 0] * x + hom[1, 1] * y + hom[1, 2]) / den - v])


def write_report(prvm, out_dir, truth=None) -> list[tuple[Path, str]]:
    """Write the PNG pictures of `prvm` (and its error against `truth`) into out_dir; returns each
    picture's path and what it shows."""
    import numpy as np

    from calib.evaluate import ErrorStats, footprint_mm, ray_error_px, working_plane
    from calib.numbers import fixed
    from calib.phase import QUALITY_NAMES
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    valid = prvm.valid
    z0 = float(prvm.meta.get("uncertainty_z_mm", [prvm.reference_z_mm])[0])
    d = distortion_px(prvm, z0)
    mag = np.where(valid, np.hypot(d[0], d[1]), np.nan)
    h, w = valid.shape
    step = max(h, w) // 24
    v, u = np.mgrid[step // 2:h:step, step // 2:w:step]
    paths.append((_image(mag, f"distortion: departure from the best\npinhole view of the plane z = "
                              f"{fixed(z0, 3)} mm", "displacement (camera px)", out / "distortion.png",
                         quiver=(u, v, d[0][v, u], d[1][v, u])),
                  f"distortion map, largest {fixed(float(np.nanmax(mag)), 2)} camera px"))
    res = prvm.residual_mm
    if res is not None and np.isfinite(res).any():
        paths.append((_image(np.where(valid, res * 1000, np.nan), "line-fit residual", "RMS distance (um)",
                             out / "residual.png", cmap="magma"),
                      f"line-fit residual map, median {fixed(1000 * float(np.nanmedian(res[valid])), 2)} um"))
    unc = prvm.extra.get("uncertainty_mm")
    if unc is not None:
        fp = footprint_mm(prvm, z0)
        paths.append((_image(np.where(valid, unc[..., 0] / fp, np.nan),
                             f"1-sigma ray uncertainty at z = {fixed(z0, 3)} mm (per axis)", "camera pixels",
                             out / "uncertainty.png", cmap="magma"), "ray uncertainty map (camera px)"))
    quality = prvm.extra.get("quality")
    if quality is not None or not valid.all():
        paths.append((_mask(valid, quality, QUALITY_NAMES, out / "mask.png"),
                      f"calibrated pixels and why the others are not ({valid.mean():.1%} calibrated)"))
    if truth is not None:
        err = ray_error_px(prvm, truth)
        s = ErrorStats.of(err)
        z = working_plane(truth)
        paths.append((_image(err, f"ray error against the truth on the plane z = {fixed(z, 3)} mm\n"
                                  f"RMS {fixed(s.rms, 4)} px, p99 {fixed(s.p99, 4)} px", "camera pixels",
                             out / "error.png", cmap="magma"),
                      f"ray error map against the truth, RMS {fixed(s.rms, 4)} px"))
        pts = prvm.at_z(z) - truth.at_z(z)
        fp = footprint_mm(truth, z)
        paths.append((_signed_pair(np.where(valid, pts[..., 0] / fp, np.nan),
                                   np.where(valid, pts[..., 1] / fp, np.nan),
                                   f"signed ray error (calibration - truth) on the plane z = {fixed(z, 3)} mm",
                                   "camera pixels", out / "error_xy.png"), "signed ray error maps in x and y"))
    return paths


def _mask(valid, quality, names, path: Path) -> Path:
    import numpy as np
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle
    fig = Figure(figsize=(7, 5.6))
    ax = fig.subplots()
    labels = ["calibrated", "not calibrated"] + list(names.values())
    code = np.where(valid, 0, 1)
    if quality is not None:
        for i, flag in enumerate(names):           # the lowest flag names the pixel's main problem
            code = np.where(~valid & (quality & flag > 0) & (code == 1), i + 2, code)
    colours = ["#2a9d8f", "#555555", "#264653", "#e76f51", "#f4a261", "#e9c46a", "#9b5de5"][:len(labels)]
    ax.imshow(code, cmap=ListedColormap(colours), vmin=-0.5, vmax=len(colours) - 0.5, interpolation="nearest")
    present = np.unique(code)
    handles = [Rectangle((0, 0), 1, 1, color=colours[i]) for i in present]
    ax.legend(handles, [f"{labels[i]} ({np.mean(code == i):.1%})" for i in present], loc="lower right", fontsize=8)
    ax.set_title("calibrated pixels")
    return _save(fig, path)
