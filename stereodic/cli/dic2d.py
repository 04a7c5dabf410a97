"""`stereodic dic2d`: 2D subset digital image correlation of one or more deformed images.

Writes one CSV row per point and deformed image: image (0-based index among the deformed images), x, y
(the point in the reference image, pixels), u, v (displacement, pixels, u along x), zncc, converged
(1/0), status (ok, no_texture, outside, diverged, low_zncc, unreached), iterations and, with
--strain-window, the Green-Lagrange strains exx, eyy, exy and strain_valid. u, v are NaN exactly
where converged is 0; strains are NaN exactly where strain_valid is 0.
"""

from __future__ import annotations

from stereodic.cli.common import add_grid_options, add_input, add_output


def register(sub):
    p = sub.add_parser("dic2d", help="2D subset digital image correlation",
                       description="2D subset DIC: displacements (and strains) of deformed images against a "
                                   "reference, on a grid of points.")
    add_input(p, "ref", what="image", metavar="REF_IMG", help="reference image (8/16-bit PNG or TIFF)")
    add_input(p, "defs", what="image", metavar="DEF_IMG", nargs="+", help="deformed images, in order")
    add_output(p, metavar="OUT.csv", help="CSV of the results")
    add_grid_options(p, "reference image")
    p.add_argument("--shape", choices=["affine", "quadratic"], default="affine",
                   help="subset shape function (default affine)")
    p.add_argument("--interp", choices=["cubic", "quintic"], default="cubic",
                   help="B-spline interpolation (default cubic)")
    p.add_argument("--prefilter", type=float, default=0.7, metavar="SIGMA",
                   help="Gaussian low-pass of both images before interpolation, pixels (default 0.7, 0 = "
                        "none); lowers the interpolation bias")
    p.add_argument("--search", type=int, default=40, metavar="PIXELS",
                   help="search range of the seeds' integer displacement (default 40)")
    p.add_argument("--min-zncc", type=float, default=0.8, help="points below are flagged (default 0.8)")
    p.add_argument("--incremental", action="store_true",
                   help="register each image against the previous one and add up (large deformations)")
    p.add_argument("--strain-window", type=int, metavar="N",
                   help="add Green-Lagrange strains fitted over N x N grid points (odd)")
    add_output(p, "--npz", metavar="OUT.npz", help="also write the fields as arrays (n_images, ny, nx)")
    add_output(p, "--plot", kind="dir", metavar="DIR", help="write PNG maps of u, v, zncc (and strains) per image")
    p.set_defaults(func=run)


def _check_args(args) -> None:
    """The options beyond the grid's (stereodic.cli.common.dic_grid checks those)."""
    from calib.errors import InputError
    if args.strain_window is not None and (args.strain_window < 3 or args.strain_window % 2 == 0):
        raise InputError("--strain-window", f"must be an odd number >= 3, got {args.strain_window}")
    if not 0 <= args.min_zncc <= 1:
        raise InputError("--min-zncc", f"must be between 0 and 1, got {args.min_zncc}")
    if args.search < 1:
        raise InputError("--search", f"must be >= 1 pixel, got {args.search}")
    if args.prefilter < 0:
        raise InputError("--prefilter", f"must be >= 0, got {args.prefilter}")


def run(args) -> int:
    import numpy as np

    from calib.errors import InputError
    from calib.imageio import image_size, read_gray
    from calib.numbers import fixed
    from calib.progress import progress
    from stereodic.cli.common import dic_grid, wrote
    from stereodic.dic import DicSettings, correlate_sequence
    from stereodic.dic.output import plot_fields, write_csv, write_npz
    if args.strain_window:
        from stereodic.strain import strain_2d

    ref = read_gray(args.ref)
    height, width = ref.shape
    for path in args.defs:  # every file checked before the (long) work starts
        w, h = image_size(path)
        if (w, h) != (width, height):
            raise InputError(path, f"image is {w}x{h} but the reference {args.ref} is {width}x{height}")
    _check_args(args)
    grid, seeds = dic_grid(args, width, height, "reference", args.ref)
    settings = DicSettings(subset=args.subset, shape=args.shape, order=3 if args.interp == "cubic" else 5,
                           prefilter_sigma=args.prefilter, min_zncc=args.min_zncc, search_radius=args.search)

    def images():
        for path in args.defs:
            img = read_gray(path)
            if img.shape != ref.shape:
                raise InputError(path, f"image is {img.shape[1]}x{img.shape[0]} but the reference is "
                                       f"{width}x{height}")
            yield img

    fields, strains = [], []
    for k, f in enumerate(progress(correlate_sequence(ref, images(), grid, settings, seeds,
                                                      args.incremental), "dic2d", total=len(args.defs))):
        fields.append(f)
        strains.append(strain_2d(grid.xs, grid.ys, f.u, f.v, args.strain_window)
                       if args.strain_window else None)
        n_ok = int(f.ok.sum())
        print(f"image {k} ({args.defs[k]}): {n_ok}/{int(grid.active.sum())} points converged, "
              f"mean u {fixed(np.nanmean(f.u) if n_ok else np.nan, 4)} px, "
              f"mean v {fixed(np.nanmean(f.v) if n_ok else np.nan, 4)} px")
    n_points = int(grid.active.sum())
    write_csv(args.output, fields, strains)
    wrote(args.output, f"{n_points * len(fields)} rows ({n_points} points x {len(fields)} deformed images)")
    if args.npz:
        write_npz(args.npz, fields, strains, settings, args.defs)
        wrote(args.npz, "the fields as arrays (n_images, ny, nx)")
    if args.plot:
        paths = plot_fields(args.plot, fields, strains)
        wrote(args.plot, f"{len(paths)} maps ({', '.join(p.name for p in paths[:3])}, ...)")
    return 0
